/* Rejection and bus counters the device reports in the v2 INFO frame. Pure C.
 *
 * Written by the capture ISRs and the TWI driver, read by the frame builder in the
 * main loop; a u16 read from the loop is taken with interrupts off. They count since
 * boot and wrap (the host takes differences). */
#ifndef DYNO_COUNTERS_H
#define DYNO_COUNTERS_H
#include <stdint.h>

typedef struct {
    volatile uint16_t lockout[2];  /* Hall edges inside the lock-out after an accepted one */
    volatile uint16_t glitch[2];   /* Hall pulses shorter than the minimum width */
    volatile uint8_t twi_timeouts; /* TWI transfers the slave aborted (SCL/SDA stuck) */
    volatile uint8_t bus_errors;   /* TWI bus errors (illegal START/STOP) */
} dyno_counters_t;

extern dyno_counters_t g_counters;

#endif
