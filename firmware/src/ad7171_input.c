/* The second AD7171 on PB0 (DOUT2/RDY2 = ICP1) / PB1 (SCLK2): the same bit-bang as the first
 * (ad7171.c), on port B. Its RDY time is Timer1's input capture (capture.c). */
#include <avr/io.h>
#include "ad7171_input.h"

#include "pins.h"
#define IN_SCLK_BIT PIN_IN_SCLK_BIT
#define IN_DOUT_BIT PIN_IN_DOUT_BIT
#define SCLK_LOW() (PORTB &= (uint8_t)~_BV(IN_SCLK_BIT))
#define SCLK_HIGH() (PORTB |= _BV(IN_SCLK_BIT))
#define DOUT() ((PINB >> IN_DOUT_BIT) & 1u)

void ad7171_input_init(void)
{
    SCLK_HIGH();
    DDRB |= _BV(IN_SCLK_BIT);
    DDRB &= (uint8_t)~_BV(IN_DOUT_BIT);
    PORTB |= _BV(IN_DOUT_BIT);  /* pull-up: a push-pull DOUT overrides it; nothing there reads 1 */
}

uint8_t ad7171_input_ready(void) { return !DOUT(); }

static uint8_t clock_bit(void)
{
    SCLK_LOW();
    __asm__ __volatile__("nop\n\tnop");
    SCLK_HIGH();
    __asm__ __volatile__("nop\n\tnop");
    return DOUT();
}

void ad7171_input_read(uint16_t *code, uint8_t *status)
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
