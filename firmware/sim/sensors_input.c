/* The engine-side input torque AD7171 (issue 27) in the simavr harness: DOUT2/RDY2 on PB0 (ICP1)
 * and SCLK2 on PB1, an external driver on port B. Absent (the line left to the MCU's pull-up)
 * unless --input-hz > 0. Each conversion carries its own code (--input-code + its index mod 4096),
 * so the host can tell every one apart: lossless is checked by codes, not only by counts. */
#include <stdint.h>
#include <stdio.h>
#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_irq.h"
#include "harness.h"

double cfg_input_hz = 0.0;
unsigned cfg_input_code = 30000, cfg_input_status = 0x05;
uint64_t in_generated, in_read, in_missed, in_overrun;
double in_period_cycles, in_t0_cycles;
int in_running;

static avr_irq_t *pin_in_dout;
static avr_ioport_external_t portb_ext = {.name = 'B', .mask = 0, .value = 0};
static int in_bit = 24, in_ready = 0, in_sclk = 1;
static uint32_t in_word;
static uint64_t in_k;

static void drive_b0(int level)
{
    portb_ext.mask |= 1u;
    if (level)
        portb_ext.value |= 1u;
    else
        portb_ext.value &= (uint8_t)~1u;
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('B'), &portb_ext);
    avr_raise_irq(pin_in_dout, (uint32_t)level);
}

static avr_cycle_count_t in_rdy_high(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    drive_b0(1);
    return 0;
}

/* One conversion's result ready (the generator's, or the plant's in --plant mode). */
void input_present(unsigned code, unsigned status)
{
    if (cfg_input_hz <= 0)
        return;  /* not fitted */
    if (in_bit > 0 && in_bit < 24) {
        in_overrun++;
        return;
    }
    if (in_ready)
        in_missed++;
    in_generated++;
    in_word = ((uint32_t)(code & 0xFFFFu) << 8) | (status & 0xFFu);
    in_bit = 0;
    in_ready = 1;
    drive_b0(0);  /* RDY */
}

static avr_cycle_count_t in_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    if (!gen_enabled) {
        in_running = 0;
        return 0;
    }
    input_present((cfg_input_code + (unsigned)(in_generated % 4096u)) & 0xFFFFu, cfg_input_status);
    in_k++;
    return (avr_cycle_count_t)(in_t0_cycles + (double)in_k * in_period_cycles + 0.5);
}

static void in_sclk_notify(avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    int level = value ? 1 : 0;
    if (level == in_sclk)
        return;
    in_sclk = level;
    if (!in_ready)
        return;
    if (level == 0 && in_bit < 24) {
        drive_b0((int)((in_word >> (23 - in_bit)) & 1u));
        in_bit++;
    } else if (level == 1 && in_bit == 24) {
        in_ready = 0;
        in_read++;
        avr_cycle_timer_register(avr, CYCLES_PER_US, in_rdy_high, NULL);
    }
}

void input_init(void)
{
    if (cfg_input_hz <= 0)
        return;  /* not fitted: PB0 floats to the MCU's pull-up */
    pin_in_dout = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 0);
    drive_b0(1);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 1), in_sclk_notify, NULL);
    /* The converter shares the Nano's supply: it converts from power-up (1 ms to settle), not from
     * when the Hall signals start, so the firmware's boot probe finds it. */
    input_start(CYCLES_PER_US * 1000u);  /* (--plant: the plant's conversions instead) */
}

void input_start(uint64_t at_cycle)
{
    if (cfg_input_hz <= 0 || in_running || cfg_plant)
        return;
    in_period_cycles = (double)F_CPU_HZ / cfg_input_hz;
    in_t0_cycles = (double)at_cycle;
    in_k = 0;
    in_running = 1;
    avr_cycle_timer_register(avr, at_cycle - avr->cycle, in_timer, NULL);
}

void input_reset(void)
{
    /* An MCU reset does not reset the converter (its own supply, no reset pin): it keeps
     * converting; a result half clocked out is abandoned (it updates at the next conversion). */
    if (cfg_input_hz <= 0)
        return;
    avr_cycle_timer_cancel(avr, in_rdy_high, NULL);
    in_bit = 24;
    in_ready = 0;
    drive_b0(1);
}

void input_print(FILE *o)
{
    fprintf(o, "\"input\": {\"fitted\": %s, \"rdy_t0_us\": %.4f, \"period_us\": %.4f, \"generated\": %llu, "
            "\"read\": %llu, \"missed\": %llu, \"overrun\": %llu, \"code\": %u}, ",
            cfg_input_hz > 0 ? "true" : "false", in_t0_cycles / CYCLES_PER_US, in_period_cycles / CYCLES_PER_US,
            (unsigned long long)in_generated, (unsigned long long)in_read, (unsigned long long)in_missed,
            (unsigned long long)in_overrun, cfg_input_code);
}
