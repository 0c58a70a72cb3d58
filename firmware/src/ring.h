/* Lossless single-consumer event ring with an overflow counter. Pure C.
 *
 * Producers: the Hall ISRs (INT0/INT1) and the main loop (ADC, inside cli). Consumer:
 * the frame builder reads entries in place (no copy out) and the ACK in the TWI ISR
 * retires them by moving `tail`. Indices are free-running u8 (RING_SIZE <= 128 divides
 * 256), so count = head - tail needs no wrap test and every index access is one byte,
 * i.e. atomic on the AVR. A full ring drops the *new* event and counts it: old events
 * are never overwritten, so what the host already expects stays consistent; the next
 * event that gets in carries TAG_GAP, so the host knows exactly where the stream has a
 * hole and never takes a period across it. */
#ifndef DYNO_RING_H
#define DYNO_RING_H
#include <stdint.h>
#include "config.h"
#include "event.h"

#if (RING_SIZE & (RING_SIZE - 1)) || RING_SIZE > 128
#error "RING_SIZE must be a power of two <= 128"
#endif
#define RING_MASK ((uint8_t)(RING_SIZE - 1u))

/* Guard bytes right before and right after the entries, set by ring_init: the simavr
 * harness checks them after every command from the host and reports any write outside
 * the ring (8 bytes of RAM, so the check runs against the shipped ELF). */
#define RING_GUARD_LEN 4u
#define RING_GUARD_BYTES {0xD1u, 0x5Cu, 0x0Au, 0x7Eu}

typedef struct {
    uint8_t guard_lo[RING_GUARD_LEN];
    dyno_event_t ev[RING_SIZE];
    uint8_t guard_hi[RING_GUARD_LEN];
    volatile uint8_t head;      /* next slot to write (producers) */
    volatile uint8_t tail;      /* oldest event not yet acknowledged by the host */
    volatile uint8_t overflow;  /* 1 once an event was dropped, until CLEAR_COUNTERS */
    volatile uint16_t dropped;  /* events dropped since boot or CLEAR_COUNTERS (wraps) */
    volatile uint8_t gap;       /* TAG_GAP once an event was dropped, until the next push */
} ring_t;

extern ring_t g_ring;

void ring_init(ring_t *r);

static inline uint8_t ring_count(const ring_t *r) { return (uint8_t)(r->head - r->tail); }

/* Caller guarantees no other producer runs meanwhile (ISR context, or interrupts off).
 * Always inlined: a call from a Hall ISR would save every call-clobbered register. */
static inline __attribute__((always_inline)) uint8_t ring_push_(ring_t *r, uint8_t tag, uint32_t t_us,
                                                                uint16_t code, uint8_t status, uint8_t data)
{
    uint8_t h = r->head;
    if ((uint8_t)(h - r->tail) >= RING_SIZE) {
        r->dropped++;
        r->overflow = 1;
        r->gap = TAG_GAP;
        return 0;
    }
    dyno_event_t *ev = r->ev;
#ifdef __AVR__
    /* An opaque base: with the entries at a non-zero offset (after guard_lo) gcc -Os
     * otherwise indexes each field with shift loops (~30 more cycles in the Hall ISRs). */
    __asm__("" : "+r"(ev));
#endif
    dyno_event_t *e = &ev[h & RING_MASK];
    e->t_us = t_us;
    if (data) {  /* a constant: the Hall ISRs' pushes store no code and status */
        e->code = code;
        e->status = status;
    }
    e->tag = (uint8_t)(tag | r->gap);
    r->gap = 0;
    r->head = (uint8_t)(h + 1u);  /* publish only after the entry is complete */
    return 1;
}

static inline __attribute__((always_inline)) uint8_t ring_push(ring_t *r, uint8_t tag, uint32_t t_us,
                                                               uint16_t code, uint8_t status)
{
    return ring_push_(r, tag, t_us, code, status, 1);
}

/* A Hall edge: its time only. The encoder reads code and status for TAG_ADC and TAG_INPUT only
 * (frame.c), so an edge's entry keeps whatever they held: 3 stores (6 cycles) less in the Hall ISRs. */
static inline __attribute__((always_inline)) uint8_t ring_push_edge(ring_t *r, uint8_t tag, uint32_t t_us)
{
    return ring_push_(r, tag, t_us, 0, 0, 0);
}

/* k-th oldest unacknowledged event (k < ring_count). */
static inline const dyno_event_t *ring_peek(const ring_t *r, uint8_t k)
{
    return &r->ev[(uint8_t)(r->tail + k) & RING_MASK];
}

static inline void ring_retire(ring_t *r, uint8_t n) { r->tail = (uint8_t)(r->tail + n); }

#endif
