/* Native unit tests of the firmware's pure-C modules (crc16, crc32c, frame, cmd, ring,
 * cobs, tstamp, proto), run on the build machine by `make -C firmware test`.
 * Frames and commands are checked byte for byte against the repository's golden
 * vectors (dyno/protocol/vectors/v2.hex), which the Python host tests check too. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "cmd.h"
#include "cobs.h"
#include "counters.h"
#include "crc16.h"
#include "crc32c.h"
#include "frame.h"
#include "proto.h"
#include "ring.h"
#include "tstamp.h"

static int failures, checks;
#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; \
    printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)


static size_t unhex(const char *s, uint8_t *out, size_t max)
{
    size_t n = 0;
    if (strcmp(s, "-") == 0)
        return 0;
    while (s[0] && s[1] && n < max) {
        unsigned v;
        if (sscanf(s, "%2x", &v) != 1)
            break;
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static const char *field(const char *line, const char *key)
{
    static char buf[512];
    const char *p = strstr(line, key);
    if (!p)
        return NULL;
    p += strlen(key);
    size_t n = strcspn(p, " \n");
    if (n >= sizeof buf)
        n = sizeof buf - 1;
    memcpy(buf, p, n);
    buf[n] = 0;
    return buf;
}

static uint8_t parse_events(const char *s, dyno_event_t *ev)
{
    uint8_t n = 0;
    if (strcmp(s, "-") == 0)
        return 0;
    while (*s) {
        unsigned ch, code = 0, status = 0;
        unsigned long t;
        int used = 0;
        if (sscanf(s, "%u@%lu%n", &ch, &t, &used) < 2)
            break;
        s += used;
        if (*s == ':') {
            sscanf(s, ":%u:%u%n", &code, &status, &used);
            s += used;
        }
        ev[n].tag = (uint8_t)ch;
        ev[n].t_us = (uint32_t)t;
        ev[n].code = (uint16_t)code;
        ev[n].status = (uint8_t)status;
        n++;
        if (*s == ',')
            s++;
    }
    return n;
}

static void test_vectors(const char *path)
{
    FILE *f = fopen(path, "r");
    CHECK(f != NULL, "cannot open %s", path);
    if (!f)
        return;
    char line[1024];
    int n_crc = 0, n_frame = 0, n_info = 0, n_cmd = 0, n_badcmd = 0;
    while (fgets(line, sizeof line, f)) {
        uint8_t want[64], got[64], data[64];
        if (strncmp(line, "crc32c ", 7) == 0) {
            char dhex[256];
            unsigned long c;
            sscanf(line + 7, "%255s %lx", dhex, &c);
            size_t n = unhex(dhex, data, sizeof data);
            CHECK(crc32c(data, (uint8_t)n) == (uint32_t)c, "crc32c %s", dhex);
            n_crc++;
        } else if (strncmp(line, "frame ", 6) == 0) {
            dyno_event_t ev[8];
            unsigned seq = (unsigned)atoi(field(line, "seq="));
            unsigned flags = (unsigned)atoi(field(line, "flags="));
            unsigned dropped = (unsigned)atoi(field(line, "dropped="));
            unsigned boot = (unsigned)atoi(field(line, "boot="));
            unsigned long t0 = strtoul(field(line, "t0="), NULL, 10);
            uint8_t n = parse_events(field(line, "events="), ev);
            size_t wn = unhex(field(line, "hex="), want, sizeof want);
            CHECK(frame_fit(frame_array_get, ev, n) == n, "all events fit: %s", line);
            uint8_t len = frame_encode_data(got, (uint8_t)seq, (uint8_t)flags, (uint16_t)boot,
                                            (uint16_t)dropped, (uint32_t)t0, frame_array_get, ev, n, NULL);
            CHECK(len == want[1], "frame length %u: %s", len, line);
            CHECK(memcmp(got, want, wn) == 0, "frame bytes: %s", line);
            /* Vectors may be stored without padding; the rest must be zero. */
            for (size_t i = wn; i < FRAME_MAX; i++)
                CHECK(got[i] == 0, "padding at %zu", i);
            n_frame++;
        } else if (strncmp(line, "info ", 5) == 0) {
            unsigned a, b, c, l0, l1, g0, g1;
            sscanf(field(line, "fw="), "%u.%u.%u", &a, &b, &c);
            sscanf(field(line, "lock="), "%u,%u", &l0, &l1);
            sscanf(field(line, "glitch="), "%u,%u", &g0, &g1);
            frame_info_t info;
            info.seq = (uint8_t)atoi(field(line, "seq="));
            info.flags = (uint8_t)atoi(field(line, "flags="));
            info.boot_id = (uint16_t)atoi(field(line, "boot="));
            info.fw_major = (uint8_t)a;
            info.fw_minor = (uint8_t)b;
            info.fw_patch = (uint8_t)c;
            info.uptime_ms = (uint32_t)strtoul(field(line, "uptime_ms="), NULL, 10);
            info.debounce_primary_us = (uint16_t)atoi(field(line, "deb_p="));
            info.debounce_secondary_us = (uint16_t)atoi(field(line, "deb_s="));
            info.lockout[0] = (uint16_t)l0;
            info.lockout[1] = (uint16_t)l1;
            info.glitch[0] = (uint16_t)g0;
            info.glitch[1] = (uint16_t)g1;
            info.twi_timeouts = (uint8_t)atoi(field(line, "twi_timeouts="));
            info.bus_errors = (uint8_t)atoi(field(line, "bus_errors="));
            size_t wn = unhex(field(line, "hex="), want, sizeof want);
            uint8_t len = frame_encode_info(got, &info);
            CHECK(len == FRAME_INFO_LEN, "info length %u", len);
            CHECK(memcmp(got, want, wn) == 0, "info bytes: %s", line);
            n_info++;
        } else if (strncmp(line, "cmd ", 4) == 0) {
            size_t n = unhex(field(line, "hex="), data, sizeof data);
            unsigned op = (unsigned)atoi(field(line, "op="));
            CHECK(data[0] == op, "op byte");
            CHECK(cmd_check(data, (uint8_t)n, crc16(data, (uint8_t)n)) == CMD_OK, "cmd ok: %s", line);
            /* The ISR's incremental check: CRC over message + CRC is zero. */
            CHECK(crc16(data, (uint8_t)n) == 0, "residue: %s", line);
            n_cmd++;
        } else if (strncmp(line, "badcmd ", 7) == 0) {
            size_t n = unhex(field(line, "hex="), data, sizeof data);
            const char *cause = field(line, "cause=");
            uint8_t want_err = strcmp(cause, "crc") == 0 ? CMD_ERR_CRC
                             : strcmp(cause, "op") == 0 ? CMD_ERR_OP
                             : strcmp(cause, "length") == 0 ? CMD_ERR_LENGTH : CMD_ERR_SHORT;
            uint8_t err = cmd_check(data, (uint8_t)n, crc16(data, (uint8_t)n));
            CHECK(err == want_err, "badcmd %s: got %u", cause, err);
            n_badcmd++;
        }
    }
    fclose(f);
    CHECK(n_crc >= 4 && n_frame >= 10 && n_info >= 1 && n_cmd >= 6 && n_badcmd >= 4,
          "vector counts crc32c=%d frame=%d info=%d cmd=%d badcmd=%d", n_crc, n_frame, n_info,
          n_cmd, n_badcmd);
    printf("vectors: %d crc32c, %d frames, %d info, %d cmd, %d badcmd\n", n_crc, n_frame, n_info,
           n_cmd, n_badcmd);
}

static void test_crc(void)
{
    const uint8_t s[] = "123456789";
    CHECK(crc16(s, 9) == 0x29B1, "check value");
    uint16_t c = CRC16_INIT;
    for (int i = 0; i < 9; i++)
        c = crc16_update(c, s[i]);
    CHECK(c == 0x29B1, "incremental");
    CHECK(crc32c(s, 9) == 0xE3069283u, "crc32c check value");
}

static void test_frame_fit(void)
{
    dyno_event_t ev[8];
    memset(ev, 0, sizeof ev);
    for (int i = 0; i < 8; i++) {
        ev[i].tag = TAG_PRIMARY;
        ev[i].t_us = 1000u + 10u * (uint32_t)i;
    }
    CHECK(frame_fit(frame_array_get, ev, 8) == 5, "five 3-byte events fill 15 bytes");
    ev[2].tag = TAG_ADC;  /* 3 + 3 + 6 = 12, the next one would make 15 */
    CHECK(frame_fit(frame_array_get, ev, 8) == 4, "adc takes 6 bytes");
    ev[3].tag = TAG_ADC;
    CHECK(frame_fit(frame_array_get, ev, 8) == 3, "two adc do not fit after two hall");
    ev[3].tag = TAG_PRIMARY;
    ev[2].tag = TAG_PRIMARY;
    ev[3].t_us = 1000u + 32767u;
    CHECK(frame_fit(frame_array_get, ev, 4) == 4, "dt 32767 fits");
    ev[3].t_us = 1000u + 32768u;
    CHECK(frame_fit(frame_array_get, ev, 4) == 3, "dt 32768 starts a new frame");
    ev[1].t_us = 1000u - 32768u;
    CHECK(frame_fit(frame_array_get, ev, 4) == 3, "dt -32768 fits");
    ev[1].t_us = 1000u - 32769u;
    CHECK(frame_fit(frame_array_get, ev, 4) == 1, "dt -32769 does not");
    /* Across the 2^32 wrap, dt is still small. */
    ev[0].t_us = 0xFFFFFFF0u;
    ev[1].t_us = 0x00000010u;
    CHECK(frame_fit(frame_array_get, ev, 2) == 2, "wrap");
}

/* A reader racing producers: every event turns into a 6-byte ADC event once read, as if
 * the slots were refilled between frame_fit and the encoder. */
static dyno_event_t race_ev[8];
static const dyno_event_t *racing_get(const void *ctx, uint8_t i)
{
    (void)ctx;
    const dyno_event_t *e = &race_ev[i];
    race_ev[i].tag = TAG_ADC;
    return e;
}

static void test_encoder_bounded(void)
{
    uint8_t buf[FRAME_MAX + 8], n_done = 99;
    memset(buf, 0xA5, sizeof buf);
    for (int i = 0; i < 8; i++) {
        race_ev[i].tag = TAG_PRIMARY;
        race_ev[i].t_us = 100u + (uint32_t)i;
    }
    uint8_t n = frame_fit(frame_array_get, race_ev, 8);
    CHECK(n == 5, "fit five hall edges");
    uint8_t len = frame_encode_data(buf, 0, 0, 1, 0, 0, racing_get, NULL, n, &n_done);
    CHECK(len <= FRAME_MAX && n_done == 2, "encoder stops at the buffer: L=%u, %u events", len, n_done);
    int guard = 1;
    for (unsigned i = FRAME_MAX; i < sizeof buf; i++)
        guard &= buf[i] == 0xA5;
    CHECK(guard, "nothing written past the 32-byte frame");
    /* Even asked for 255 events of 6 bytes. */
    memset(buf, 0xA5, sizeof buf);
    len = frame_encode_data(buf, 0, 0, 1, 0, 0, frame_array_get, race_ev, 8, &n_done);
    guard = 1;
    for (unsigned i = FRAME_MAX; i < sizeof buf; i++)
        guard &= buf[i] == 0xA5;
    CHECK(guard && n_done == 2 && len == 13 + 12 + 4, "bounded with too many events asked");
}

static void test_ring(void)
{
    static ring_t r;
    ring_init(&r);
    uint32_t pushed = 0, popped = 0;
    /* Many passes over the u8 index wrap (256) and the slot wrap (RING_SIZE). */
    for (int round = 0; round < 1000; round++) {
        int k = 1 + round % (int)RING_SIZE;
        for (int i = 0; i < k; i++)
            CHECK(ring_push(&r, TAG_SECONDARY, pushed++, 0, 0), "push");
        CHECK(ring_count(&r) == k, "count");
        for (int i = 0; i < k; i++)
            CHECK(ring_peek(&r, (uint8_t)i)->t_us == popped + (uint32_t)i, "fifo order");
        ring_retire(&r, (uint8_t)k);
        popped += (uint32_t)k;
    }
    CHECK(r.dropped == 0 && !r.overflow, "no drop");
    for (unsigned i = 0; i < RING_SIZE; i++)
        ring_push(&r, TAG_PRIMARY, i, 0, 0);
    CHECK(ring_count(&r) == RING_SIZE, "full");
    CHECK(!ring_push(&r, TAG_PRIMARY, 999, 0, 0), "full ring refuses");
    CHECK(!ring_push(&r, TAG_PRIMARY, 1000, 0, 0), "full ring refuses");
    CHECK(r.dropped == 2 && r.overflow, "drops counted");
    CHECK(ring_peek(&r, RING_SIZE - 1)->t_us == RING_SIZE - 1, "old events kept");
    CHECK(ring_peek(&r, RING_SIZE - 1)->tag == TAG_PRIMARY, "no gap mark before the drops");
    ring_retire(&r, 1);
    CHECK(ring_push(&r, TAG_SECONDARY, 2000, 0, 0), "room again");
    CHECK(ring_peek(&r, RING_SIZE - 1)->tag == (TAG_SECONDARY | TAG_GAP), "first event after drops marked");
    ring_retire(&r, 1);
    ring_push(&r, TAG_SECONDARY, 2001, 0, 0);
    CHECK(ring_peek(&r, RING_SIZE - 1)->tag == TAG_SECONDARY, "only the first one");
    r.dropped = 0xFFFF;
    ring_push(&r, TAG_PRIMARY, 0, 0, 0);
    CHECK(r.dropped == 0, "dropped wraps like the u16 on the wire");
}

static void test_tstamp(void)
{
    /* Plain: base + ticks/2. */
    CHECK(tstamp_extend(0, 0, 0) == 0, "zero");
    CHECK(tstamp_extend(32768, 2001, 0) == 32768 + 1000, "half-us ticks truncate");
    CHECK(tstamp_extend(0, 0xFFFF, 0) == 32767, "top of the timer");
    /* Overflow pending and counter wrapped (small): base is one overflow behind. */
    CHECK(tstamp_extend(32768, 4, 1) == 65536 + 2, "pending overflow, small count");
    /* Overflow pending but counter read before the wrap (large): base is right. */
    CHECK(tstamp_extend(32768, 0xFFFE, 1) == 32768 + 32767, "pending overflow, large count");
    /* Monotonic through a simulated overflow sequence, counted in ticks. */
    uint32_t base = 0, last = 0;
    int ok = 1;
    for (uint32_t ticks = 0; ticks < 5u * 65536u; ticks += 7) {
        uint16_t tcnt = (uint16_t)ticks;
        uint32_t true_base = (ticks >> 16) * 32768u;
        /* The ISR lags: for the first 64 ticks after a wrap base is stale. */
        uint8_t pending = (ticks >= 65536u && (ticks & 0xFFFFu) < 64u);
        base = pending ? true_base - 32768u : true_base;
        uint32_t t = tstamp_extend(base, tcnt, pending);
        if (t != ticks / 2u || t < last)
            ok = 0;
        last = t;
    }
    CHECK(ok, "monotonic and exact across overflows with a lagging ISR");
    /* u32 wrap at 2^32 us: base wraps, times wrap, differences stay right. */
    uint32_t b = 0xFFFF8000u;  /* 2^32 - 32768 */
    uint32_t t1 = tstamp_extend(b, 0xFFF0, 0);
    uint32_t t2 = tstamp_extend(b, 0x0010, 1);  /* after the wrap, ISR pending */
    CHECK(t1 == 0xFFFFFFF8u, "just before 2^32: %u", t1);
    CHECK(t2 == 8u, "just after 2^32: %u", t2);
    CHECK((uint32_t)(t2 - t1) == 16u, "difference across 2^32");
}

static void test_cobs(void)
{
    uint8_t in[253], enc[260], dec[260];
    srand(1);
    for (int trial = 0; trial < 2000; trial++) {
        uint8_t n = (uint8_t)(rand() % 40);
        if (trial == 0) n = 253;
        for (int i = 0; i < n; i++)
            in[i] = (uint8_t)(rand() % 3 == 0 ? 0 : rand() % 256);
        uint8_t e = cobs_encode(in, n, enc);
        int zero = 0;
        for (int i = 0; i < e; i++)
            zero |= enc[i] == 0;
        CHECK(!zero, "no zero in COBS output");
        CHECK(e <= n + 2, "overhead");
        uint8_t d = cobs_decode(enc, e, dec);
        CHECK(d == n && memcmp(in, dec, n) == 0, "round trip n=%u", n);
    }
    const uint8_t bad[] = {5, 1, 2};
    CHECK(cobs_decode(bad, 3, dec) == 0xFF, "code past the end is malformed");
    const uint8_t known_in[] = {0x11, 0x22, 0x00, 0x33};
    const uint8_t known_out[] = {0x03, 0x11, 0x22, 0x02, 0x33};
    CHECK(cobs_encode(known_in, 4, enc) == 5 && memcmp(enc, known_out, 5) == 0, "known");
}

/* --- proto: the ack/re-send state machine, with a tiny host model -------------- */

static uint8_t mk_cmd(uint8_t *out, uint8_t op, const uint8_t *args, uint8_t nargs)
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

static void test_proto_basics(void)
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
static void test_proto_lossless(void)
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

int main(int argc, char **argv)
{
    test_crc();
    test_frame_fit();
    test_encoder_bounded();
    test_ring();
    test_tstamp();
    test_cobs();
    test_proto_basics();
    test_proto_lossless();
    if (argc > 1)
        test_vectors(argv[1]);
    else
        CHECK(0, "usage: test_native path/to/v1.hex");
    printf("%d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
