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
 * A pulse (PULSE_RUN_ENABLE, the host's kill-path probe, issue 49) turns an output that is on off for its
 * length and on again, unlatched, unless meanwhile the heartbeat expired or an over-speed came (then it stays
 * off, latched, with that cause). Every change yields one event for the ring: tag 5, code and status as in
 * the contract. */
#ifndef DYNO_SUPERVISOR_H
#define DYNO_SUPERVISOR_H
#include <stdint.h>
#include "event.h"

/* status of a TAG_SUPERVISOR event: the cause of the change */
#define SUP_ON 0u
#define SUP_HEARTBEAT 1u
#define SUP_OVERSPEED_PRIMARY 2u
#define SUP_OVERSPEED_SECONDARY 3u
#define SUP_PULSE 4u  /* off for a pulse: code = its length in ms; its end is an ON event */

typedef struct {
    uint32_t beat_us;            /* device time of the last heartbeat the loop took */
    uint16_t min_period_us[2];   /* primary, secondary; 0: not checked */
    uint16_t timeout_ms;
    uint8_t armed;               /* a SET_SUPERVISOR was taken in this boot */
    uint8_t on;                  /* the output */
    uint8_t pulsing;             /* off for a pulse (not latched) */
    uint16_t pulse_ms;
    uint32_t pulse_start_us;
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
/* The heartbeat check at now_us: 1 (and the event) if it turns the output off, or if the pulse under way ended
 * (on again: ON; or off for good: HEARTBEAT when no heartbeat came within the timeout of its end). */
uint8_t supervisor_check(supervisor_t *s, uint32_t now_us, dyno_event_t *ev);
/* PULSE_RUN_ENABLE taken at now_us: an output that is on goes off for ms (1 and the PULSE event); otherwise
 * nothing (0: off or latched stays so, a pulse under way runs its own length). ms == PULSE_LATCH (0xFFFF):
 * off and latched like a drop (also during a pulse), until the next arm: the host's cut when its own kill
 * path failed its probe. */
uint8_t supervisor_pulse(supervisor_t *s, uint16_t ms, uint32_t now_us, dyno_event_t *ev);

#endif
