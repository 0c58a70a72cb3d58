/* The v2 link state machine (docs/protocol.md "Acknowledge and re-send"). Pure C.
 *
 * The device holds a *current* frame and a pre-built *next* frame, both encoded with
 * CRC in a small buffer pool. The link ISR never encodes anything: a read just points
 * the transmitter at a ready buffer, and an ACK_POLL that retires the current frame
 * swaps in the pre-built next one, so the TWI slave never stretches the clock while
 * the Pi waits (the BCM2835 I2C master mishandles clock stretching).
 *
 * Roles of the pool buffers (indices): cur, nxt, info, and tx (the one being
 * transmitted, which may be a former role holder). The main loop builds into a buffer
 * that has no role and publishes it with a short critical section, only if nothing
 * changed meanwhile (the `gen` counter).
 *
 * Invariant: cur holds ring events [tail, tail + n_cur), nxt the next n_nxt after
 * those. Once any byte of cur was transmitted it is frozen until retired. */
#ifndef DYNO_PROTO_H
#define DYNO_PROTO_H
#include <stdint.h>
#include "cmd.h"
#include "counters.h"
#include "frame.h"
#include "port.h"
#include "ring.h"

#define PROTO_NBUF 5u
#define PROTO_NONE 0xFFu

typedef struct {
    uint8_t n;          /* ring events in this frame */
    uint8_t head;       /* ring head when built: new events since? */
    uint16_t dropped;   /* ring dropped count when built */
    uint32_t built_us;  /* device time when built (empty-frame refresh) */
} proto_meta_t;

typedef struct {
    uint8_t pool[PROTO_NBUF][FRAME_MAX];
    proto_meta_t meta[PROTO_NBUF];
    ring_t *ring;
    const dyno_counters_t *counters;
    uint16_t boot_id;              /* this boot's identity: in every frame, echoed by ACK_POLL */
    uint8_t boot_hi, boot_lo;      /* its bytes, for the ISR's compare */
    uint8_t cause_flags;           /* reset cause, already shifted into flags bits 4..7 */
    volatile uint8_t cur, nxt, info, tx;
    volatile uint8_t cur_n, nxt_n;  /* meta[cur].n, meta[nxt].n: the ISR retires without indexing */
    volatile uint8_t cur_seq;
    volatile uint8_t cur_sent;     /* a byte of cur has gone out: frozen */
    volatile uint8_t nxt_valid;
    volatile uint8_t serve_info;   /* INFO received: the next read returns the info frame */
    volatile uint8_t retired_any;  /* no RESET flag once the first frame was acknowledged */
    volatile uint8_t gen;          /* bumped whenever cur changes */
    volatile uint8_t info_dirty;
    volatile uint8_t debounce_pending;  /* SET_DEBOUNCE seen in the ISR, taken by the loop */
    uint16_t debounce_primary_us, debounce_secondary_us;  /* mirrored for INFO */
    uint32_t info_built_ms;
    /* diagnostics, not on the wire: commands ignored (bad CRC/length/op) */
    uint8_t cmds_bad;
    /* the optional input torque channel (issue 27): fitted at boot, enabled by the host's
     * SET_CHANNELS in this boot; the capabilities frame double-buffered (the ISR serves one while
     * the loop may build the other), rebuilt by the loop when SET_CHANNELS changed it */
    uint8_t channels_fitted;
    volatile uint8_t channels_enabled;
    volatile uint8_t serve_caps;
    volatile uint8_t caps_ready;   /* the boot's probe is done: the capabilities are known */
    volatile uint8_t caps_dirty;
    volatile uint8_t caps_cur;
    uint8_t caps_buf[2][FRAME_MAX];
    /* the run-enable supervisor (issue 37): SET_SUPERVISOR's args as the ISR copied them, taken by the
     * loop (proto_take_supervisor); the output's state as the loop last published it (proto_set_run) */
    uint8_t sup_args[6];           /* u16 min period primary, secondary (us), timeout (ms), big-endian */
    volatile uint8_t sup_pending;
    uint8_t pulse_args[2];         /* PULSE_RUN_ENABLE's u16 ms as sent (big-endian), taken by the loop */
    volatile uint8_t pulse_pending;
    uint8_t run_flag;              /* FLAG_RUN while the output is on: in data and info frames */
    uint8_t sup_armed;             /* capabilities: enabled bit CHANNEL_SUPERVISOR */
#ifndef __AVR__
    volatile uint8_t beat;         /* natively; on the AVR a bit of GPIOR0 (PROTO_BEAT_SET) */
#endif
} proto_t;

/* "A heartbeat came" (a CRC-valid POLL, ACK_POLL or SET_SUPERVISOR): set in the link ISR, taken by the
 * main loop. On the AVR one bit of GPIOR0 (an I/O register: one 2-cycle sbi in the TWI ISR, no RAM;
 * capture.c uses bits 0..2, this is bit 3). */
#ifdef __AVR__
#define PROTO_BEAT_BIT 3
#define PROTO_BEAT_SET(p) (GPIOR0 |= (uint8_t)_BV(PROTO_BEAT_BIT))
#else
#define PROTO_BEAT_SET(p) ((p)->beat = 1)
#endif

extern proto_t g_proto;

void proto_init(proto_t *p, ring_t *ring, const dyno_counters_t *counters, uint16_t boot_id,
                uint8_t reset_cause, uint16_t deb_p_us, uint16_t deb_s_us, uint32_t now_us);

/* Main loop: 1 and the new Hall lock-out windows if a SET_DEBOUNCE arrived since the
 * last call (the caller applies them: proto does not know the capture module). */
uint8_t proto_take_debounce(proto_t *p, uint16_t *primary_us, uint16_t *secondary_us);
/* Boot: the optional channels found (CHANNEL_INPUT: the second converter answered); from then on
 * CAPS is answered. */
void proto_set_fitted(proto_t *p, uint8_t channels);
/* Main loop: a SET_SUPERVISOR arrived since the last call? 1 and its args (min periods in us, timeout in
 * ms), or 0; one with timeout 0 is ignored here (counted in cmds_bad, no heartbeat). */
uint8_t proto_take_supervisor(proto_t *p, uint16_t args[3]);
/* Main loop: a PULSE_RUN_ENABLE arrived since the last call? 1 and its length in ms, or 0; one of 0 ms or over
 * PULSE_MS_MAX but PULSE_LATCH is ignored here (counted in cmds_bad). Not a heartbeat. */
uint8_t proto_take_pulse(proto_t *p, uint16_t *ms);
/* Main loop: a heartbeat arrived since the last call? */
uint8_t proto_take_beat(proto_t *p);
/* Main loop: the output's state (FLAG_RUN in the frames built from now on) and whether the supervisor is
 * armed in this boot (the capabilities frame, rebuilt on a change). */
void proto_set_run(proto_t *p, uint8_t on, uint8_t armed);
/* Main loop: queue the input converter's conversions? (fitted and enabled in this boot) */
static inline uint8_t proto_input_enabled(const proto_t *p) { return p->channels_enabled & CHANNEL_INPUT; }

/* The ISR-side functions below are inline and call nothing: in an AVR ISR any call
 * makes gcc save every call-clobbered register, on every TWI interrupt. */

/* The host acknowledged the current frame: its events leave the ring, the pre-built
 * next frame becomes current. */
static inline __attribute__((always_inline)) void proto_retire(proto_t *p)
{
    ring_retire(p->ring, p->cur_n);
    p->cur_n = p->nxt_n;
    p->cur = p->nxt;
    p->nxt = PROTO_NONE;
    p->nxt_valid = 0;
    p->cur_seq++;
    p->cur_sent = 0;
    p->retired_any = 1;
    p->gen++;
}

/* A complete command arrived (crc_residue: CRC-16 over all n bytes, 0 if intact).
 * ISR context or interrupts off. Returns the op, or 0 if the command was ignored. */
static inline __attribute__((always_inline)) uint8_t proto_command(proto_t *p, const uint8_t *buf,
                                                                   uint8_t n, uint16_t crc_residue)
{
    if (cmd_check(buf, n, crc_residue) != CMD_OK) {
        p->cmds_bad++;
        return 0;  /* ignored: the device serves its current frame unchanged */
    }
    /* ACK_POLL first, outside the switch: it is the TWI ISR's longest path (a retire), and the test
     * for it is the switch's first. */
    if (buf[0] == OP_ACK_POLL) {
        /* Retire only what the host has seen of *this* boot (an ACK written to the boot
         * before a reset must not retire the new boot's frame of the same seq); a next
         * frame must be ready, or the host would have nothing new to read (it then gets
         * a stale repeat and re-acks). A heartbeat whatever boot it names. */
        if (!(uint8_t)((buf[1] ^ p->boot_hi) | (buf[2] ^ p->boot_lo) | (buf[3] ^ p->cur_seq)) &&
            p->cur_sent && p->nxt_valid)
            proto_retire(p);
        PROTO_BEAT_SET(p);
        return OP_ACK_POLL;
    }
    switch (buf[0]) {
    case OP_SET_SUPERVISOR:
        /* copied as sent (big-endian), checked and taken by the loop (proto_take_supervisor), which
         * also restarts the heartbeat when it arms: the ISR's part is only this copy */
        for (uint8_t i = 0; i < 6; i++)
            p->sup_args[i] = buf[1 + i];
        p->sup_pending = 1;
        break;
    case OP_PULSE_RUN_ENABLE:
        p->pulse_args[0] = buf[1];
        p->pulse_args[1] = buf[2];
        p->pulse_pending = 1;
        break;
    case OP_SET_DEBOUNCE:
        p->debounce_primary_us = (uint16_t)(buf[1] << 8 | buf[2]);
        p->debounce_secondary_us = (uint16_t)(buf[3] << 8 | buf[4]);
        p->debounce_pending = 1;
        break;
    case OP_CLEAR_COUNTERS:
        p->ring->dropped = 0;
        p->ring->overflow = 0;
        break;
    case OP_INFO:
        p->serve_info = 1;
        break;
    case OP_CAPS:
        /* not while the boot still probes for the converter: served the data frame instead, as an
         * unknown op would be; the host asks again at its next poll */
        p->serve_caps = p->caps_ready;
        break;
    case OP_SET_CHANNELS:
        p->channels_enabled = (uint8_t)(buf[1] & p->channels_fitted);  /* a channel not fitted stays off */
        p->caps_dirty = 1;
        break;
    default:  /* OP_POLL: serve the current frame, retire nothing; a heartbeat */
        PROTO_BEAT_SET(p);
        break;
    }
    return buf[0];
}

/* A read starts (ISR context or interrupts off): the 32 bytes to send. A data frame
 * counts as sent from here on. */
static inline __attribute__((always_inline)) const uint8_t *proto_begin_read(proto_t *p)
{
    uint8_t b;
    if (p->serve_caps) {  /* not a pool buffer: tx keeps its role holder */
        p->serve_caps = 0;
        return p->caps_buf[p->caps_cur];
    }
    if (p->serve_info) {
        p->serve_info = 0;
        b = p->info;
    } else {
        b = p->cur;
        p->cur_sent = 1;
    }
    p->tx = b;
    return p->pool[b];
}

static inline __attribute__((always_inline)) void proto_end_read(proto_t *p) { p->tx = PROTO_NONE; }

/* Main loop: rebuild the unsent current frame with new events, pre-build the next
 * frame, refresh the info frame. Never blocks; interrupts off only to publish. */
void proto_service(proto_t *p, uint32_t now_us, uint32_t uptime_ms);

#endif
