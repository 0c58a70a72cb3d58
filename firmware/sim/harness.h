/* Shared between the parts of the simavr harness: harness.c (UART, host line protocol,
 * stats), mcu.c (ELF, stepping/profiling, simavr register fixes, ring guard bytes),
 * twi_master.c (the Pi's I2C master) and sensors.c (Hall sensors and AD7171 as external
 * drivers on port D). */
#ifndef DYNO_HARNESS_H
#define DYNO_HARNESS_H
#include <stdint.h>
#include <stdio.h>
#include "sim_avr.h"
#include "sim_irq.h"
#include "sim_interrupts.h"

#define F_CPU_HZ 16000000ull
#define CYCLES_PER_US (F_CPU_HZ / 1000000ull)

#define MCUSR_ADDR 0x54  /* data-space address of MCUSR (reset cause) */
#define N_VECTORS 26

/* mcu.c */
extern avr_t *avr;
extern int crashed, cfg_profile;
extern double cfg_profile_from_us, wall_s;
extern uint64_t wall_cycles;
int mcu_load(const char *elf);
void mcu_reset(uint8_t mcusr);
void step(void);
void run_until(uint64_t cycle);
void batch_break(void);  /* the batched run_until stops after the current instruction */
double now_s(void);
avr_int_vector_t *find_vector(int num);
void print_profile(FILE *o);
void guard_check(void);
extern uint64_t eeprom_writes;
extern FILE *trace_out;
#define REG_WDTCSR 0x60
void print_guard(FILE *o);

/* twi_master.c */
extern unsigned cfg_i2c_khz, cfg_addr;
extern uint64_t i2c_transfers, i2c_nacks, i2c_timeouts;
int i2c_init(void);
int i2c_transfer(const uint8_t *wr, int nw, uint8_t *rd, int nr, int abort_after);
void print_i2c(FILE *o);

/* sensor configuration (command line) */
extern double cfg_rpm[2];
extern unsigned cfg_adc_code, cfg_adc_status, cfg_adc_err_every;
extern double cfg_adc_hz, cfg_pulse_us, cfg_duty, cfg_glitch_hz, cfg_glitch_us;
extern int cfg_bounce, cfg_legacy_pullups;

typedef struct {
    int ch;                      /* 0 primary (PD2), 1 secondary (PD3) */
    avr_irq_t *pin;
    double period_cycles;
    uint64_t k;                  /* index of the next true edge */
    double t0_cycles;            /* time of edge 0 */
    int step;                    /* position in the pulse pattern */
    uint64_t edge_cycle;         /* cycle of the current true edge */
    uint64_t generated, bounces, glitches, glitches_masked;
    uint64_t first_cycle, last_cycle;
    int running;
    int sensor_level, glitch_level, out_level;
    uint64_t glitch_rng;
} hall_t;
extern hall_t hall[2];
extern int gen_enabled;

extern avr_irq_t *pin_dout;
extern int adc_bit, adc_ready, adc_running;
extern uint64_t adc_generated, adc_read, adc_missed, adc_overrun, adc_errors_set;
extern double adc_period_cycles, adc_t0_cycles;

void drive_pin(avr_irq_t *pin, int bit, int level);
void hall_drive(hall_t *h);
void adc_present(unsigned code, unsigned status);
void input_present(unsigned code, unsigned status);

/* plant.c: --plant, the sensors driven by a plant model's events (closed-loop firmware in the loop) */
extern int cfg_plant;
void plant_events(const char *list);
void plant_run_enable(FILE *o);
void plant_run_enable_change(double t_us, int level, int pump);
void plant_print(FILE *o);
void plant_reset(void);
int run_enable_is_pump(void);
int run_enable_on(void);
extern FILE *proto_out;
double pulse_us(const hall_t *h);
void hall_start(hall_t *h, uint64_t at_cycle);
void adc_start(uint64_t at_cycle);
avr_cycle_count_t hall_timer(avr_t *a, avr_cycle_count_t when, void *param);
avr_cycle_count_t glitch_timer(avr_t *a, avr_cycle_count_t when, void *param);
avr_cycle_count_t adc_timer(avr_t *a, avr_cycle_count_t when, void *param);
avr_cycle_count_t adc_rdy_high(avr_t *a, avr_cycle_count_t when, void *param);
void adc_sclk_notify(avr_irq_t *irq, uint32_t value, void *param);

/* sensors_input.c: the input torque AD7171 on port B (issue 27), absent unless --input-hz > 0 */
extern double cfg_input_hz;
extern unsigned cfg_input_code, cfg_input_status;
void input_init(void);
void input_start(uint64_t at_cycle);
void input_reset(void);
void input_print(FILE *o);

/* run_enable.c: the run-enable output on PD7 (issue 37), checked after every instruction */
extern int cfg_enable_model;
extern uint8_t run_enable_last;
void run_enable_edge(void);
void run_enable_print(FILE *o);
static inline void run_enable_watch(void)
{
    uint8_t v = (uint8_t)(avr->data[0x2A] & avr->data[0x2B] & 0x80u);  /* DDRD7 & PORTD7 */
    if (v != run_enable_last) {
        run_enable_last = v;
        run_enable_edge();
    }
}

#endif
