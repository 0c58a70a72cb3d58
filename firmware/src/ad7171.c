/* The AD7171 shifts a bit out on each SCLK falling edge; it is valid by the rising
 * edge, where we sample it (as the thesis sketch did). SCLK idles high. After the
 * 24th bit DOUT/RDY returns high until the next conversion (125 Hz at the rig's
 * setting). Interrupts stay on: a Hall ISR in the middle just stretches one SCLK
 * phase, which the AD7171 does not mind (no serial timeout). */
#include <avr/io.h>
#include "ad7171.h"
#include "pins.h"

#define SCLK_LOW() (PORTD &= (uint8_t)~_BV(PIN_ADC_SCLK_BIT))
#define SCLK_HIGH() (PORTD |= _BV(PIN_ADC_SCLK_BIT))

#if AD7171_ARDUINO_PULLUP
/* Build variant (make pullup): DOUT read the common Arduino way, INPUT_PULLUP and
 * digitalRead(). Slower (~4 us a bit) but it must work, and it is what much Arduino
 * code does: the simavr harness has to model the AD7171 as an external driver over the
 * MCU's pull-up for this to read anything but 1 (docs/firmware.md). */
#include <Arduino.h>
#define DOUT() ((uint8_t)digitalRead(5))

void ad7171_init(void)
{
    SCLK_HIGH();
    DDRD |= _BV(PIN_ADC_SCLK_BIT);
    pinMode(5, INPUT_PULLUP);  /* D5 = PD5 */
}
#else
#define DOUT() ((PIND >> PIN_ADC_DOUT_BIT) & 1u)

void ad7171_init(void)
{
    SCLK_HIGH();
    DDRD |= _BV(PIN_ADC_SCLK_BIT);
    DDRD &= (uint8_t)~_BV(PIN_ADC_DOUT_BIT);
    /* Pull-up on: DOUT/RDY is push-pull and overrides it, but an unplugged cable then reads 1 ("not ready",
     * no conversion) instead of floating low and reading "ready" on every pass (a ring full of junk codes;
     * dyno doctor: "no conversions"). As the input converter's (ad7171_input.c). */
    PORTD |= _BV(PIN_ADC_DOUT_BIT);
}
#endif

uint8_t ad7171_ready(void) { return !DOUT(); }

static uint8_t clock_bit(void)
{
    SCLK_LOW();
    __asm__ __volatile__("nop\n\tnop");  /* >= 100 ns SCLK low */
    SCLK_HIGH();
    __asm__ __volatile__("nop\n\tnop");  /* DOUT settles after the falling edge */
    return DOUT();
}

void ad7171_read(uint16_t *code, uint8_t *status)
{
    uint16_t c = 0;
    uint8_t s = 0;
    for (uint8_t i = 0; i < 16; i++)
        c = (uint16_t)(c << 1) | clock_bit();
    for (uint8_t i = 0; i < 8; i++)
        s = (uint8_t)(s << 1) | clock_bit();
    *code = c;
    *status = s;
}
