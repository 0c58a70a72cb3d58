#include "proto.h"
#include "cmd.h"
#include "config.h"
#include "port.h"

proto_t g_proto;

/* Events from a fixed ring index: a snapshot of the tail, never the live one (the TWI
 * ISR may retire, i.e. move the tail, while the main loop encodes). */
typedef struct {
    const ring_t *ring;
    uint8_t first;
} ring_view_t;

static const dyno_event_t *view_get(const void *ctx, uint8_t i)
{
    const ring_view_t *v = (const ring_view_t *)ctx;
    return &v->ring->ev[(uint8_t)(v->first + i) & RING_MASK];
}

/* A buffer with no role. With 5 buffers and at most 4 roles one always exists. */
static uint8_t free_buffer(const proto_t *p)
{
    for (uint8_t b = 0; b < PROTO_NBUF; b++)
        if (b != p->cur && b != p->nxt && b != p->info && b != p->tx)
            return b;
    return PROTO_NONE;  /* unreachable */
}

/* Encode the data frame that starts `offset` events after the ring tail.
 *
 * Tail, head and the drop counters are taken together with interrupts off. If the ISR
 * retires meanwhile, slots of this snapshot may be refilled by producers while we read
 * them: the frame is then garbage, but `gen` changed, so the caller never publishes it,
 * and the encoder is bounded by the buffer whatever it reads. */
static uint8_t build(proto_t *p, uint8_t buf, uint8_t seq, uint8_t offset, uint8_t reset,
                     uint32_t now_us)
{
    ring_t *r = p->ring;
    uint8_t head, tail, overflow;
    uint16_t dropped;
    PORT_CRITICAL_BEGIN();
    head = r->head;
    tail = r->tail;
    dropped = r->dropped;
    overflow = r->overflow;
    PORT_CRITICAL_END();
    uint8_t count = (uint8_t)(head - tail);
    uint8_t avail = count > offset ? (uint8_t)(count - offset) : 0u;
    ring_view_t view = {r, (uint8_t)(tail + offset)};
    uint8_t n = frame_fit(view_get, &view, avail);
    uint8_t flags = (uint8_t)((reset ? FLAG_RESET : 0u) | (avail > n ? FLAG_MORE : 0u) |
                              (overflow ? FLAG_OVERFLOW : 0u) | p->run_flag | p->cause_flags);
    frame_encode_data(p->pool[buf], seq, flags, p->boot_id, dropped, now_us, view_get, &view, n, &n);
    proto_meta_t *m = &p->meta[buf];
    m->n = n;
    m->head = head;
    m->dropped = dropped;
    m->built_us = now_us;
    return n;
}

static void build_info(proto_t *p, uint8_t buf, uint32_t uptime_ms)
{
    const dyno_counters_t *c = p->counters;
    frame_info_t info;
    info.seq = p->cur_seq;
    info.flags = (uint8_t)(p->cause_flags | p->run_flag);
    info.boot_id = p->boot_id;
    info.fw_major = FW_VERSION_MAJOR;
    info.fw_minor = FW_VERSION_MINOR;
    info.fw_patch = FW_VERSION_PATCH;
    info.uptime_ms = uptime_ms;
    info.debounce_primary_us = p->debounce_primary_us;
    info.debounce_secondary_us = p->debounce_secondary_us;
    PORT_CRITICAL_BEGIN();  /* u16 counters written by ISRs */
    for (uint8_t k = 0; k < 2; k++) {
        info.lockout[k] = c->lockout[k];
        info.glitch[k] = c->glitch[k];
    }
    info.twi_timeouts = c->twi_timeouts;
    info.bus_errors = c->bus_errors;
    PORT_CRITICAL_END();
    frame_encode_info(p->pool[buf], &info);
}

void proto_init(proto_t *p, ring_t *ring, const dyno_counters_t *counters, uint16_t boot_id,
                uint8_t reset_cause, uint16_t deb_p_us, uint16_t deb_s_us, uint32_t now_us)
{
    uint8_t *raw = (uint8_t *)p;
    for (unsigned i = 0; i < sizeof *p; i++)
        raw[i] = 0;
    p->ring = ring;
    p->counters = counters;
    p->boot_id = boot_id;
    p->boot_hi = (uint8_t)(boot_id >> 8);
    p->boot_lo = (uint8_t)boot_id;
    p->cause_flags = (uint8_t)((reset_cause & 0x0Fu) << FLAG_CAUSE_SHIFT);
    p->debounce_primary_us = deb_p_us;
    p->debounce_secondary_us = deb_s_us;
    p->cur = 0;
    p->nxt = p->info = p->tx = PROTO_NONE;
    p->cur_n = build(p, 0, 0, 0, 1, now_us);
    p->info = 1;
    build_info(p, 1, 0);
    proto_set_fitted(p, 0);
    p->caps_ready = 0;  /* until the boot's probe calls proto_set_fitted */
}

static void build_caps(proto_t *p, uint8_t which)
{
    uint8_t fitted = p->channels_fitted;
    /* CHANNEL_SUPERVISOR: this firmware has the run-enable output; enabled once armed in this boot */
    frame_encode_caps(p->caps_buf[which], p->cur_seq, p->cause_flags, p->boot_id,
                      (uint8_t)(fitted | CHANNEL_SUPERVISOR),
                      (uint8_t)(p->channels_enabled | (p->sup_armed ? CHANNEL_SUPERVISOR : 0u)),
                      (fitted & CHANNEL_INPUT) ? CONVERTER_AD7171 : 0u,
                      (fitted & CHANNEL_INPUT) ? INPUT_RATE_MHZ : 0ul);
}

void proto_set_fitted(proto_t *p, uint8_t channels)
{
    p->channels_fitted = channels;
    p->channels_enabled = 0;
    p->caps_cur = 0;
    build_caps(p, 0);
    p->caps_ready = 1;
}

uint8_t proto_take_debounce(proto_t *p, uint16_t *primary_us, uint16_t *secondary_us)
{
    uint8_t pending;
    PORT_CRITICAL_BEGIN();
    pending = p->debounce_pending;
    p->debounce_pending = 0;
    *primary_us = p->debounce_primary_us;
    *secondary_us = p->debounce_secondary_us;
    PORT_CRITICAL_END();
    if (pending)
        p->info_dirty = 1;
    return pending;
}

uint8_t proto_take_supervisor(proto_t *p, uint16_t args[3])
{
    uint8_t pending;
    PORT_CRITICAL_BEGIN();
    pending = p->sup_pending;
    p->sup_pending = 0;
    for (uint8_t k = 0; k < 3; k++)
        args[k] = (uint16_t)(p->sup_args[2 * k] << 8 | p->sup_args[2 * k + 1]);
    if (pending && !args[2]) {  /* timeout 0 would never time out: the command is ignored */
        p->cmds_bad++;
        pending = 0;
    }
    PORT_CRITICAL_END();
    return pending;
}

uint8_t proto_take_pulse(proto_t *p, uint16_t *ms)
{
    uint8_t pending;
    if (!p->pulse_pending)  /* (one byte: read atomically) the usual pass takes no critical section */
        return 0;
    PORT_CRITICAL_BEGIN();
    pending = p->pulse_pending;
    p->pulse_pending = 0;
    *ms = (uint16_t)(p->pulse_args[0] << 8 | p->pulse_args[1]);
    if (pending && (!*ms || (*ms > PULSE_MS_MAX && *ms != PULSE_LATCH))) {
        p->cmds_bad++;
        pending = 0;
    }
    PORT_CRITICAL_END();
    return pending;
}

uint8_t proto_take_beat(proto_t *p)
{
#ifdef __AVR__
    (void)p;
    if (!(GPIOR0 & _BV(PROTO_BEAT_BIT)))
        return 0;
    GPIOR0 &= (uint8_t)~_BV(PROTO_BEAT_BIT);  /* cbi: atomic (a beat in between is this one) */
    return 1;
#else
    uint8_t b = p->beat;
    p->beat = 0;
    return b;
#endif
}

void proto_set_run(proto_t *p, uint8_t on, uint8_t armed)
{
    uint8_t flag = on ? FLAG_RUN : 0u;
    if (flag != p->run_flag) {
        p->run_flag = flag;  /* the unsent frames are rebuilt by proto_service (their flags byte differs) */
        p->info_dirty = 1;
    }
    if (armed != p->sup_armed) {
        p->sup_armed = armed;
        p->caps_dirty = 1;
    }
}

/* The RUN flag of a built data frame differs from the output's state now. */
static uint8_t run_stale(const proto_t *p, uint8_t buf)
{
    return (uint8_t)((p->pool[buf][4] & FLAG_RUN) != p->run_flag);
}

void proto_service(proto_t *p, uint32_t now_us, uint32_t uptime_ms)
{
    ring_t *r = p->ring;
    uint8_t gen, seq, cur, buf, reset;

    /* 1. The unsent current frame takes any new events (or a fresh t0 when empty). */
    if (!p->cur_sent) {
        cur = p->cur;
        const proto_meta_t *m = &p->meta[cur];
        if (m->head != r->head || m->dropped != r->dropped || run_stale(p, cur) ||
            (m->n == 0 && (uint32_t)(now_us - m->built_us) >= PROTO_EMPTY_REFRESH_US)) {
            PORT_CRITICAL_BEGIN();
            gen = p->gen;
            seq = p->cur_seq;
            reset = !p->retired_any;
            buf = free_buffer(p);
            PORT_CRITICAL_END();
            uint8_t n = build(p, buf, seq, 0, reset, now_us);
            PORT_CRITICAL_BEGIN();
            if (gen == p->gen && !p->cur_sent) {
                p->cur = buf;
                p->cur_n = n;
                p->nxt = PROTO_NONE;  /* it followed the old cur's events */
                p->nxt_valid = 0;
                p->gen++;
            }
            PORT_CRITICAL_END();
        }
    }

    /* 2. Pre-build the next frame so an ACK_POLL can swap it in inside the ISR; the
     * host has not seen it, so it too takes new events until the swap. */
    uint8_t nxt = p->nxt;  /* once: the ISR may retire (nxt = NONE) at any moment */
    if (!p->nxt_valid || nxt >= PROTO_NBUF || p->meta[nxt].head != r->head || run_stale(p, nxt)) {
        uint8_t offset;
        PORT_CRITICAL_BEGIN();
        gen = p->gen;
        seq = (uint8_t)(p->cur_seq + 1u);
        offset = p->cur_n;
        buf = free_buffer(p);
        PORT_CRITICAL_END();
        uint8_t n = build(p, buf, seq, offset, 0, now_us);
        PORT_CRITICAL_BEGIN();
        if (gen == p->gen) {  /* cur unchanged, so nxt still follows it */
            p->nxt = buf;
            p->nxt_n = n;
            p->nxt_valid = 1;
        }
        PORT_CRITICAL_END();
    }

    /* 3. The capabilities frame after a SET_CHANNELS or the supervisor's arming, into the buffer the ISR is not serving. */
    if (p->caps_dirty) {
        uint8_t other = (uint8_t)(p->caps_cur ^ 1u);
        p->caps_dirty = 0;
        build_caps(p, other);
        PORT_CRITICAL_BEGIN();
        p->caps_cur = other;
        PORT_CRITICAL_END();
    }

    /* 4. Info frame (uptime), never built in the ISR. */
    if (p->info_dirty || (uint32_t)(uptime_ms - p->info_built_ms) >= INFO_REFRESH_MS) {
        PORT_CRITICAL_BEGIN();
        buf = free_buffer(p);
        p->info_dirty = 0;
        PORT_CRITICAL_END();
        build_info(p, buf, uptime_ms);
        p->info_built_ms = uptime_ms;
        PORT_CRITICAL_BEGIN();
        p->info = buf;
        PORT_CRITICAL_END();
    }
}
