/* Native unit tests of the run-enable supervisor (issue 37): supervisor.c's state machine, and proto's
 * part (the heartbeat, SET_SUPERVISOR taken by the loop, FLAG_RUN, the capabilities bits). The wire bytes
 * are checked against dyno/protocol/vectors/v2-supervisor.hex in test_native.c. */
#include <string.h>
#include "cmd.h"
#include "crc16.h"
#include "frame.h"
#include "proto.h"
#include "ring.h"
#include "supervisor.h"
#include "test_native.h"

#define MS 1000u

static int ev_is(const dyno_event_t *e, uint32_t t_us, uint16_t code, uint8_t status)
{
    return e->tag == TAG_SUPERVISOR && e->t_us == t_us && e->code == code && e->status == status;
}

void test_supervisor_machine(void)
{
    supervisor_t s;
    dyno_event_t ev;
    memset(&ev, 0, sizeof ev);
    supervisor_init(&s);
    /* Boot: not armed, off; nothing turns it on but the arm, nothing yields events. */
    CHECK(!s.armed && !s.on, "boot: off, not armed");
    CHECK(!supervisor_check(&s, 10000000u, &ev), "no heartbeat event before arming");
    CHECK(!supervisor_period(&s, 0, 10, 5, &ev), "no over-speed event before arming");
    supervisor_beat(&s, 123);
    CHECK(!s.on, "a heartbeat does not arm");

    /* Arm at t = 1 s: 14285 us (4200 rpm), 7692 us (7800 rpm), 200 ms. */
    supervisor_arm(&s, 14285, 7692, 200, 1000000u, &ev);
    CHECK(s.armed && s.on, "armed: on");
    CHECK(ev_is(&ev, 1000000u, 0, SUP_ON), "ON event at the arm");

    /* Heartbeat: off only after *more than* the timeout since the last beat. */
    CHECK(!supervisor_check(&s, 1000000u + 200u * MS, &ev), "exactly the timeout: still on");
    supervisor_beat(&s, 1150000u);
    CHECK(!supervisor_check(&s, 1000000u + 200u * MS + 1u, &ev), "beat restarted the timeout");
    CHECK(!supervisor_check(&s, 1350000u, &ev) && s.on, "150 + 200 ms: on");
    CHECK(supervisor_check(&s, 1350001u, &ev) && !s.on, "past the timeout: off");
    CHECK(ev_is(&ev, 1350000u, 200, SUP_HEARTBEAT), "HEARTBEAT event: last beat + timeout, code = timeout");
    /* Latched: beats, periods and time change nothing until the next arm. */
    supervisor_beat(&s, 1400000u);
    CHECK(!supervisor_check(&s, 1400001u, &ev) && !s.on, "latched off after a beat");
    CHECK(!supervisor_period(&s, 0, 100, 1400002u, &ev) && !s.on, "latched: no further event");

    /* Re-arm (the host's SET_SUPERVISOR): on again, the heartbeat restarted from the arm. */
    supervisor_arm(&s, 14285, 7692, 200, 2000000u, &ev);
    CHECK(s.on && ev_is(&ev, 2000000u, 0, SUP_ON), "re-armed");
    CHECK(!supervisor_check(&s, 2200000u, &ev), "re-arm restarts the heartbeat");

    /* Over-speed: a period at the minimum is fine, one shorter turns it off with the period and the
     * pulse's time; the secondary likewise with its own status. */
    CHECK(!supervisor_period(&s, 0, 14285, 2010000u, &ev) && s.on, "period = min: on");
    CHECK(!supervisor_period(&s, 1, 7692, 2010000u, &ev) && s.on, "secondary at its min: on");
    CHECK(supervisor_period(&s, 0, 13043, 2023043u, &ev) && !s.on, "4600 rpm primary: off");
    CHECK(ev_is(&ev, 2023043u, 13043, SUP_OVERSPEED_PRIMARY), "OVERSPEED_PRIMARY event");
    supervisor_arm(&s, 14285, 7692, 200, 3000000u, &ev);
    CHECK(supervisor_period(&s, 1, 7000, 3007000u, &ev) && !s.on, "secondary over-speed: off");
    CHECK(ev_is(&ev, 3007000u, 7000, SUP_OVERSPEED_SECONDARY), "OVERSPEED_SECONDARY event");

    /* A minimum of 0: that channel is not checked. */
    supervisor_arm(&s, 14285, 0, 65535, 4000000u, &ev);
    CHECK(!supervisor_period(&s, 1, 1, 4000100u, &ev) && s.on, "secondary unchecked");
    CHECK(!supervisor_check(&s, 4000000u + 65535000u, &ev), "timeout 65535 ms");
    CHECK(supervisor_check(&s, 4000000u + 65535001u, &ev) && ev_is(&ev, 4000000u + 65535000u, 65535, SUP_HEARTBEAT),
          "the longest timeout");

    /* A pulse (issue 49): off for its length, on again unlatched; nothing when off; a silence or an
     * over-speed during it latches it off with that cause. */
    supervisor_arm(&s, 14285, 7692, 200, 5000000u, &ev);
    CHECK(supervisor_pulse(&s, 100, 5010000u, &ev) && !s.on && s.pulsing, "pulse: off");
    CHECK(ev_is(&ev, 5010000u, 100, SUP_PULSE), "PULSE event, code = its ms");
    CHECK(!supervisor_pulse(&s, 100, 5020000u, &ev), "a pulse during a pulse: nothing");
    supervisor_beat(&s, 5100000u);
    CHECK(!supervisor_check(&s, 5109999u, &ev) && !s.on, "still off before its end");
    CHECK(supervisor_check(&s, 5110400u, &ev) && s.on && !s.pulsing, "on again at its end");
    CHECK(ev_is(&ev, 5110000u, 0, SUP_ON), "ON event at the pulse's end");
    CHECK(!supervisor_check(&s, 5300000u, &ev) && s.on, "the heartbeat runs on from the last beat");
    supervisor_beat(&s, 5300000u);
    CHECK(supervisor_pulse(&s, 100, 5310000u, &ev), "second pulse");
    CHECK(supervisor_check(&s, 5510001u, &ev) && !s.on && !s.pulsing, "no beat within the timeout: off for good");
    CHECK(ev_is(&ev, 5500000u, 200, SUP_HEARTBEAT), "HEARTBEAT event: last beat + timeout");
    CHECK(!supervisor_pulse(&s, 100, 5600000u, &ev) && !s.on, "latched: a pulse does not turn it on");
    supervisor_arm(&s, 14285, 7692, 200, 6000000u, &ev);
    CHECK(supervisor_pulse(&s, 100, 6000000u, &ev), "third pulse");
    CHECK(supervisor_period(&s, 0, 13000, 6050000u, &ev) && !s.on && !s.pulsing, "over-speed in a pulse: latched");
    CHECK(!supervisor_check(&s, 6200000u, &ev) && !s.on, "it stays off after the pulse's length");
    supervisor_arm(&s, 14285, 7692, 200, 7000000u, &ev);
    CHECK(supervisor_pulse(&s, 0xFFFF, 7000000u, &ev) && !s.on && !s.pulsing, "PULSE_LATCH: off");
    CHECK(ev_is(&ev, 7000000u, 0xFFFF, SUP_PULSE), "PULSE event with the latch's code");
    supervisor_beat(&s, 7100000u);
    CHECK(!supervisor_check(&s, 8000000u, &ev) && !s.on, "latched: no end, beats change nothing");
    supervisor_arm(&s, 14285, 7692, 200, 9000000u, &ev);
    CHECK(supervisor_pulse(&s, 100, 9000000u, &ev) && supervisor_pulse(&s, 0xFFFF, 9050000u, &ev) && !s.pulsing,
          "PULSE_LATCH during a pulse: latched");
    CHECK(!supervisor_check(&s, 9200000u, &ev) && !s.on, "stays off past the pulse's end");
    supervisor_init(&s);
    CHECK(!supervisor_pulse(&s, 100, 1000u, &ev) && !s.on, "not armed: a pulse does nothing");
    CHECK(!supervisor_pulse(&s, 0xFFFF, 1000u, &ev) && !s.on, "not armed: nor a latch");

    /* Across the u32 wrap of device time. */
    supervisor_arm(&s, 0, 0, 200, 0xFFFF0000u, &ev);
    CHECK(!supervisor_check(&s, 0xFFFF0000u + 200000u, &ev), "wrap: at the timeout");
    CHECK(supervisor_check(&s, (uint32_t)(0xFFFF0000u + 200001u), &ev) && ev.t_us == (uint32_t)(0xFFFF0000u + 200000u),
          "wrap: past the timeout");
}


static uint8_t cmd(proto_t *p, const uint8_t *c, uint8_t n) { return proto_command(p, c, n, crc16(c, n)); }

void test_supervisor_proto(void)
{
    static ring_t r;
    static proto_t p;
    static dyno_counters_t cnt;
    uint8_t c[CMD_MAX_LEN], f[FRAME_MAX];
    uint16_t args[3];
    ring_init(&r);
    proto_init(&p, &r, &cnt, 0x0007, 0x1, 1000, 1000, 0);
    proto_set_fitted(&p, 0);

    CHECK(cmd_length(OP_SET_SUPERVISOR) == 9 && CMD_MAX_LEN == 9, "SET_SUPERVISOR is 9 bytes, the longest");
    /* The heartbeat: POLL, ACK_POLL (any boot), not INFO, CAPS, SET_DEBOUNCE, nor a bad CRC. */
    CHECK(!proto_take_beat(&p), "no beat at boot");
    uint8_t n = mk_cmd(c, OP_POLL, NULL, 0);
    cmd(&p, c, n);
    CHECK(proto_take_beat(&p) && !proto_take_beat(&p), "POLL is a heartbeat, taken once");
    uint8_t ack[3] = {0xBE, 0xEF, 9};
    n = mk_cmd(c, OP_ACK_POLL, ack, 3);
    cmd(&p, c, n);
    CHECK(proto_take_beat(&p), "ACK_POLL naming another boot is a heartbeat");
    n = mk_cmd(c, OP_INFO, NULL, 0);
    cmd(&p, c, n);
    n = mk_cmd(c, OP_CAPS, NULL, 0);
    cmd(&p, c, n);
    uint8_t deb[4] = {0x03, 0xE8, 0x03, 0xE8};
    n = mk_cmd(c, OP_SET_DEBOUNCE, deb, 4);
    cmd(&p, c, n);
    n = mk_cmd(c, OP_POLL, NULL, 0);
    c[2] ^= 1;
    CHECK(proto_command(&p, c, n, crc16(c, n)) == 0, "bad CRC ignored");
    CHECK(!proto_take_beat(&p), "INFO, CAPS, SET_DEBOUNCE and a corrupted POLL are no heartbeat");
    p.serve_info = p.serve_caps = 0;

    /* SET_SUPERVISOR: the ISR copies, the loop takes it once; timeout 0 is ignored and counted. */
    uint8_t a[6] = {0x37, 0xCD, 0x1E, 0x0C, 0x00, 0xC8};
    n = mk_cmd(c, OP_SET_SUPERVISOR, a, 6);
    CHECK(n == 9 && cmd(&p, c, n) == OP_SET_SUPERVISOR, "SET_SUPERVISOR accepted");
    CHECK(proto_take_supervisor(&p, args) && args[0] == 14285 && args[1] == 7692 && args[2] == 200,
          "args taken: %u %u %u", args[0], args[1], args[2]);
    CHECK(!proto_take_supervisor(&p, args), "taken once");
    uint8_t bad_before = p.cmds_bad;
    uint8_t z[6] = {0x37, 0xCD, 0x1E, 0x0C, 0x00, 0x00};
    n = mk_cmd(c, OP_SET_SUPERVISOR, z, 6);
    cmd(&p, c, n);
    CHECK(!proto_take_supervisor(&p, args) && p.cmds_bad == bad_before + 1, "timeout 0: ignored, counted bad");
    CHECK(cmd(&p, c, 8) == 0, "8 bytes: a length error");

    /* PULSE_RUN_ENABLE: taken once by the loop, not a heartbeat; 0 ms or over PULSE_MS_MAX ignored, counted. */
    uint16_t ms = 0;
    uint8_t pa[2] = {0x00, 0x64};
    n = mk_cmd(c, OP_PULSE_RUN_ENABLE, pa, 2);
    CHECK(n == 5 && cmd(&p, c, n) == OP_PULSE_RUN_ENABLE, "PULSE_RUN_ENABLE accepted");
    CHECK(!proto_take_beat(&p), "a pulse is no heartbeat");
    CHECK(proto_take_pulse(&p, &ms) && ms == 100 && !proto_take_pulse(&p, &ms), "100 ms taken once");
    bad_before = p.cmds_bad;
    uint8_t pz[2] = {0x00, 0x00}, pl[2] = {0x03, 0xE9};
    n = mk_cmd(c, OP_PULSE_RUN_ENABLE, pz, 2);
    cmd(&p, c, n);
    CHECK(!proto_take_pulse(&p, &ms) && p.cmds_bad == bad_before + 1, "0 ms: ignored, counted bad");
    n = mk_cmd(c, OP_PULSE_RUN_ENABLE, pl, 2);
    cmd(&p, c, n);
    CHECK(!proto_take_pulse(&p, &ms) && p.cmds_bad == bad_before + 2, "1001 ms: ignored, counted bad");
    uint8_t px[2] = {0xFF, 0xFF};
    n = mk_cmd(c, OP_PULSE_RUN_ENABLE, px, 2);
    cmd(&p, c, n);
    CHECK(proto_take_pulse(&p, &ms) && ms == PULSE_LATCH && p.cmds_bad == bad_before + 2, "PULSE_LATCH taken");

    /* FLAG_RUN: the unsent current frame and the info frame follow the output; the caps' bits too. */
    proto_service(&p, 5000, 5);
    memcpy(f, proto_begin_read(&p), FRAME_MAX);
    proto_end_read(&p);
    p.cur_sent = 0;  /* (as if that read had not happened: the frame may still change) */
    CHECK(!(f[4] & FLAG_RUN), "not armed: no RUN flag");
    CHECK(p.caps_buf[p.caps_cur][7] == CHANNEL_SUPERVISOR && p.caps_buf[p.caps_cur][8] == 0,
          "caps: the output exists, not armed");
    proto_set_run(&p, 1, 1);
    proto_service(&p, 6000, 6);
    memcpy(f, proto_begin_read(&p), FRAME_MAX);
    proto_end_read(&p);
    CHECK(f[4] & FLAG_RUN, "on: RUN in the (rebuilt) current frame");
    CHECK(p.pool[p.info][4] & FLAG_RUN, "on: RUN in the info frame");
    CHECK(p.pool[p.info][7] == 2 && p.pool[p.info][8] == 1 && p.pool[p.info][9] == 0, "fw 2.1.0");
    CHECK(p.caps_buf[p.caps_cur][7] == CHANNEL_SUPERVISOR && p.caps_buf[p.caps_cur][8] == CHANNEL_SUPERVISOR,
          "caps: armed");
    proto_set_run(&p, 0, 1);
    proto_service(&p, 7000, 7);
    CHECK(!(p.pool[p.info][4] & FLAG_RUN), "off: no RUN in the info frame");
    CHECK(p.nxt_valid && !(p.pool[p.nxt][4] & FLAG_RUN), "off: the next frame rebuilt without RUN");
    /* SET_CHANNELS cannot arm it: the supervisor is not an optional channel the host enables. */
    uint8_t mask = 0x03;
    proto_set_run(&p, 0, 0);
    n = mk_cmd(c, OP_SET_CHANNELS, &mask, 1);
    cmd(&p, c, n);
    proto_service(&p, 8000, 8);
    CHECK(p.caps_buf[p.caps_cur][8] == 0, "SET_CHANNELS(0x03) enables nothing here");
}
