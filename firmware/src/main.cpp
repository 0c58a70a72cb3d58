/* dyno Nano firmware: setup() and loop(). See docs/firmware.md. */
#include <Arduino.h>
#include <avr/wdt.h>
#include "config.h"
#include "link_serial.h"
extern "C" {
#include "ad7171.h"
#include "ad7171_input.h"
#include "boot.h"
#include "capture.h"
#include "counters.h"
#include "link_i2c.h"
#include "proto.h"
#include "ring.h"
}

static void service_once(void);

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
    /* The input torque converter (issue 27): announced in the capabilities frame if its RDY falls
     * within 20 ms (2.5 conversions). The work goes on meanwhile (the links are up, the frames
     * served and acknowledged as in loop()); CAPS is not answered until the probe is done (the
     * host then gets its data frame and asks again). */
    ad7171_input_init();
    uint8_t fitted = 0;
    for (uint32_t t0 = micros(); (uint32_t)(micros() - t0) < INPUT_PROBE_US;) {
        if (ad7171_input_ready()) {
            fitted = CHANNEL_INPUT;
            capture_input_arm();
            break;
        }
        service_once();
    }
    proto_set_fitted(&g_proto, fitted);
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

/* One pass of the work (both converters, the lock-out, the frames, the links): loop() and the
 * input converter's boot probe run it. */
static void service_once(void)
{
    uint16_t lock_p_us, lock_s_us;
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
    /* The input converter, read the same way; queued only once the host enabled it in this boot
     * (an old host never asked, and must never see tag 4). Read even when not queued: RDY stays armed. */
    if (g_proto.channels_fitted && ad7171_input_ready()) {
        uint32_t t_in = capture_input_rdy_us();
        uint16_t code;
        uint8_t status;
        ad7171_input_read(&code, &status);
        capture_input_arm();
        if (proto_input_enabled(&g_proto))
            capture_push_input(t_in, code, status);
    }
    capture_service();
    /* SET_DEBOUNCE reaches capture through here: proto knows nothing of capture. */
    if (proto_take_debounce(&g_proto, &lock_p_us, &lock_s_us))
        capture_set_lockout(lock_p_us, lock_s_us);
    proto_service(&g_proto, capture_now_us(), millis());
    link_i2c_service((uint16_t)millis());
    link_serial_service();
}

void loop()
{
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
    service_once();
}
