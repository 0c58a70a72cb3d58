/* dyno Nano firmware: setup() and loop(). See docs/firmware.md. */
#include <Arduino.h>
#include <avr/wdt.h>
#include "config.h"
#include "link_serial.h"
extern "C" {
#include "ad7171.h"
#include "bootcount.h"
#include "capture.h"
#include "link_i2c.h"
#include "proto.h"
#include "ring.h"
}

/* MCUSR saved before anything else: a watchdog reset leaves the WDT running with the
 * shortest timeout, which would reset the MCU again during init(). */
uint8_t g_reset_cause __attribute__((section(".noinit")));
extern "C" void early_wdt_off(void) __attribute__((naked, used, section(".init3")));
extern "C" void early_wdt_off(void)
{
    g_reset_cause = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

extern "C" void proto_hook_set_debounce(uint16_t primary_us, uint16_t secondary_us)
{
    capture_set_lockout(primary_us, secondary_us);
}

void setup()
{
    uint16_t boots = bootcount_increment();
    ring_init(&g_ring);
    ad7171_init();
    capture_init(DEBOUNCE_PRIMARY_US_DEFAULT, DEBOUNCE_SECONDARY_US_DEFAULT);
    proto_init(&g_proto, &g_ring, boots, DEBOUNCE_PRIMARY_US_DEFAULT,
               DEBOUNCE_SECONDARY_US_DEFAULT, capture_now_us());
    proto_service(&g_proto, capture_now_us(), millis());
    link_serial_init();
    link_i2c_init(I2C_ADDRESS);
    /* 500 ms: far above the longest loop pass (well under 1 ms), short enough that a
     * hung MCU is back before the host's link-lost timeout. */
    wdt_enable(WDTO_500MS);
}

void loop()
{
    wdt_reset();
    /* The ADC is read here, not in an ISR: clocking 24 bits takes ~25 us. Its time is
     * taken when RDY is seen, so it may be queued after a later Hall edge (the frame's
     * signed dt covers that). */
    if (ad7171_ready()) {
        uint32_t t_us = capture_now_us();
        uint16_t code;
        uint8_t status;
        ad7171_read(&code, &status);
        capture_push_adc(t_us, code, status);
    }
    capture_service();
    proto_service(&g_proto, capture_now_us(), millis());
    link_serial_service();
}
