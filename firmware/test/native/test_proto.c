/* Native unit tests of proto.c: the ack/re-send state machine against a tiny host model
 * (boot ids, stale ACKs, re-sends, and a long lossless run with random faults). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cmd.h"
#include "counters.h"
#include "crc16.h"
#include "crc32c.h"
#include "frame.h"
#include "proto.h"
#include "ring.h"
#include "test_native.h"

uint8_t mk_cmd(uint8_t *out, uint8_t op, const uint8_t *args, uint8_t nargs)
{
    out[0] = op;
    memcpy(out + 1, args, nargs);
    uint16_t c = crc16(out, (uint8_t)(1 + nargs));
    out[1 + nargs] = (uint8_t)(c >> 8);
    out[2 + nargs] = (uint8_t)c;
    return (uint8_t)(3 + nargs);
}

static void send_cmd(proto_t *p, const uint8_t *c, uint8_t n)
{
    proto_command(p, c, n, crc16(c, n));
}

static void read_frame(proto_t *p, uint8_t *out)
{
    memcpy(out, proto_begin_read(p), FRAME_MAX);
    proto_end_read(p);
}

static int frame_ok(const uint8_t *f)
{
    uint8_t len = f[1];
    if (f[0] != FRAME_VERSION || len < FRAME_HEADER_LEN + FRAME_CRC_LEN || len > 32)
        return 0;
    uint32_t want = (uint32_t)f[len - 4] << 24 | (uint32_t)f[len - 3] << 16 |
                    (uint32_t)f[len - 2] << 8 | f[len - 1];
    return crc32c(f, (uint8_t)(len - 4)) == want;
}

/* ACK_POLL(boot, seq) */
static uint8_t mk_ack(uint8_t *out, uint16_t boot, uint8_t seq)
{
    uint8_t args[3] = {(uint8_t)(boot >> 8), (uint8_t)boot, seq};
    return mk_cmd(out, OP_ACK_POLL, args, 3);
}

#define BOOT 0x1234u

void test_proto_basics(void)
{
    static ring_t r;
    static proto_t p;
    static dyno_counters_t cnt;
    uint8_t c[8], f[32], f2[32];
    uint16_t dp = 0, ds = 0;
    ring_init(&r);
    memset(&cnt, 0, sizeof cnt);
    proto_init(&p, &r, &cnt, BOOT, 0x8 /* WDRF */, 10000, 6000, 1000);
    proto_service(&p, 1000, 1);
    read_frame(&p, f);
    CHECK(frame_ok(f) && f[2] == KIND_DATA && f[3] == 0 && f[4] == (FLAG_RESET | 0x80),
          "first frame: seq 0, RESET, cause WDRF in bits 4..7 (0x%02x)", f[4]);
    CHECK(f[5] == 0x12 && f[6] == 0x34, "boot id in the frame");
    /* New events while seq 0 is frozen go to the next frames, not into seq 0. */
    ring_push(&r, TAG_PRIMARY, 2000, 0, 0);
    proto_service(&p, 2100, 2);
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "a sent frame is frozen");
    /* Wrong seq: no retire. */
    send_cmd(&p, c, mk_ack(c, BOOT, 7));
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "wrong ack -> same frame again");
    /* Right seq, another boot's id (an ACK written before a reset): no retire. */
    send_cmd(&p, c, mk_ack(c, BOOT - 1u, 0));
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "ack of another boot retires nothing");
    /* A v1 ACK_POLL (4 bytes) is a length error under v2. */
    uint8_t one = 0;
    send_cmd(&p, c, mk_cmd(c, OP_ACK_POLL, &one, 1));
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "v1 ack ignored");
    /* Corrupted ack: ignored. */
    uint8_t n = mk_ack(c, BOOT, 0);
    c[3] ^= 1;
    send_cmd(&p, c, n);
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "corrupted ack ignored");
    /* Good ack: seq 1 with the event, no RESET. */
    send_cmd(&p, c, mk_ack(c, BOOT, 0));
    read_frame(&p, f);
    CHECK(frame_ok(f) && f[3] == 1 && !(f[4] & FLAG_RESET) && f[1] == 20 && f[13] == TAG_PRIMARY,
          "ack -> next frame with the event");
    /* Ack for seq 1 before the main loop pre-built seq 2: no retire (the host re-reads). */
    send_cmd(&p, c, mk_ack(c, BOOT, 1));
    read_frame(&p, f2);
    CHECK(memcmp(f, f2, 32) == 0, "no next frame ready -> same frame");
    proto_service(&p, 3000, 3);
    send_cmd(&p, c, mk_ack(c, BOOT, 1));
    read_frame(&p, f);
    CHECK(frame_ok(f) && f[3] == 2 && f[1] == 17, "empty seq 2");
    /* SET_DEBOUNCE is taken by the main loop and shows in the info frame. */
    CHECK(!proto_take_debounce(&p, &dp, &ds), "nothing pending");
    uint8_t d[4] = {0x13, 0x88, 0x0B, 0xB8};  /* 5000, 3000 */
    send_cmd(&p, c, mk_cmd(c, OP_SET_DEBOUNCE, d, 4));
    CHECK(proto_take_debounce(&p, &dp, &ds) && dp == 5000 && ds == 3000, "debounce taken");
    CHECK(!proto_take_debounce(&p, &dp, &ds), "taken once");
    cnt.lockout[0] = 0x0102;
    cnt.glitch[1] = 0x0304;
    cnt.twi_timeouts = 5;
    cnt.bus_errors = 6;
    proto_service(&p, 4000, 4);
    send_cmd(&p, c, mk_cmd(c, OP_INFO, NULL, 0));
    read_frame(&p, f2);
    CHECK(frame_ok(f2) && f2[2] == KIND_INFO && f2[1] == 32, "info frame");
    CHECK(f2[5] == 0x12 && f2[6] == 0x34 && f2[4] == 0x80, "boot id and cause in info");
    CHECK(f2[7] == FW_VERSION_MAJOR, "fw major = protocol version");
    CHECK(f2[14] == 0x13 && f2[15] == 0x88 && f2[16] == 0x0B && f2[17] == 0xB8, "debounce in info");
    CHECK(f2[18] == 1 && f2[19] == 2 && f2[24] == 3 && f2[25] == 4 && f2[26] == 5 && f2[27] == 6,
          "counters in info");
    read_frame(&p, f2);
    CHECK(f2[2] == KIND_DATA && memcmp(f, f2, 32) == 0, "then data frames again");
    /* Overflow: flag + count, CLEAR_COUNTERS zeroes both. */
    send_cmd(&p, c, mk_ack(c, BOOT, 2));  /* retire seq 2 */
    for (unsigned i = 0; i < RING_SIZE + 3; i++)
        ring_push(&r, TAG_SECONDARY, 5000 + i, 0, 0);
    proto_service(&p, 6000, 6);
    read_frame(&p, f);
    CHECK(frame_ok(f) && f[3] == 3, "seq 3");
    CHECK((f[4] & (FLAG_OVERFLOW | FLAG_MORE)) == (FLAG_OVERFLOW | FLAG_MORE), "overflow+more flags 0x%02x", f[4]);
    CHECK(f[7] == 0 && f[8] >= 3, "dropped count %u", f[8]);
    send_cmd(&p, c, mk_cmd(c, OP_CLEAR_COUNTERS, NULL, 0));
    CHECK(r.dropped == 0 && r.overflow == 0, "cleared");
}

/* Host model: decode a frame, check sequence, collect events. */
typedef struct {
    int have_seq;
    uint8_t last_seq;
    uint8_t last[32];
    uint32_t next_expected_t;  /* events carry t = 0, 1, 2, ... in order */
    long accepted, stale, bad, events, order_errors;
} host_t;

static void host_accept(host_t *h, const uint8_t *f)
{
    if (!frame_ok(f)) { h->bad++; return; }
    if (h->have_seq && memcmp(f, h->last, f[1]) == 0) { h->stale++; return; }
    uint8_t seq = f[3];
    if (h->have_seq && seq != (uint8_t)(h->last_seq + 1)) { h->bad++; return; }
    memcpy(h->last, f, 32);
    h->last_seq = seq;
    h->have_seq = 1;
    h->accepted++;
    uint32_t t0 = (uint32_t)f[9] << 24 | (uint32_t)f[10] << 16 | (uint32_t)f[11] << 8 | f[12];
    for (uint8_t i = FRAME_HEADER_LEN; i < f[1] - FRAME_CRC_LEN;) {
        uint8_t tag = f[i];
        int16_t dt = (int16_t)(f[i + 1] << 8 | f[i + 2]);
        uint32_t udt = (uint32_t)(int32_t)dt;
        uint32_t t = (uint32_t)(t0 + udt);
        if (t != h->next_expected_t)
            h->order_errors++;
        h->next_expected_t = t + 1;
        h->events++;
        i = (uint8_t)(i + (tag == TAG_ADC ? 6 : 3));
    }
}

/* Randomised: events trickle in, the "bus" corrupts reads and acks, the host re-reads;
 * every event must arrive exactly once and in order. */
void test_proto_lossless(void)
{
    static ring_t r;
    static proto_t p;
    host_t h;
    memset(&h, 0, sizeof h);
    ring_init(&r);
    static dyno_counters_t cnt;
    proto_init(&p, &r, &cnt, BOOT, 1, 10000, 6000, 0);
    srand(7);
    uint32_t produced = 0;
    for (int step = 0; step < 200000; step++) {
        int burst = rand() % 4;  /* 0..3 new events per poll: a bit above the rig's rate */
        for (int i = 0; i < burst && produced < 400000; i++) {
            uint8_t tag = (uint8_t)(1 + rand() % 3);
            if (ring_push(&r, tag, produced, 123, 5))
                produced++;
        }
        proto_service(&p, produced, (uint32_t)step);
        uint8_t c[8], f[32];
        uint8_t n = h.have_seq ? mk_ack(c, BOOT, h.last_seq) : mk_cmd(c, OP_POLL, NULL, 0);
        if (rand() % 20 == 0)
            c[rand() % n] ^= (uint8_t)(1u << (rand() % 8));  /* corrupted command */
        send_cmd(&p, c, n);
        if (rand() % 7 == 0)
            proto_service(&p, produced, (uint32_t)step);  /* main loop interleaves */
        read_frame(&p, f);
        int fault = rand() % 25;
        if (fault == 0)
            f[rand() % 32] ^= (uint8_t)(1u << (rand() % 8));  /* bit flip on the wire */
        else if (fault == 1)
            continue;  /* NACK / timeout: the host never sees it */
        host_accept(&h, f);
    }
    /* Drain. */
    for (int step = 0; step < 1000; step++) {
        uint8_t c[8], f[32];
        proto_service(&p, produced, 0);
        send_cmd(&p, c, mk_ack(c, BOOT, h.last_seq));
        read_frame(&p, f);
        host_accept(&h, f);
    }
    CHECK(r.dropped == 0, "no ring overflow in this test");
    CHECK(h.events == (long)produced, "every event delivered once: %ld of %u", h.events, produced);
    CHECK(h.order_errors == 0, "in order (%ld errors)", h.order_errors);
    CHECK(h.stale > 0 && h.bad > 0, "faults were exercised (stale %ld, bad %ld)", h.stale, h.bad);
    printf("proto lossless: %u events, %ld frames accepted, %ld stale repeats, %ld bad\n",
           produced, h.accepted, h.stale, h.bad);
}

