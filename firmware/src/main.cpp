/* dyno Nano firmware: setup() and loop(). See docs/firmware.md. */
#include <Arduino.h>
#include <avr/wdt.h>
#include "config.h"
#include "pins.h"
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
#include "supervisor.h"
}

static void service_once(void);

void setup()
{
    /* The run-enable output (D7) low before anything else: off until the host's limits arrive. */
    PORTD &= (uint8_t)~_BV(PIN_RUN_BIT);
    DDRD |= _BV(PIN_RUN_BIT);
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

/* ---- the run-enable supervisor (issue 37): supervisor.c decides, this feeds it and drives D7 ---------- */
static supervisor_t g_sup;      /* zeroed by the C runtime at every boot: not armed, off */
/* Supervisor events the full ring could not take yet, oldest first: two, so an arming and the drop right
 * after it (a re-arm into an over-speed while the host lags) both wait; a third change while both still
 * wait loses the oldest, counted as a drop like any event the ring could not take. */
#define SUP_HELD_MAX 2u
static dyno_event_t sup_held[SUP_HELD_MAX];
static uint8_t sup_held_n;

/* Into the ring while there is room (never dropped for lack of room: held until the host retired some). */
static void sup_flush(void)
{
    while (sup_held_n) {
        uint8_t sreg = SREG, pushed = 0;
        cli();  /* the Hall ISRs push too */
        if (ring_count(&g_ring) < RING_SIZE) {
            ring_push(&g_ring, TAG_SUPERVISOR, sup_held[0].t_us, sup_held[0].code, sup_held[0].status);
            pushed = 1;
        }
        SREG = sreg;
        if (!pushed)
            return;
        sup_held[0] = sup_held[1];
        sup_held_n--;
    }
}

static void sup_emit(const dyno_event_t *ev)
{
    sup_flush();
    if (sup_held_n == SUP_HELD_MAX) {  /* the oldest is lost, counted as such */
        uint8_t sreg = SREG;
        cli();
        g_ring.dropped++;
        g_ring.overflow = 1;
        g_ring.gap = TAG_GAP;
        SREG = sreg;
        sup_held[0] = sup_held[1];
        sup_held_n--;
    }
    sup_held[sup_held_n++] = *ev;
    sup_flush();
}

/* Once per pass: the heartbeat and SET_SUPERVISOR the link ISRs noted, the periods capture_service
 * measured, the heartbeat timeout; then the pin. */
static void supervisor_pass(void)
{
    uint16_t args[3], pulse_ms;
    dyno_event_t ev;
    uint32_t now = capture_now_us();
    uint8_t periods = capture_take_periods();
    uint8_t beat = proto_take_beat(&g_proto);
    if (proto_take_supervisor(&g_proto, args)) {
        supervisor_arm(&g_sup, args[0], args[1], args[2], now, &ev);
        sup_emit(&ev);
        periods = 0;  /* measured before the command was taken: not counted */
    } else if (beat) {
        supervisor_beat(&g_sup, now);
    }
    if (proto_take_pulse(&g_proto, &pulse_ms) && supervisor_pulse(&g_sup, pulse_ms, now, &ev))
        sup_emit(&ev);
    for (uint8_t c = 0; c < 2; c++)
        if ((periods >> c) & 1u && supervisor_period(&g_sup, c, capture_period_us(c), capture_last_us(c), &ev))
            sup_emit(&ev);
    if (supervisor_check(&g_sup, now, &ev))
        sup_emit(&ev);
    sup_flush();
    proto_set_run(&g_proto, g_sup.on, g_sup.armed);
#if DYNO_OLD_BOOTLOADER
    /* No watchdog: a charge pump. Toggled on every pass while on (writing 1 to PIND7 toggles PORTD7), so
     * a hung loop stops the pulses and the pump's output falls; low when off. */
    if (g_sup.on)
        PIND = _BV(PIN_RUN_BIT);
    else
        PORTD &= (uint8_t)~_BV(PIN_RUN_BIT);
#else
    /* The watchdog resets a hung loop, and the reset leaves the pin high-Z (the pull-down: off). */
    if (g_sup.on)
        PORTD |= _BV(PIN_RUN_BIT);
    else
        PORTD &= (uint8_t)~_BV(PIN_RUN_BIT);
#endif
}

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
    supervisor_pass();
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
