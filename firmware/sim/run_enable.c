/* The Nano's run-enable output (issue 37) as the rig sees it: D7 = PD7, driving a transistor through a
 * pull-down. The pin's level is PORTD7 while DDRD7 is set (an input, high-Z, is off: the pull-down; a
 * reset clears both). Watched after every instruction (mcu.c's step()), so every change is timed to the
 * cycle.
 *
 * Two readings of the same pin, for the two builds:
 *   static  (the watchdog build): the enable is the pin's level.
 *   pump    (the old-bootloader build): the pin feeds a charge pump (a coupling capacitor and a diode),
 *           which passes only a pulse train: the enable is on from the second of two edges less than
 *           PUMP_HOLD_US apart, off PUMP_HOLD_US after the last edge (a static level, high or low, is off).
 * The harness takes the pin for a pump once it saw PUMP_DETECT_EDGES edges in a row, each within
 * PUMP_HOLD_US of the previous one (the static build changes its level once per arming at most);
 * --enable-model static|pump forces the reading. */
#include <stdio.h>
#include <string.h>
#include "harness.h"

#define REG_DDRD 0x2A
#define REG_PORTD 0x2B
#define RUN_BIT 0x80u
#define PUMP_HOLD_US 2000.0
#define PUMP_DETECT_EDGES 4
#define MAX_TRANSITIONS 64

int cfg_enable_model = 0;  /* 0 auto, 1 static, 2 pump */

typedef struct {
    double t_us[MAX_TRANSITIONS];
    int level[MAX_TRANSITIONS];
    int n, dropped;
} transitions_t;

static int pin_level;
static uint64_t edges;
static double last_edge_us = -1e300, max_interval_us;
static int run_in_a_row, pump_seen;
static transitions_t pin_tr, pump_tr;
static int pump_on;

static void add(transitions_t *t, double t_us, int level)
{
    plant_run_enable_change(t_us, level, t == &pump_tr);
    if (t->n < MAX_TRANSITIONS) {
        t->t_us[t->n] = t_us;
        t->level[t->n] = level;
        t->n++;
    } else {
        /* keep the first ones and the latest: the last slot always holds the newest */
        t->t_us[MAX_TRANSITIONS - 1] = t_us;
        t->level[MAX_TRANSITIONS - 1] = level;
        t->dropped++;
    }
}

/* The pump's output falls PUMP_HOLD_US after the last edge: recorded once that time has passed. */
static void pump_decay(double now_us)
{
    if (pump_on && now_us - last_edge_us > PUMP_HOLD_US) {
        pump_on = 0;
        add(&pump_tr, last_edge_us + PUMP_HOLD_US, 0);
    }
}

void run_enable_edge(void)
{
    double t = (double)avr->cycle / CYCLES_PER_US;
    int level = (avr->data[REG_DDRD] & avr->data[REG_PORTD] & RUN_BIT) != 0;
    pin_level = level;
    edges++;
    add(&pin_tr, t, level);
    pump_decay(t);
    double gap = t - last_edge_us;
    if (gap <= PUMP_HOLD_US) {
        if (gap > max_interval_us)
            max_interval_us = gap;
        if (++run_in_a_row >= PUMP_DETECT_EDGES)
            pump_seen = 1;
        if (!pump_on) {
            pump_on = 1;
            add(&pump_tr, t, 1);
        }
    } else {
        run_in_a_row = 1;
    }
    last_edge_us = t;
}

uint8_t run_enable_last;

static int is_pump(void) { return cfg_enable_model == 2 || (cfg_enable_model == 0 && pump_seen); }

int run_enable_is_pump(void) { return is_pump(); }

int run_enable_on(void)
{
    pump_decay((double)avr->cycle / CYCLES_PER_US);
    return is_pump() ? pump_on : pin_level;
}

static void print_tr(FILE *o, const transitions_t *t)
{
    fprintf(o, "[");
    for (int i = 0; i < t->n; i++)
        fprintf(o, "%s[%.3f, %d]", i ? ", " : "", t->t_us[i], t->level[i]);
    fprintf(o, "]");
}

void run_enable_print(FILE *o)
{
    double now = (double)avr->cycle / CYCLES_PER_US;
    pump_decay(now);
    int pump = is_pump();
    fprintf(o, "\"run_enable\": {\"pin\": \"PD7\", \"model\": \"%s\", \"on\": %s, \"level\": %d, \"edges\": %llu, "
            "\"pulsing\": %s, \"pump_hold_us\": %.0f, \"max_pulse_interval_us\": %.3f, \"last_edge_us\": %.3f, "
            "\"transitions\": ", pump ? "pump" : "static", (pump ? pump_on : pin_level) ? "true" : "false",
            pin_level, (unsigned long long)edges, pump_on ? "true" : "false", PUMP_HOLD_US, max_interval_us,
            edges ? last_edge_us : -1.0);
    print_tr(o, pump ? &pump_tr : &pin_tr);
    fprintf(o, ", \"transitions_dropped\": %d, \"pin_transitions\": ", pump ? pump_tr.dropped : pin_tr.dropped);
    print_tr(o, &pin_tr);
    fprintf(o, "}, ");
}
