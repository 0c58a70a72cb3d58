/* --plant: the rig's sensors driven by a plant model outside the harness (closed-loop firmware in the loop,
 * `dyno run --sim --firmware-elf`). The Hall and converter generators stay off; the plant sends its events,
 * each at its own simulated time ahead of the MCU's clock:
 *
 *   ev h0:T:W,h1:T:W,a0:T:CODE:STATUS,a1:T:CODE:STATUS,...      -> ok <late>
 *
 * hN: Hall sensor N pulls its line low at T us for W us (the magnet's arc); bN: its line, low, bounces high at
 * T for W us (contact-like ringing inside the pulse: a second falling edge the firmware must reject); a0: the brake-side AD7171
 * finishes a conversion at T with CODE/STATUS (RDY low); a1: the engine-side one (needs --input-hz > 0 for
 * its pins). An event already in the MCU's past is applied at once and counted late.
 *
 *   run T  -> ok <t_us> <on> <t_us>:<level>,...|-
 *
 * (in --plant mode) the run-enable as the kill chain reads it (pin or charge pump, run_enable.c): its level at
 * T and every change since the last run, timed to the cycle, so the plant cuts the engine when the firmware did. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "harness.h"

int cfg_plant = 0;

/* simavr keeps 64 cycle timers in all: the plant's events wait in one queue, sorted by time, behind a
 * single timer that fires at the earliest. */
#define N_QUEUE 2048
typedef struct {
    avr_cycle_count_t at;
    char kind;  /* 'h' Hall pulls low, 'r' Hall releases, 'b' Hall bounces high, 'f' falls back, 'a' converter */
    int ch;
    unsigned code, status;
    avr_cycle_count_t width_cycles;
} plant_ev_t;
static plant_ev_t queue[N_QUEUE];
static int n_queue;
static unsigned long long late_events, dropped_events;

static void apply(const plant_ev_t *e, avr_cycle_count_t when);

static avr_cycle_count_t queue_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    while (n_queue && queue[0].at <= when) {
        plant_ev_t e = queue[0];
        memmove(queue, queue + 1, (size_t)(n_queue - 1) * sizeof queue[0]);
        n_queue--;
        apply(&e, when);
    }
    return n_queue ? queue[0].at : 0;
}

static void push(const plant_ev_t *e)
{
    if (n_queue == N_QUEUE) {
        dropped_events++;
        return;
    }
    int i = n_queue;
    while (i > 0 && queue[i - 1].at > e->at)
        i--;
    memmove(queue + i + 1, queue + i, (size_t)(n_queue - i) * sizeof queue[0]);
    queue[i] = *e;
    n_queue++;
    if (i == 0)  /* a new earliest: the one timer moves to it */
        avr_cycle_timer_register(avr, e->at > avr->cycle ? e->at - avr->cycle : 1, queue_timer, NULL);
}

static void apply(const plant_ev_t *e, avr_cycle_count_t when)
{
    if (e->kind == 'b' || e->kind == 'f') {
        hall_t *h = &hall[e->ch];
        if (e->kind == 'b') {
            h->bounces++;
            plant_ev_t f = *e;
            f.kind = 'f';
            f.at = when + (e->width_cycles ? e->width_cycles : 1);
            push(&f);
        }
        h->sensor_level = e->kind == 'b';
        hall_drive(h);
    } else if (e->kind == 'h' || e->kind == 'r') {
        hall_t *h = &hall[e->ch];
        if (e->kind == 'h') {
            h->generated++;
            if (!h->first_cycle)
                h->first_cycle = when;
            h->last_cycle = when;
            plant_ev_t r = *e;
            r.kind = 'r';
            r.at = when + (e->width_cycles ? e->width_cycles : 1);
            push(&r);
        }
        h->sensor_level = e->kind == 'r';
        hall_drive(h);
    } else if (e->ch == 0) {
        adc_present(e->code, e->status);
    } else {
        input_present(e->code, e->status);
    }
}

void plant_events(const char *list)
{
    unsigned late = 0;
    const char *p = list;
    while (p && *p && *p != '\n') {
        plant_ev_t e = {0};
        double t_us = 0, w_us = 0;
        e.kind = p[0];
        e.ch = p[1] - '0';
        if (e.kind == 'h' || e.kind == 'b')
            sscanf(p + 2, ":%lf:%lf", &t_us, &w_us);
        else
            sscanf(p + 2, ":%lf:%u:%u", &t_us, &e.code, &e.status);
        if ((e.kind != 'h' && e.kind != 'b' && e.kind != 'a') || e.ch < 0 || e.ch > 1) {
            dropped_events++;
        } else {
            e.at = (avr_cycle_count_t)(t_us * CYCLES_PER_US);
            e.width_cycles = (avr_cycle_count_t)(w_us * CYCLES_PER_US);
            if (e.at <= avr->cycle) {
                late++;
                e.at = avr->cycle + 1;
            }
            push(&e);
        }
        p = strchr(p, ',');
        if (p)
            p++;
    }
    late_events += late;
    fprintf(proto_out, "ok %u\n", late);
}

void plant_reset(void)
{
    /* The MCU's reset clears simavr's timers: the queue's one timer is set again (the rig keeps turning). */
    if (n_queue)
        avr_cycle_timer_register(avr, queue[0].at > avr->cycle ? queue[0].at - avr->cycle : 1, queue_timer, NULL);
}

#define N_CHANGES 256
static struct { double t_us; int level, pump; } changes[N_CHANGES];
static int n_changes, changes_dropped;

void plant_run_enable_change(double t_us, int level, int pump)
{
    if (!cfg_plant)
        return;
    if (n_changes < N_CHANGES) {
        changes[n_changes].t_us = t_us;
        changes[n_changes].level = level;
        changes[n_changes].pump = pump;
        n_changes++;
    } else {
        changes_dropped++;
    }
}

void plant_run_enable(FILE *o)
{
    int pump = run_enable_is_pump();
    int on = run_enable_on();  /* (also records a charge pump's decay up to now) */
    fprintf(o, "%d ", on);
    int any = 0;
    for (int i = 0; i < n_changes; i++) {
        if (changes[i].pump != pump)
            continue;
        fprintf(o, "%s%.3f:%d", any ? "," : "", changes[i].t_us, changes[i].level);
        any = 1;
    }
    fprintf(o, "%s\n", any ? "" : "-");
    n_changes = 0;
}

void plant_print(FILE *o)
{
    fprintf(o, "\"plant\": {\"on\": %s, \"late_events\": %llu, \"dropped_events\": %llu, \"changes_dropped\": %d}, ",
            cfg_plant ? "true" : "false", late_events, dropped_events, changes_dropped);
}
