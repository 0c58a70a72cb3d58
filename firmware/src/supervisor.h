/* The run-enable supervisor (issue 37, docs/protocol.md "Run-enable supervisor"): the decisions only.
 * Pure C, unit-tested natively (test/native/test_supervisor.c); main.cpp feeds it (the heartbeats and
 * SET_SUPERVISOR the link ISRs flagged, the Hall periods capture.c's loop side measured, the time) and
 * drives the pin (D7) from `on`, so nothing here runs in an ISR (Grbl's and Klipper's split: the
 * interrupt only notes, the loop decides).
 *
 * States: not armed (boot: off until the host's SET_SUPERVISOR), on, off (latched: only the next
 * SET_SUPERVISOR turns it on again). While on it goes off when
 *   - no heartbeat (a CRC-valid POLL, ACK_POLL or SET_SUPERVISOR) came for more than timeout_ms, or
 *   - a Hall period measured after arming is shorter than its channel's minimum (0: not checked).
 * Every change yields one event for the ring: tag 5, code and status as in the contract. */
#ifndef DYNO_SUPERVISOR_H
#define DYNO_SUPERVISOR_H
#include <stdint.h>
#include "event.h"

/* status of a TAG_SUPERVISOR event: the cause of the change */
#define SUP_ON 0u
#define SUP_HEARTBEAT 1u
#define SUP_OVERSPEED_PRIMARY 2u
#define SUP_OVERSPEED_SECONDARY 3u

typedef struct {
    uint32_t beat_us;            /* device time of the last heartbeat the loop took */
    uint16_t min_period_us[2];   /* primary, secondary; 0: not checked */
    uint16_t timeout_ms;
    uint8_t armed;               /* a SET_SUPERVISOR was taken in this boot */
    uint8_t on;                  /* the output */
} supervisor_t;

void supervisor_init(supervisor_t *s);
/* SET_SUPERVISOR taken at now_us (also the re-arm): store the limits, on, the heartbeat restarts.
 * Fills the ON event. (timeout_ms == 0 never gets here: proto ignores that command.) */
void supervisor_arm(supervisor_t *s, uint16_t min_primary_us, uint16_t min_secondary_us, uint16_t timeout_ms,
                    uint32_t now_us, dyno_event_t *ev);
/* A heartbeat taken at now_us. */
static inline void supervisor_beat(supervisor_t *s, uint32_t now_us) { s->beat_us = now_us; }
/* A period of channel ch (0 primary, 1 secondary) measured after arming, ended by the accepted pulse at
 * t_us: 1 (and the event) if it turns the output off. */
uint8_t supervisor_period(supervisor_t *s, uint8_t ch, uint32_t period_us, uint32_t t_us, dyno_event_t *ev);
/* The heartbeat check at now_us: 1 (and the event) if it turns the output off. */
uint8_t supervisor_check(supervisor_t *s, uint32_t now_us, dyno_event_t *ev);

#endif
