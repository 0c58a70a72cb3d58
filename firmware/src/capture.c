/* Hall ISRs: every accepted falling edge gets a 0.5 us-resolution timestamp (reported in
 * us) and goes into the ring. An edge within the channel's lock-out window after the
 * last *accepted* edge is contact/magnet bounce and is dropped here, never queued. */
#include <avr/io.h>
#include <avr/interrupt.h>
#include "capture.h"
#include "config.h"
#include "counters.h"
#include "pins.h"
#include "ring.h"
#include "tstamp.h"

/* us at the last Timer1 overflow; only the overflow ISR writes it. */
static volatile uint32_t t1_base_us;
static volatile uint32_t last_primary_us, last_secondary_us;
static volatile uint16_t lockout_primary_us, lockout_secondary_us;

ISR(TIMER1_OVF_vect)
{
    t1_base_us += TSTAMP_US_PER_OVERFLOW;
}

/* Interrupts must be off (ISR, or inside a critical section). Always inlined: a call
 * from an ISR makes gcc save all 12 call-clobbered registers (~60 cycles). */
static inline __attribute__((always_inline)) uint32_t now_us_locked(void)
{
    uint16_t tcnt = TCNT1;  /* counter first, then the pending-overflow flag: tstamp.h */
    uint8_t tov = TIFR1 & _BV(TOV1);
    return tstamp_extend(t1_base_us, tcnt, tov);
}

uint32_t capture_now_us(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t = now_us_locked();
    SREG = sreg;
    return t;
}

/* Both Hall ISRs: timestamp first (latency matters), then the lock-out test against
 * the last *accepted* edge, then queue. Inlined into each vector, no calls. */
static inline __attribute__((always_inline)) void hall_edge(uint8_t tag, volatile uint32_t *last_us,
                                                            uint16_t lockout_us, uint8_t ch)
{
    uint32_t t = now_us_locked();
    uint32_t since_us = t - *last_us;
    /* Lock-outs are u16: only the low half needs a compare (fewer registers to save). */
    if (!(uint16_t)(since_us >> 16) && (uint16_t)since_us < lockout_us) {
        g_counters.lockout[ch]++;
        return;
    }
    *last_us = t;
    ring_push(&g_ring, tag, t, 0, 0);
}

ISR(INT0_vect) { hall_edge(TAG_PRIMARY, &last_primary_us, lockout_primary_us, 0); }
ISR(INT1_vect) { hall_edge(TAG_SECONDARY, &last_secondary_us, lockout_secondary_us, 1); }

void capture_set_lockout(uint16_t primary_us, uint16_t secondary_us)
{
    uint8_t sreg = SREG;
    cli();
    lockout_primary_us = primary_us;
    lockout_secondary_us = secondary_us;
    SREG = sreg;
}

void capture_push_adc(uint32_t t_us, uint16_t code, uint8_t status)
{
    uint8_t sreg = SREG;
    cli();  /* the Hall ISRs push too */
    ring_push(&g_ring, TAG_ADC, t_us, code, status);
    SREG = sreg;
}

/* A channel quiet for more than 2^31 us would see (t - last) wrap to a small number
 * and lose one genuine edge; keep `last` within reach. */
void capture_service(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t = now_us_locked();
    if ((uint32_t)(t - last_primary_us) > 0x40000000ul)
        last_primary_us = t - 0x10000ul;
    if ((uint32_t)(t - last_secondary_us) > 0x40000000ul)
        last_secondary_us = t - 0x10000ul;
    SREG = sreg;
}

void capture_init(uint16_t lockout_primary, uint16_t lockout_secondary)
{
    uint8_t sreg = SREG;
    cli();
    /* Timer1 free running, normal mode, clk/8 = 2 MHz. This takes Timer1 from the
     * Arduino core's analogWrite() on D9/D10, which the rig does not use. */
    TCCR1A = 0;
    TCCR1B = _BV(CS11);
    TCCR1C = 0;
    TCNT1 = 0;
    t1_base_us = 0;
    TIFR1 = _BV(TOV1);
    TIMSK1 = _BV(TOIE1);

    lockout_primary_us = lockout_primary;
    lockout_secondary_us = lockout_secondary;
    /* First edge always accepted: pretend the last one was 65.5 ms ago (> any window). */
    last_primary_us = last_secondary_us = (uint32_t)0 - 0x10000ul;

    DDRD &= (uint8_t)~(_BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT));
#if HALL_INTERNAL_PULLUP
    PORTD |= _BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT);
#else
    PORTD &= (uint8_t)~(_BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT));
#endif
    /* Falling edge on INT0 and INT1 (the magnet pulls the sensor output low). */
    EICRA = _BV(ISC01) | _BV(ISC11);
    EIFR = _BV(INTF0) | _BV(INTF1);
    EIMSK = _BV(INT0) | _BV(INT1);
    SREG = sreg;
}
