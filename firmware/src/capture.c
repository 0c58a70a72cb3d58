/* Hall ISRs: every Hall pulse gets a 0.5 us-resolution timestamp of its falling edge
 * (reported in us) and goes into the ring if it is a real pulse:
 *   - a glitch (low for less than HALL_MIN_PULSE_US: an ignition spike) is dropped;
 *   - a pulse starting within the lock-out after the end of the last *accepted* one
 *     (ringing at release, magnet bounce) is dropped;
 * each counted per cause in g_counters. The pin interrupts on any change: the falling
 * edge records the time, the rising edge decides (so an event is queued when its pulse
 * ends, with the time it started). The lock-out adapts to the speed in the main loop
 * (capture_service): a quarter of the last accepted period, within [floor, cap], counted
 * from the end of the accepted pulse, so it fits any pulse width below 3/4 of a period. */
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

typedef struct {
    uint32_t fall_us;        /* falling edge of the pulse in progress */
    uint32_t last_us;        /* falling edge of the last accepted pulse */
    uint16_t end_us16;       /* rising edge of the last accepted pulse, low 16 bits */
    uint16_t lockout_us;     /* current lock-out (main loop writes, ISR reads) */
    uint8_t state;           /* IDLE, PULSE (fall seen, deciding at the rise), LOCKED */
    uint8_t accepted;        /* accepted pulses (wraps): the loop derives the period */
} hall_ch_t;
static volatile hall_ch_t hall[2];
enum { HALL_IDLE = 0, HALL_PULSE = 1, HALL_LOCKED = 2 };

/* Main-loop side of the adaptive lock-out (never touched by ISRs). */
typedef struct {
    uint32_t seen_last_us;
    uint32_t period_us;
    uint16_t floor_us;  /* SET_DEBOUNCE */
    uint8_t seen_accepted;
    uint8_t have_last, have_period;
} hall_loop_t;
static hall_loop_t hall_loop[2];
static uint8_t new_periods;  /* bit c: capture_service measured a new period of channel c (the supervisor) */

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

/* The low 16 bits of tstamp_extend(t1_base_us, tcnt, tov), with 16-bit arithmetic only
 * (the rising edge needs no more: widths and lock-outs are < 65.5 ms). */
static inline __attribute__((always_inline)) uint16_t us16_of(uint16_t tcnt, uint8_t tov)
{
    /* Only the base's low half (the AVR is little-endian): a volatile u32 read would
     * load all four bytes. */
    uint16_t base16 = *(volatile uint16_t *)&t1_base_us;
    uint16_t t = (uint16_t)(base16 + (uint16_t)(tcnt >> 1));
    if ((tov & _BV(TOV1)) && !(tcnt & 0x8000u))
        t = (uint16_t)(t + (uint16_t)TSTAMP_US_PER_OVERFLOW);
    return t;
}

uint32_t capture_now_us(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t = now_us_locked();
    SREG = sreg;
    return t;
}

/* Both Hall ISRs, inlined into each vector (no calls); `low` is the pin level now. The
 * work is split between the two edges of a pulse so neither ISR is long:
 *   fall: timestamp; inside the lock-out (from the end of the last accepted pulse)?
 *         -> LOCKED (counted once), else PULSE;
 *   rise: PULSE shorter than the minimum width -> glitch, else the event (its fall time).
 * Two changes closer than the ISR latency make one interrupt, and the level tells which
 * was seen last: a rise missed between two lows merges two pulses into one (keeping the
 * first fall: at most the latency early, never a real pulse lost); a fall missed between
 * two highs was a pulse shorter than the latency: a glitch. Widths are taken mod 2^16 us:
 * a pulse longer than 65.5 ms (below ~46 rpm at 5 % duty) is misjudged with probability
 * 50/65536, the price of a short ISR. */
static inline __attribute__((always_inline)) void hall_edge(uint8_t tag, volatile hall_ch_t *h,
                                                            uint8_t low, uint8_t ch,
                                                            uint16_t tcnt, uint8_t tov)
{
    if (low) {
        uint8_t st = h->state;
        if (st == HALL_LOCKED)
            return;  /* a rise and a fall missed while locked out: still locked out */
        uint32_t t = tstamp_extend(t1_base_us, tcnt, tov & _BV(TOV1));
        if (st == HALL_PULSE) {
            /* Low again: the rise in between was missed (it came, and a new fall, before this
             * ISR read the pin). Low since the fall for at least the minimum even counted to
             * now: a real pulse and a spike or ring right after it, one longer pulse (its fall
             * kept). Shorter: that low was a glitch (two spikes a few us apart measured as one
             * pulse passed the filter: issue 27's stress run); the pulse starts now. */
            if ((uint16_t)((uint16_t)t - (uint16_t)h->fall_us) >= HALL_MIN_PULSE_US)
                return;
            g_counters.glitch[ch]++;
            h->fall_us = t;
            return;
        }
        h->fall_us = t;  /* first (unused while LOCKED): t's registers are free for the test */
        if ((uint16_t)((uint16_t)t - h->end_us16) < h->lockout_us &&
            !(uint16_t)((t - h->last_us) >> 16)) {
            g_counters.lockout[ch]++;
            h->state = HALL_LOCKED;
            return;
        }
        h->state = HALL_PULSE;
        return;
    }
    uint8_t st = h->state;
    h->state = HALL_IDLE;
    if (st != HALL_PULSE) {
        if (st == HALL_IDLE)  /* high again before we saw it low: shorter than the latency */
            g_counters.glitch[ch]++;
        return;
    }
    uint16_t t16 = us16_of(tcnt, tov);
    uint32_t fall = h->fall_us;
    if ((uint16_t)(t16 - (uint16_t)fall) < HALL_MIN_PULSE_US) {
        g_counters.glitch[ch]++;
        return;
    }
    h->last_us = fall;
    h->end_us16 = t16;
    h->accepted++;
    ring_push_edge(&g_ring, tag, fall);
}

/* AD7171 RDY (DOUT/RDY falling on PD5 = PCINT21): its time is Timer1 read first thing
 * in whichever ISR runs first after the fall -- the pin change ISR, or a Hall ISR that
 * finds the pin change flag set (INT0/INT1 outrank PCINT2, and a Hall ISR would otherwise
 * delay RDY's timestamp by its whole length, twice with both channels). So the stamp is
 * late by at most one ISR already running when RDY fell (TWI's, <= 200 cycles) plus an
 * ISR's entry, not by a stack of ISRs. A Hall ISR keeps the raw count (tcnt, tov); the
 * pin change ISR, which runs right after it (it outranks the overflow ISR, so the base
 * has not moved), extends it to us. The pin change interrupt is masked from RDY until
 * the result has been clocked out: the data bits toggle the same pin. */
/* "A Hall ISR kept RDY's raw count" is a bit of GPIOR0 (an I/O register: tested and set
 * in one cycle each, which keeps the Hall ISRs under 200 cycles; nothing else uses it). */
#define RDY_RAW_BIT PCIF2  /* (GPIOR0's bit for this converter: its PCIFR bit, see rdy_snapshot) */
static volatile uint8_t adc_rdy_seen;  /* the pin change ISR stamped adc_rdy_us */
static volatile uint32_t adc_rdy_us;

/* The input torque converter's RDY state (its ISR and functions are further down). */
static volatile uint8_t in_rdy_seen;
static volatile uint32_t in_rdy_us;

/* One snapshot serves both converters and INT1: GPIOR0 bit PCIF2 / PCIF0 (the PCIFR bit of the RDY's
 * pin change group) says "this RDY was pending at the snapshot: rdy_raw_* is its count", and bit INTF1
 * (bit 1: PCINT1 is unused) the same for an INT1 edge pending when INT0 took it; a new snapshot is
 * taken only when none is waiting to be consumed, so one never overwrites another's.
 * Why INT1 too (issue 27): INT0 outranks INT1, so an INT1 edge could wait behind a running ISR, INT0,
 * a main-loop cli window and INT0 again (measured 32 us: a TWI ISR, then both edges of a spike on the
 * primary line); a 20 us spike on the secondary line then measured 51 us and passed the glitch
 * filter. With INT0's entry snapshot, INT1's edge is late by no more than INT0's edges can be
 * (unless a RDY's snapshot is still unconsumed when INT0 runs: then INT1 reads Timer1 itself).
 * INT1 takes its own count for the RDYs (one may have fallen after INT0's snapshot) and INT0's for
 * its edge; neither can wait behind the overflow ISR (both outrank it), so the base is the same. */
static volatile uint16_t rdy_raw_tcnt;
static volatile uint8_t rdy_raw_tov;
#define RDY_BITS (_BV(PCIF2) | _BV(PCIF0))
#define RAW_BITS (_BV(PCIF2) | _BV(INTF1) | _BV(PCIF0))

static inline __attribute__((always_inline)) void rdy_snapshot(uint8_t f, uint16_t tcnt, uint8_t tov)
{
    if (f && !(GPIOR0 & RAW_BITS)) {
        rdy_raw_tcnt = tcnt;
        rdy_raw_tov = tov;
        GPIOR0 |= f;
    }
}

/* Timer1 first (counter, then its overflow flag: tstamp.h), then the pin. */
ISR(INT0_vect)
{
    uint16_t tcnt = TCNT1;
    uint8_t tov = TIFR1;  /* TOV1 is masked where used (saves a cycle on every path) */
    rdy_snapshot((uint8_t)((PCIFR & RDY_BITS) | (EIFR & _BV(INTF1))), tcnt, tov);
    hall_edge(TAG_PRIMARY, &hall[0], !(PIND & _BV(PIN_HALL_PRIMARY_BIT)), 0, tcnt, tov);
}
ISR(INT1_vect)
{
    uint16_t tcnt = TCNT1;
    uint8_t tov = TIFR1;  /* TOV1 is masked where used (saves a cycle on every path) */
    uint16_t etcnt = tcnt;
    uint8_t etov = tov;
    if (GPIOR0 & _BV(INTF1)) {  /* INT0 ran first and kept the count: this edge came before it */
        etcnt = rdy_raw_tcnt;
        etov = rdy_raw_tov;
        GPIOR0 &= (uint8_t)~_BV(INTF1);
    }
    rdy_snapshot((uint8_t)(PCIFR & RDY_BITS), tcnt, tov);
    hall_edge(TAG_SECONDARY, &hall[1], !(PIND & _BV(PIN_HALL_SECONDARY_BIT)), 1, etcnt, etov);
}

void capture_set_lockout(uint16_t primary_us, uint16_t secondary_us)
{
    hall_loop[0].floor_us = primary_us;
    hall_loop[1].floor_us = secondary_us;
    capture_service();
}

ISR(PCINT2_vect)
{
    uint16_t tcnt = TCNT1;
    uint8_t tov = TIFR1 & _BV(TOV1);
    if (GPIOR0 & _BV(RDY_RAW_BIT)) {  /* a Hall ISR ran first and kept the count */
        tcnt = rdy_raw_tcnt;
        tov = rdy_raw_tov;
        GPIOR0 &= (uint8_t)~_BV(RDY_RAW_BIT);
    }
    if (PIND & _BV(PIN_ADC_DOUT_BIT))
        return;  /* not RDY (a change that undid itself) */
    adc_rdy_us = tstamp_extend(t1_base_us, tcnt, tov & _BV(TOV1));
    adc_rdy_seen = 1;
    PCMSK2 = 0;
}

uint32_t capture_adc_rdy_us(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t;
    if (adc_rdy_seen)
        t = adc_rdy_us;
    else if (GPIOR0 & _BV(RDY_RAW_BIT))  /* the pin change ISR has not run yet: same base */
        t = tstamp_extend(t1_base_us, rdy_raw_tcnt, rdy_raw_tov & _BV(TOV1));
    else
        t = now_us_locked();  /* RDY seen before any ISR could stamp it */
    /* The result is clocked out next: its data bits must not look like RDY. */
    PCMSK2 = 0;
    PCIFR = _BV(PCIF2);
    GPIOR0 &= (uint8_t)~_BV(RDY_RAW_BIT);
    adc_rdy_seen = 0;
    SREG = sreg;
    return t;
}

void capture_adc_rearm(void)
{
    uint8_t sreg = SREG;
    cli();
    PCIFR = _BV(PCIF2);  /* forget the data bits' changes */
    GPIOR0 &= (uint8_t)~_BV(RDY_RAW_BIT);
    adc_rdy_seen = 0;
    PCMSK2 = _BV(PIN_ADC_DOUT_BIT);  /* PCINT21 is PD5 */
    SREG = sreg;
}

/* The input torque AD7171's RDY (DOUT2/RDY2 falling on PB0 = PCINT0): timed exactly as the
 * first converter's (above), by whichever ISR runs first after the fall: PCINT0's own, or a Hall
 * ISR that finds PCIF0 set and keeps Timer1's raw count (GPIOR0 bit 1). (Timer1's input capture
 * on ICP1 = PB0 would latch it in hardware, but simavr 1.6 does not capture on ICP1, so the FIL
 * run could not test it; the pin is the ICP1 pin, the option stays open.) */

ISR(PCINT0_vect)
{
    uint16_t tcnt = TCNT1;
    uint8_t tov = TIFR1 & _BV(TOV1);
    if (GPIOR0 & _BV(PCIF0)) {  /* a Hall ISR ran first and kept the count */
        tcnt = rdy_raw_tcnt;
        tov = rdy_raw_tov;
        GPIOR0 &= (uint8_t)~_BV(PCIF0);
    }
    if (PINB & _BV(PIN_IN_DOUT_BIT))
        return;  /* not RDY */
    in_rdy_us = tstamp_extend(t1_base_us, tcnt, tov & _BV(TOV1));
    in_rdy_seen = 1;
    PCMSK0 = 0;
}

void capture_input_arm(void)
{
    uint8_t sreg = SREG;
    cli();
    PCIFR = _BV(PCIF0);  /* forget the data bits' changes */
    GPIOR0 &= (uint8_t)~_BV(PCIF0);
    in_rdy_seen = 0;
    PCMSK0 = _BV(PIN_IN_DOUT_BIT);  /* PCINT0 is PB0 */
    PCICR |= _BV(PCIE0);
    SREG = sreg;
}

uint32_t capture_input_rdy_us(void)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t;
    if (in_rdy_seen)
        t = in_rdy_us;
    else if (GPIOR0 & _BV(PCIF0))
        t = tstamp_extend(t1_base_us, rdy_raw_tcnt, rdy_raw_tov & _BV(TOV1));
    else
        t = now_us_locked();
    PCMSK0 = 0;
    PCIFR = _BV(PCIF0);
    GPIOR0 &= (uint8_t)~_BV(PCIF0);
    in_rdy_seen = 0;
    SREG = sreg;
    return t;
}

void capture_push_input(uint32_t t_us, uint16_t code, uint8_t status)
{
    uint8_t sreg = SREG;
    cli();
    ring_push(&g_ring, TAG_INPUT, t_us, code, status);
    SREG = sreg;
}

void capture_push_adc(uint32_t t_us, uint16_t code, uint8_t status)
{
    uint8_t sreg = SREG;
    cli();  /* the Hall ISRs push too */
    ring_push(&g_ring, TAG_ADC, t_us, code, status);
    SREG = sreg;
}

/* Main loop: the adaptive lock-out (a quarter of the last period between two accepted
 * pulses, within [floor, cap]), and the last accepted time kept within reach of the u32
 * wrap (a channel quiet for more than 2^31 us would see (t - last) wrap small). The
 * loop passes far more often than pulses come, so it sees every accepted pulse; if it
 * ever missed one, that period is skipped. */
void capture_service(void)
{
    for (uint8_t c = 0; c < 2; c++) {
        volatile hall_ch_t *h = &hall[c];
        hall_loop_t *l = &hall_loop[c];
        uint8_t sreg = SREG;
        cli();
        uint32_t t = now_us_locked();
        if ((uint32_t)(t - h->last_us) > 0x40000000ul)
            h->last_us = t - 0x10000ul;  /* >= 65.5 ms ago: out of any lock-out */
        uint8_t acc = h->accepted;
        uint32_t last = h->last_us;
        SREG = sreg;
        if (acc != l->seen_accepted) {
            if ((uint8_t)(acc - l->seen_accepted) == 1 && l->have_last) {
                l->period_us = last - l->seen_last_us;
                l->have_period = 1;
                new_periods |= (uint8_t)(1u << c);
            }
            l->seen_accepted = acc;
            l->seen_last_us = last;
            l->have_last = 1;
        }
        uint32_t quarter = l->have_period ? l->period_us >> 2 : 0u;
        uint16_t lock = quarter > LOCKOUT_CAP_US ? (uint16_t)LOCKOUT_CAP_US : (uint16_t)quarter;
        if (lock < l->floor_us)
            lock = l->floor_us;
        cli();
        h->lockout_us = lock;
        SREG = sreg;
    }
}

uint8_t capture_take_periods(void)
{
    uint8_t m = new_periods;
    new_periods = 0;
    return m;
}

uint32_t capture_period_us(uint8_t ch) { return hall_loop[ch].period_us; }
uint32_t capture_last_us(uint8_t ch) { return hall_loop[ch].seen_last_us; }

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

    for (uint8_t c = 0; c < 2; c++) {
        hall_loop[c].floor_us = hall[c].lockout_us = c ? lockout_secondary : lockout_primary;
        hall_loop[c].have_last = hall_loop[c].have_period = 0;
        hall_loop[c].seen_accepted = 0;
        hall[c].accepted = 0;
        /* First pulse always accepted: the last one was 65.5 ms before boot. */
        hall[c].last_us = (uint32_t)0 - 0x10000ul;
        hall[c].end_us16 = 0;
        hall[c].state = HALL_IDLE;
    }

    DDRD &= (uint8_t)~(_BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT));
#if HALL_INTERNAL_PULLUP
    PORTD |= _BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT);
#else
    PORTD &= (uint8_t)~(_BV(PIN_HALL_PRIMARY_BIT) | _BV(PIN_HALL_SECONDARY_BIT));
#endif
    /* Any change on INT0 and INT1: the falling edge (magnet pulls the output low) times
     * the pulse, the rising edge measures its width. */
    EICRA = _BV(ISC00) | _BV(ISC10);
    EIFR = _BV(INTF0) | _BV(INTF1);
    EIMSK = _BV(INT0) | _BV(INT1);
    /* AD7171 RDY on PD5: pin change interrupt group 2. */
    adc_rdy_seen = 0;
    GPIOR0 &= (uint8_t)~(_BV(RDY_RAW_BIT) | _BV(INTF1));
    PCIFR = _BV(PCIF2);
    PCMSK2 = _BV(PIN_ADC_DOUT_BIT);
    PCICR |= _BV(PCIE2);
    SREG = sreg;
}
