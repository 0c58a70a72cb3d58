/* dyno Nano firmware: setup() and loop(). See docs/firmware.md. */
#include <Arduino.h>
#include <avr/wdt.h>
#include "config.h"
#include "link_serial.h"
extern "C" {
#include "ad7171.h"
#include "boot.h"
#include "capture.h"
#include "counters.h"
#include "link_i2c.h"
#include "proto.h"
#include "ring.h"
}

void setup()
{
    ring_init(&g_ring);
    ad7171_init();
    capture_init(DEBOUNCE_PRIMARY_US_DEFAULT, DEBOUNCE_SECONDARY_US_DEFAULT);
    proto_init(&g_proto, &g_ring, &g_counters, g_boot_id, g_reset_cause,
               DEBOUNCE_PRIMARY_US_DEFAULT, DEBOUNCE_SECONDARY_US_DEFAULT, capture_now_us());
    proto_service(&g_proto, capture_now_us(), millis());
    link_serial_init();
    link_i2c_init(I2C_ADDRESS);
#if !DYNO_OLD_BOOTLOADER
    /* 500 ms: far above the longest loop pass (well under 1 ms), short enough that a
     * hung MCU is back before the host's link-lost timeout. Not with the old ATmegaBOOT,
     * which would loop on watchdog resets (platformio.ini, docs/firmware.md). */
    wdt_enable(WDTO_500MS);
#endif
}

#ifdef DYNO_TEST_HANG_MS
/* Test build only (make hang): hang once, DYNO_TEST_HANG_MS after power-up; the flag
 * survives the watchdog reset in .noinit (zero at power-up in simavr). */
static uint8_t test_hung __attribute__((section(".noinit")));
#endif

void loop()
{
    uint16_t lock_p_us, lock_s_us;
#ifdef DYNO_TEST_HANG_MS
    if (!test_hung && millis() >= DYNO_TEST_HANG_MS) {
        test_hung = 1;
        for (;;) {
        }
    }
#endif
#if !DYNO_OLD_BOOTLOADER
    wdt_reset();
#endif
    /* The ADC is read here, not in an ISR: clocking 24 bits takes ~25 us. Its time is
     * RDY's falling edge, taken by the pin change ISR, so it may be queued after a later
     * Hall edge (the frame's signed dt covers that). */
    if (ad7171_ready()) {
        uint32_t t_us = capture_adc_rdy_us();
        uint16_t code;
        uint8_t status;
        ad7171_read(&code, &status);
        capture_adc_rearm();
        capture_push_adc(t_us, code, status);
    }
    capture_service();
    /* SET_DEBOUNCE reaches capture through here: proto knows nothing of capture. */
    if (proto_take_debounce(&g_proto, &lock_p_us, &lock_s_us))
        capture_set_lockout(lock_p_us, lock_s_us);
    proto_service(&g_proto, capture_now_us(), millis());
    link_i2c_service((uint16_t)millis());
    link_serial_service();
}
