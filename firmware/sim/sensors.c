/* The rig's sensors around the MCU in the simavr harness (harness.c runs the MCU, the
 * I2C master and the host's line protocol): the two Hall sensors and the AD7171, as
 * external drivers on port D. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_irq.h"
#include "harness.h"

double cfg_rpm[2] = {3800.0, 7600.0};
unsigned cfg_adc_code = 35145, cfg_adc_status = 0x05, cfg_adc_err_every = 0;
double cfg_adc_hz = 125.0;
int cfg_bounce = 0;
double cfg_pulse_us = 1e9;  /* no cap by default: the pulse is the magnet arc, 5 % of a turn */

/* ---- external drivers on port D -------------------------------------------------- */
/* The sensors drive PD2, PD3 (Hall, open collector over pull-ups) and PD5 (AD7171
 * DOUT/RDY) from outside the MCU. simavr re-derives every input pin on each PORTD or
 * DDRD write: a pin whose PORT bit is 1 (Arduino's INPUT_PULLUP) snaps back to 1 unless
 * the port knows an external device drives it. So every level we drive is also
 * registered as the port's "external" state (AVR_IOCTL_IOPORT_SET_EXTERNAL), which
 * simavr then keeps; the MCU's pull-up only matters where nothing drives the line, as
 * on hardware. --legacy-pullups restores the old behaviour (for the regression test). */
int cfg_legacy_pullups = 0;
static avr_ioport_external_t portd_ext = {.name = 'D', .mask = 0, .value = 0};

void drive_pin(avr_irq_t *pin, int bit, int level)
{
    if (!cfg_legacy_pullups) {
        portd_ext.mask |= (uint8_t)(1u << bit);
        if (level)
            portd_ext.value |= (uint8_t)(1u << bit);
        else
            portd_ext.value &= (uint8_t)~(1u << bit);
        avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &portd_ext);
    }
    avr_raise_irq(pin, (uint32_t)level);
}

/* ---- Hall generators ------------------------------------------------------------ */
/* Each Hall line is a wired-AND of open-collector drivers over the pull-up: the sensor
 * (low for the pulse) and, with --glitch-hz, a noise source (ignition spikes: low for
 * --glitch-us at Poisson instants). The pin is driven only when the AND changes. */
/* hall_t is declared in harness.h */
hall_t hall[2];
int gen_enabled = 1;
double cfg_glitch_hz = 0.0, cfg_glitch_us = 20.0;
double cfg_duty = 0.05;   /* pulse = this fraction of the period (magnet arc), like a real sensor ... */

double pulse_us(const hall_t *h)
{
    double us = cfg_duty * h->period_cycles / CYCLES_PER_US;
    return us > cfg_pulse_us ? cfg_pulse_us : us;  /* ... at most --pulse-us */
}

void hall_drive(hall_t *h)
{
    int level = h->sensor_level && h->glitch_level;
    if (level != h->out_level) {
        h->out_level = level;
        if (trace_out)
            fprintf(trace_out, "P %llu %d %d s=%d g=%d\n", (unsigned long long)avr->cycle, h->ch,
                    level, h->sensor_level, h->glitch_level);
        drive_pin(h->pin, 2 + h->ch, level);
    }
}

/* Pulse pattern after a true falling edge: (offset us from the pulse end or, for the
 * first step, from the edge; level). With --bounce, the release rings: two 60 us
 * pulses 150 us and 700 us after the pulse ends (inside any lock-out, longer than the
 * firmware's 50 us minimum pulse width, so the lock-out has to reject them). */
static const struct { double us; int level; } pattern_plain[] = {{0, 0}, {0, 1}};
static const struct { double us; int level; } pattern_bounce[] = {
    {0, 0}, {0, 1}, {150, 0}, {210, 1}, {700, 0}, {760, 1}};

static double pattern_us(const hall_t *h, int step)
{
    double us = cfg_bounce ? pattern_bounce[step].us : pattern_plain[step].us;
    return step == 0 ? 0.0 : pulse_us(h) + us;
}

avr_cycle_count_t hall_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    hall_t *h = param;
    int n = cfg_bounce ? 6 : 2;
    int level = cfg_bounce ? pattern_bounce[h->step].level : pattern_plain[h->step].level;
    if (h->step == 0) {
        if (!gen_enabled) {
            h->running = 0;
            return 0;
        }
        h->edge_cycle = when;
        h->generated++;
        if (!h->first_cycle)
            h->first_cycle = when;
        h->last_cycle = when;
    } else if (level == 0) {
        h->bounces++;
    }
    h->sensor_level = level;
    hall_drive(h);
    h->step++;
    if (h->step < n)
        return h->edge_cycle + (avr_cycle_count_t)(pattern_us(h, h->step) * CYCLES_PER_US);
    h->step = 0;
    h->k++;
    return (avr_cycle_count_t)(h->t0_cycles + (double)h->k * h->period_cycles + 0.5);
}

/* xorshift64*: seeded per channel, so glitch times are reproducible. */
static double glitch_uniform(hall_t *h)
{
    uint64_t x = h->glitch_rng;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    h->glitch_rng = x;
    return (double)((x * 0x2545F4914F6CDD1Dull) >> 11) / 9007199254740992.0;
}

avr_cycle_count_t glitch_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    hall_t *h = param;
    if (h->glitch_level) {  /* a spike starts: the line is pulled low for cfg_glitch_us */
        if (!gen_enabled)
            return 0;
        if (h->sensor_level)
            h->glitches++;
        else
            h->glitches_masked++;  /* the sensor already holds the line low */
        h->glitch_level = 0;
        hall_drive(h);
        return when + (avr_cycle_count_t)(cfg_glitch_us * CYCLES_PER_US);
    }
    h->glitch_level = 1;
    hall_drive(h);
    double gap_s = -log(1.0 - glitch_uniform(h)) / cfg_glitch_hz;
    return when + 1 + (avr_cycle_count_t)(gap_s * F_CPU_HZ);
}

void hall_start(hall_t *h, uint64_t at_cycle)
{
    if (cfg_glitch_hz > 0 && !h->running) {
        avr_cycle_timer_cancel(avr, glitch_timer, h);
        h->glitch_level = 1;
        hall_drive(h);
        if (!h->glitch_rng)
            h->glitch_rng = 0x9E3779B97F4A7C15ull * (uint64_t)(h->ch + 1);
        h->glitch_level = 1;
        double gap_s = -log(1.0 - glitch_uniform(h)) / cfg_glitch_hz;
        avr_cycle_timer_register(avr, (avr_cycle_count_t)(gap_s * F_CPU_HZ) + 1, glitch_timer, h);
    }
    if (cfg_rpm[h->ch] <= 0)
        return;
    h->period_cycles = 60.0 * (double)F_CPU_HZ / cfg_rpm[h->ch];
    h->t0_cycles = (double)at_cycle;
    h->k = 0;
    h->step = 0;
    h->running = 1;
    avr_cycle_timer_register(avr, at_cycle - avr->cycle, hall_timer, h);
}

/* ---- AD7171 --------------------------------------------------------------------- */
avr_irq_t *pin_dout;
int adc_bit = 24;         /* next bit to shift out; 24 = idle (RDY high) */
int adc_ready = 0;        /* RDY low, not yet clocked out */
static uint32_t adc_word;        /* 16 data bits << 8 | status */
static int sclk_level = 1;
uint64_t adc_generated, adc_read, adc_missed, adc_overrun, adc_errors_set;
int adc_running;
double adc_period_cycles, adc_t0_cycles;
static uint64_t adc_k;

avr_cycle_count_t adc_rdy_high(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    drive_pin(pin_dout, 5, 1);
    return 0;
}

/* One conversion's result ready: RDY low with this code (the generator's, or the plant's in --plant mode). */
void adc_present(unsigned code, unsigned status)
{
    if (adc_bit > 0 && adc_bit < 24) {
        adc_overrun++;  /* a read in progress: the real part keeps the old result */
        return;
    }
    if (adc_ready)
        adc_missed++;  /* previous result never read: overwritten */
    adc_generated++;
    if (cfg_adc_err_every && adc_generated % cfg_adc_err_every == 0) {
        status |= 0x20;
        adc_errors_set++;
    }
    adc_word = ((uint32_t)(code & 0xFFFF) << 8) | (status & 0xFF);
    adc_bit = 0;
    adc_ready = 1;
    drive_pin(pin_dout, 5, 0);  /* RDY */
}

avr_cycle_count_t adc_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    if (!gen_enabled) {
        adc_running = 0;
        return 0;
    }
    adc_present(cfg_adc_code, cfg_adc_status);
    adc_k++;
    return (avr_cycle_count_t)(adc_t0_cycles + (double)adc_k * adc_period_cycles + 0.5);
}

void adc_sclk_notify(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    int level = value ? 1 : 0;
    if (level == sclk_level)
        return;
    sclk_level = level;
    if (!adc_ready)
        return;
    if (level == 0 && adc_bit < 24) {
        /* Falling edge: the AD7171 shifts out the next bit, MSB first. */
        drive_pin(pin_dout, 5, (int)((adc_word >> (23 - adc_bit)) & 1u));
        adc_bit++;
    } else if (level == 1 && adc_bit == 24) {
        /* After the 24th rising edge DOUT/RDY returns high; 1 us later so the MCU's
         * sample of the last bit (a few cycles after the edge) still sees it. */
        adc_ready = 0;
        adc_read++;
        avr_cycle_timer_register(avr, CYCLES_PER_US, adc_rdy_high, NULL);
    }
}

void adc_start(uint64_t at_cycle)
{
    if (cfg_adc_hz <= 0)
        return;
    adc_period_cycles = (double)F_CPU_HZ / cfg_adc_hz;
    adc_t0_cycles = (double)at_cycle;
    adc_k = 0;
    adc_running = 1;
    avr_cycle_timer_register(avr, at_cycle - avr->cycle, adc_timer, NULL);
}

