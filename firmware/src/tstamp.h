/* Timer1 timestamp extension. Pure C (the AVR reads the registers, this does the math).
 *
 * Timer1 runs free at F_CPU/8 = 2 MHz (0.5 us ticks) and overflows every 65536 ticks =
 * 32768 us. The overflow ISR adds 32768 to a u32 "base_us", so base + tcnt/2 is device
 * time in us, wrapping at 2^32 us (~71.6 min) exactly as docs/protocol.md wants, with no
 * multiplication anywhere.
 *
 * The race: an edge ISR (or a cli section) may read TCNT1 just after the counter wrapped
 * but before the overflow ISR ran (it cannot run: interrupts are off). TOV1 is then set
 * and TCNT1 small. Read TCNT1 *first*, TIFR1 second: if TOV1 is pending and the count is
 * in the lower half, the wrap happened before the read and base is one overflow behind.
 * If the count is in the upper half, the wrap came after the read and base is right. */
#ifndef DYNO_TSTAMP_H
#define DYNO_TSTAMP_H
#include <stdint.h>

#define TSTAMP_US_PER_OVERFLOW 32768ul

static inline uint32_t tstamp_extend(uint32_t base_us, uint16_t tcnt_ticks, uint8_t tov_pending)
{
    uint32_t t_us = base_us + (uint16_t)(tcnt_ticks >> 1);
    if (tov_pending && !(tcnt_ticks & 0x8000u))
        t_us += TSTAMP_US_PER_OVERFLOW;
    return t_us;
}

#endif
