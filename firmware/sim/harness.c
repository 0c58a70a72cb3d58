/* Firmware-in-the-loop harness: runs any ATmega328P ELF in simavr (Debian's libsimavr
 * 1.6) with the rig around it, and plays the I2C master for a host process that talks
 * to it over stdin/stdout.
 *
 *   - Hall sensors on PD2/PD3 (INT0/INT1) and the AD7171 on PD4/PD5 as external
 *     drivers: sensors.c (one pulse per revolution, ringing, glitches; a conversion
 *     every 1/adc_hz s, shifted out on SCLK).
 *   - The host's USB serial on UART0 (uwrite/uread below).
 *   - I2C master at the bus's bit rate. simavr 1.6 cannot complete a slave-transmit
 *     (it never produces TWI status 0xB8/0xC0; fixed upstream in 2022), so this
 *     harness does not use simavr's TWI message IRQs at all: it is the bus. For every
 *     bus event it waits one byte time (9 SCL clocks), writes the TWI status the real
 *     hardware would produce into TWSR (keeping the prescaler bits), puts received
 *     data into TWDR, raises the TWI vector, and waits for the ISR to clear TWINT --
 *     the time SCL is held low, i.e. clock stretching, which it measures. Transmitted
 *     bytes are taken from TWDR after the ISR. Any slave (our driver, or Arduino's
 *     Wire for the v0 sketch) sees the same register behaviour as on silicon.
 *
 * Simulated time paces everything; the host advances it explicitly.
 *
 * Line protocol (one reply line per command, on the original stdout; simavr's own
 * messages are sent to stderr):
 *   run <t_us>           run until simulated time t_us        -> "ok <t_us>"
 *   xfer <hex|-> <n> [t_us]  (run until t_us first, if given: one pipe round trip per
 *                        poll), write bytes, repeated start, read n
 *                                                             -> "ok <hex|->" | "nack" | "timeout"
 *   abort <hex|-> <n> [t_us]  like xfer, but the master stops clocking halfway through
 *                        the read (no NACK, no STOP): the slave holds SDA until its
 *                        timeout disables TWI; transfers meanwhile -> "busheld"
 *   uwrite <hex|-> [t_us]  (run until t_us first) bytes into UART0   -> "ok"
 *   uread <max_us>       run until the MCU sent a whole packet (a 0x00) or max_us
 *                        passed; the bytes it sent             -> "ok <t_us> <hex|->"
 *   gen off|on           stop/restart generating Hall edges and conversions -> "ok"
 *   reset [mcusr]        reset the MCU; RAM kept, MCUSR set to the given hex cause
 *                        (default 08 = WDRF, a watchdog reset; 02 = EXTRF)   -> "ok"
 *   stats                one JSON object
 *   quit
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_elf.h"
#include "avr_uart.h"
#include "sim_interrupts.h"
#include "sim_irq.h"
#include "harness.h"


/* ATmega328P data-space addresses of the TWI registers. */
#define MCUSR_ADDR 0x54  /* data-space address of MCUSR (reset cause) */
#define REG_TWSR 0xB9
#define REG_TWAR 0xBA
#define REG_TWDR 0xBB
#define REG_TWCR 0xBC
#define TWCR_TWINT 0x80
#define TWCR_TWEA 0x40
#define TWCR_TWEN 0x04
#define TWI_VECTOR 24
#define N_VECTORS 26

avr_t *avr;
static FILE *proto_out;

/* ---- configuration ------------------------------------------------------------ */
static unsigned cfg_i2c_khz = 100, cfg_addr = 0x03;
static double cfg_start_us = 50000.0;
static int cfg_profile = 0;
static double cfg_profile_from_us = 100000.0;

/* ---- stepping, with optional ISR / interrupts-off profiling ---------------------- */
typedef struct {
    uint64_t count, total, max, min;
} isr_stat_t;
static isr_stat_t isr_stat[N_VECTORS];
static int in_isr = -1;
static uint64_t isr_start;
static uint64_t cli_start, cli_max, cli_max_at;
static int crashed;
static double wall_s;
static uint64_t wall_cycles;

static inline void step(void)
{
    if (!cfg_profile) {
        int st = avr_run(avr);
        if (st == cpu_Crashed || st == cpu_Done)
            crashed = 1;
        return;
    }
    uint32_t pc = avr->pc;
    uint16_t op = (uint16_t)(avr->flash[pc] | avr->flash[pc + 1] << 8);
    uint64_t before = avr->cycle;
    int st = avr_run(avr);
    if (st == cpu_Crashed || st == cpu_Done)
        crashed = 1;
    int armed = avr->cycle >= (uint64_t)(cfg_profile_from_us * CYCLES_PER_US);
    if (in_isr >= 0) {
        if (op == 0x9518) {  /* RETI */
            uint64_t d = avr->cycle - isr_start;
            isr_stat_t *s = &isr_stat[in_isr];
            if (armed) {
                s->count++;
                s->total += d;
                if (d > s->max) s->max = d;
                if (!s->min || d < s->min) s->min = d;
            }
            in_isr = -1;
        }
        return;
    }
    uint32_t npc = avr->pc;
    if (npc && npc < N_VECTORS * 4 && !(npc & 3)) {
        in_isr = (int)(npc / 4);
        isr_start = before;  /* includes the interrupted instruction: an upper bound */
        cli_start = 0;
        return;
    }
    /* Interrupts-off windows in the main program (cli ... sei / SREG restore). */
    if (!avr->sreg[S_I]) {
        if (!cli_start)
            cli_start = before;
    } else if (cli_start) {
        uint64_t d = avr->cycle - cli_start;
        if (armed && d > cli_max) {
            cli_max = d;
            cli_max_at = cli_start;
        }
        cli_start = 0;
    }
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void run_until(uint64_t cycle)
{
    double w0 = now_s();
    uint64_t c0 = avr->cycle;
    while (avr->cycle < cycle && !crashed)
        step();
    wall_s += now_s() - w0;
    wall_cycles += avr->cycle - c0;
}

/* ---- I2C master ------------------------------------------------------------------- */
static avr_int_vector_t *twi_vec;
static uint64_t i2c_transfers, i2c_nacks, i2c_timeouts, stretch_max, stretch_total, stretch_n;
static uint64_t byte_cycles, bit_cycles;

/* simavr 1.6 does not clear TWINT when the ISR writes 1 to it (TWI's vector is
 * "sticky"), so "the slave released SCL" is detected from the write itself. */
static int twint_written;

static avr_int_vector_t *find_vector(int num)
{
    for (int i = 0; i < avr->interrupts.vector_count; i++)
        if (avr->interrupts.vector[i] && avr->interrupts.vector[i]->vector == num)
            return avr->interrupts.vector[i];
    return NULL;
}

/* The slave's ISR holds SCL low from TWINT until it clears it. Real masters wait (clock
 * stretching); a stuck slave times the transfer out. */
static int wait_twint_clear(void)
{
    uint64_t t0 = avr->cycle, limit = t0 + 25000ull * CYCLES_PER_US;
    double w0 = now_s();
    while (!twint_written && avr->cycle < limit && !crashed)
        step();
    if (twint_written)
        avr->data[REG_TWCR] &= (uint8_t)~TWCR_TWINT;
    wall_s += now_s() - w0;
    wall_cycles += avr->cycle - t0;
    uint64_t d = avr->cycle - t0;
    if (getenv("HARNESS_DEBUG") && !twint_written)
        fprintf(stderr, "harness: TWINT stuck: TWCR %02x TWSR %02x pending %d I %d pc %04x\n",
                avr->data[REG_TWCR], avr->data[REG_TWSR], twi_vec->pending, avr->sreg[S_I], avr->pc);
    stretch_total += d;
    stretch_n++;
    if (d > stretch_max)
        stretch_max = d;
    return twint_written;
}

/* A master that gave up mid-read leaves the slave transmitter driving SDA: the bus is
 * held until the slave disables its TWI unit (TWEN written 0: its timeout). */
static int bus_held;
static uint64_t bus_held_since, bus_release_cycles, bus_aborts;

static void twcr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)a; (void)addr; (void)param;
    if (v & TWCR_TWINT)
        twint_written = 1;
    if (bus_held && !(v & TWCR_TWEN)) {
        bus_held = 0;
        bus_release_cycles = avr->cycle - bus_held_since;
    }
}

/* PCIFR's flags clear when a 1 is written to them (silicon); simavr 1.6 stores the 1
 * instead, so a flag "cleared" that way stays set and its interrupt stays pending. */
#define REG_PCIFR 0x3B
static avr_int_vector_t *pcint_vec[3];

static void pcifr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    for (int b = 0; b < 3; b++)
        if (v & (1u << b)) {
            a->data[addr] &= (uint8_t)~(1u << b);
            if (pcint_vec[b])
                pcint_vec[b]->pending = 0;  /* simavr drops a queued vector that is not pending */
        }
}

static void twi_event(uint8_t status)
{
    twint_written = 0;
    avr->data[REG_TWSR] = (uint8_t)((avr->data[REG_TWSR] & 0x03) | status);
    avr_raise_interrupt(avr, twi_vec);
}

static int slave_acks(uint8_t addr7)
{
    uint8_t twcr = avr->data[REG_TWCR];
    if (!(twcr & TWCR_TWEN) || !(twcr & TWCR_TWEA))
        return 0;
    return (avr->data[REG_TWAR] >> 1) == addr7;
}

/* Returns 0 ok, 1 NACK, 2 timeout, 3 bus held (SDA low since an aborted transfer).
 * abort_after >= 0: the master stops clocking after that many bytes of the read, with
 * no NACK and no STOP (a crashed or killed host). */
static int i2c_transfer(const uint8_t *wr, int nw, uint8_t *rd, int nr, int abort_after)
{
    if (bus_held)
        return 3;
    i2c_transfers++;
    /* simavr stores a 1 written to TWINT (silicon clears the flag), so TWINT can read
     * as set with nothing pending: only our own events count. */
    if ((avr->data[REG_TWCR] & TWCR_TWINT) && !twi_vec->pending)
        avr->data[REG_TWCR] &= (uint8_t)~TWCR_TWINT;
    run_until(avr->cycle + bit_cycles);  /* START */
    if (nw > 0) {
        run_until(avr->cycle + byte_cycles);  /* SLA+W */
        if (!slave_acks((uint8_t)cfg_addr))
            return 1;
        twi_event(0x60);
        if (!wait_twint_clear()) return 2;
        for (int i = 0; i < nw; i++) {
            run_until(avr->cycle + byte_cycles);
            if (!(avr->data[REG_TWCR] & TWCR_TWEA))
                return 1;  /* slave stopped acknowledging */
            avr->data[REG_TWDR] = wr[i];
            twi_event(0x80);
            if (!wait_twint_clear()) return 2;
        }
        run_until(avr->cycle + bit_cycles);  /* repeated START, or STOP */
        twi_event(0xA0);
        if (!wait_twint_clear()) return 2;
    }
    if (nr > 0) {
        run_until(avr->cycle + byte_cycles);  /* SLA+R */
        if (!slave_acks((uint8_t)cfg_addr))
            return 1;
        twi_event(0xA8);
        if (!wait_twint_clear()) return 2;
        rd[0] = avr->data[REG_TWDR];
        for (int i = 1; i < nr; i++) {
            if (abort_after >= 0 && i >= abort_after) {
                bus_held = 1;
                bus_held_since = avr->cycle;
                bus_aborts++;
                return 0;
            }
            run_until(avr->cycle + byte_cycles);  /* byte i-1 out, master ACKs */
            twi_event(0xB8);
            if (!wait_twint_clear()) return 2;
            rd[i] = avr->data[REG_TWDR];
        }
        run_until(avr->cycle + byte_cycles);  /* last byte out, master NACKs */
        twi_event(0xC0);
        if (!wait_twint_clear()) return 2;
    }
    run_until(avr->cycle + bit_cycles);  /* STOP */
    return 0;
}

/* ---- the host's USB serial (UART0, 115200 8N1 through the Nano's USB bridge) ----- */
static avr_irq_t *uart_in;
static uint8_t uart_rx[4096];   /* bytes the MCU sent, not yet handed to the host */
static int uart_rx_n, uart_packet_end;
static uint64_t uart_bytes_out, uart_bytes_in;

static void uart_out_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    uart_bytes_out++;
    if (uart_rx_n < (int)sizeof uart_rx)
        uart_rx[uart_rx_n++] = (uint8_t)value;
    if ((uint8_t)value == 0)
        uart_packet_end = 1;  /* COBS packets end with 0x00 */
}

/* ---- setup and command loop ------------------------------------------------------ */
static void logger(avr_t *a, const int level, const char *fmt, va_list ap)
{
    (void)a;
    if (level <= LOG_WARNING)
        vfprintf(stderr, fmt, ap);
}

static const char *vector_name(int v)
{
    static const char *names[N_VECTORS] = {
        "RESET", "INT0", "INT1", "PCINT0", "PCINT1", "PCINT2", "WDT", "TIMER2_COMPA",
        "TIMER2_COMPB", "TIMER2_OVF", "TIMER1_CAPT", "TIMER1_COMPA", "TIMER1_COMPB",
        "TIMER1_OVF", "TIMER0_COMPA", "TIMER0_COMPB", "TIMER0_OVF", "SPI_STC", "USART_RX",
        "USART_UDRE", "USART_TX", "ADC", "EE_READY", "ANALOG_COMP", "TWI", "SPM_READY"};
    return names[v];
}

static void print_stats(void)
{
    FILE *o = proto_out;
    fprintf(o, "{\"cycle\": %llu, \"sim_s\": %.6f, \"wall_s\": %.4f, \"sim_per_wall\": %.3f, "
            "\"crashed\": %s, ",
            (unsigned long long)avr->cycle, (double)avr->cycle / F_CPU_HZ, wall_s,
            wall_s > 0 ? (double)wall_cycles / F_CPU_HZ / wall_s : 0.0, crashed ? "true" : "false");
    fprintf(o, "\"hall\": [");
    for (int c = 0; c < 2; c++)
        fprintf(o, "%s{\"rpm\": %.6f, \"edges\": %llu, \"bounce_edges\": %llu, "
                "\"glitches\": %llu, \"glitches_masked\": %llu, \"pulse_us\": %.3f, "
                "\"first_us\": %.4f, \"last_us\": %.4f}", c ? ", " : "", cfg_rpm[c],
                (unsigned long long)hall[c].generated, (unsigned long long)hall[c].bounces,
                (unsigned long long)hall[c].glitches, (unsigned long long)hall[c].glitches_masked,
                hall[c].period_cycles > 0 ? pulse_us(&hall[c]) : 0.0,
                (double)hall[c].first_cycle / CYCLES_PER_US, (double)hall[c].last_cycle / CYCLES_PER_US);
    fprintf(o, "], \"adc\": {\"rdy_t0_us\": %.4f, \"period_us\": %.4f, "
            "\"generated\": %llu, \"read\": %llu, \"missed\": %llu, "
            "\"overrun\": %llu, \"error_bit_set\": %llu, \"code\": %u, \"status\": %u}, ",
            adc_t0_cycles / CYCLES_PER_US, adc_period_cycles / CYCLES_PER_US,
            (unsigned long long)adc_generated, (unsigned long long)adc_read,
            (unsigned long long)adc_missed, (unsigned long long)adc_overrun,
            (unsigned long long)adc_errors_set, cfg_adc_code, cfg_adc_status);
    fprintf(o, "\"i2c\": {\"khz\": %u, \"transfers\": %llu, \"nacks\": %llu, \"timeouts\": %llu, "
            "\"stretch_max_us\": %.3f, \"stretch_mean_us\": %.3f, \"aborts\": %llu, "
            "\"bus_held\": %s, \"last_release_after_us\": %.1f}",
            cfg_i2c_khz, (unsigned long long)i2c_transfers, (unsigned long long)i2c_nacks,
            (unsigned long long)i2c_timeouts, (double)stretch_max / CYCLES_PER_US,
            stretch_n ? (double)stretch_total / (double)stretch_n / CYCLES_PER_US : 0.0,
            (unsigned long long)bus_aborts, bus_held ? "true" : "false",
            (double)bus_release_cycles / CYCLES_PER_US);
    if (cfg_profile) {
        fprintf(o, ", \"isr\": {");
        int first = 1;
        for (int v = 1; v < N_VECTORS; v++) {
            isr_stat_t *s = &isr_stat[v];
            if (!s->count)
                continue;
            fprintf(o, "%s\"%s\": {\"count\": %llu, \"mean_cycles\": %.1f, \"max_cycles\": %llu, "
                    "\"min_cycles\": %llu}", first ? "" : ", ", vector_name(v),
                    (unsigned long long)s->count, (double)s->total / (double)s->count,
                    (unsigned long long)s->max, (unsigned long long)s->min);
            first = 0;
        }
        fprintf(o, "}, \"cli_max_cycles\": %llu, \"cli_max_at_us\": %.1f",
                (unsigned long long)cli_max, (double)cli_max_at / CYCLES_PER_US);
    }
    fprintf(o, "}\n");
}

static void start_generators(uint64_t at_cycle)
{
    for (int c = 0; c < 2; c++)
        if (!hall[c].running)
            hall_start(&hall[c], at_cycle);
    if (!adc_running)
        adc_start(at_cycle);
}

static void usage(void)
{
    fprintf(stderr,
            "usage: harness FIRMWARE.elf [--primary-rpm R] [--secondary-rpm R] [--adc-code C]\n"
            "       [--adc-status S] [--adc-error-every N] [--adc-hz F] [--bounce]\n"
            "       [--i2c-khz K] [--addr A] [--start-us T] [--pulse-us T] [--duty F]\n"
            "       [--glitch-hz N] [--glitch-us W] [--profile]\n"
            "       [--profile-from-us T]\n");
    exit(2);
}

int main(int argc, char **argv)
{
    const char *elf = NULL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
#define OPT(name) (strcmp(a, name) == 0 && v && (i++, 1))
        if (OPT("--primary-rpm")) cfg_rpm[0] = atof(v);
        else if (OPT("--secondary-rpm")) cfg_rpm[1] = atof(v);
        else if (OPT("--adc-code")) cfg_adc_code = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--adc-status")) cfg_adc_status = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--adc-error-every")) cfg_adc_err_every = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--adc-hz")) cfg_adc_hz = atof(v);
        else if (OPT("--i2c-khz")) cfg_i2c_khz = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--addr")) cfg_addr = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--start-us")) cfg_start_us = atof(v);
        else if (OPT("--pulse-us")) cfg_pulse_us = atof(v);
        else if (OPT("--duty")) cfg_duty = atof(v);
        else if (OPT("--glitch-hz")) cfg_glitch_hz = atof(v);
        else if (OPT("--glitch-us")) cfg_glitch_us = atof(v);
        else if (OPT("--profile-from-us")) cfg_profile_from_us = atof(v);
        else if (strcmp(a, "--bounce") == 0) cfg_bounce = 1;
        else if (strcmp(a, "--legacy-pullups") == 0) cfg_legacy_pullups = 1;
        else if (strcmp(a, "--profile") == 0) cfg_profile = 1;
        else if (a[0] == '-') usage();
        else elf = a;
#undef OPT
    }
    if (!elf)
        usage();

    /* simavr prints traces on stdout: keep the protocol on a private copy of it. */
    int fd = dup(1);
    dup2(2, 1);
    proto_out = fdopen(fd, "w");
    avr_global_logger_set(logger);

    static elf_firmware_t fw;
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "harness: cannot read %s\n", elf);
        return 1;
    }
    /* Arduino ELFs carry no .mmcu section. */
    strcpy(fw.mmcu, "atmega328p");
    fw.frequency = (uint32_t)F_CPU_HZ;
    avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "harness: no atmega328p in libsimavr\n");
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->log = LOG_WARNING;
    avr->data[MCUSR_ADDR] = 0x01;  /* PORF: this is a power-on (RAM is zero in simavr) */

    /* The TWI peripheral is number 0 (not '0') on the mega328. */
    twi_vec = find_vector(TWI_VECTOR);
    if (!twi_vec) {
        fprintf(stderr, "harness: TWI vector not found\n");
        return 1;
    }
    avr_register_io_write(avr, REG_TWCR, twcr_write_hook, NULL);
    for (int b = 0; b < 3; b++)
        pcint_vec[b] = find_vector(3 + b);  /* PCINT0..2 are vectors 3..5 */
    avr_register_io_write(avr, REG_PCIFR, pcifr_write_hook, NULL);
    bit_cycles = F_CPU_HZ / (cfg_i2c_khz * 1000ull);
    byte_cycles = 9 * bit_cycles;

    for (int c = 0; c < 2; c++) {
        hall[c].ch = c;
        hall[c].pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2 + c);
        hall[c].sensor_level = hall[c].glitch_level = hall[c].out_level = 1;
        drive_pin(hall[c].pin, 2 + c, 1);  /* sensor output idles high */
    }
    pin_dout = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 5);
    drive_pin(pin_dout, 5, 1);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 4),
                            adc_sclk_notify, NULL);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_notify, NULL);
    start_generators((uint64_t)(cfg_start_us * CYCLES_PER_US));

    char line[512];
    uint8_t wr[256], rd[256];
    while (fgets(line, sizeof line, stdin)) {
        char cmd[16] = "", a1[300] = "", a2[32] = "", a3[32] = "";
        sscanf(line, "%15s %299s %31s %31s", cmd, a1, a2, a3);
        if (strcmp(cmd, "run") == 0) {
            uint64_t target = (uint64_t)(atof(a1) * CYCLES_PER_US);
            run_until(target);
            fprintf(proto_out, "ok %.3f\n", (double)avr->cycle / CYCLES_PER_US);
        } else if (strcmp(cmd, "xfer") == 0 || strcmp(cmd, "abort") == 0) {
            /* abort: like xfer, but the master stops clocking after n/2 bytes of the read */
            int nw = 0, nr = atoi(a2);
            if (a3[0])
                run_until((uint64_t)(atof(a3) * CYCLES_PER_US));
            if (strcmp(a1, "-") != 0)
                for (const char *p = a1; p[0] && p[1] && nw < (int)sizeof wr; p += 2) {
                    unsigned b;
                    sscanf(p, "%2x", &b);
                    wr[nw++] = (uint8_t)b;
                }
            if (nr < 0 || nr > (int)sizeof rd)
                nr = 0;
            int r = i2c_transfer(wr, nw, rd, nr, strcmp(cmd, "abort") == 0 ? nr / 2 : -1);
            if (r == 3) {
                fprintf(proto_out, "busheld\n");
            } else if (r == 1) {
                i2c_nacks++;
                fprintf(proto_out, "nack\n");
            } else if (r == 2) {
                i2c_timeouts++;
                fprintf(proto_out, "timeout\n");
            } else {
                fprintf(proto_out, "ok ");
                if (!nr)
                    fprintf(proto_out, "-");
                for (int i = 0; i < nr; i++)
                    fprintf(proto_out, "%02x", rd[i]);
                fprintf(proto_out, "\n");
            }
        } else if (strcmp(cmd, "uwrite") == 0) {
            /* bytes from the host into UART0 (simavr paces them at the baud rate) */
            if (a2[0])
                run_until((uint64_t)(atof(a2) * CYCLES_PER_US));
            if (strcmp(a1, "-") != 0)
                for (const char *p = a1; p[0] && p[1]; p += 2) {
                    unsigned b;
                    sscanf(p, "%2x", &b);
                    avr_raise_irq(uart_in, (uint32_t)b);
                    uart_bytes_in++;
                }
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "uread") == 0) {
            /* run until the MCU has sent a whole packet (0x00) or max_us passed; hand over
             * whatever it sent: "ok <t_us> <hex|->" */
            uint64_t limit = avr->cycle + (uint64_t)(atof(a1) * CYCLES_PER_US);
            double w0 = now_s();
            uint64_t c0 = avr->cycle;
            while (!uart_packet_end && avr->cycle < limit && !crashed)
                step();
            wall_s += now_s() - w0;
            wall_cycles += avr->cycle - c0;
            fprintf(proto_out, "ok %.3f ", (double)avr->cycle / CYCLES_PER_US);
            if (!uart_rx_n)
                fprintf(proto_out, "-");
            for (int i = 0; i < uart_rx_n; i++)
                fprintf(proto_out, "%02x", uart_rx[i]);
            fprintf(proto_out, "\n");
            uart_rx_n = 0;
            uart_packet_end = 0;
        } else if (strcmp(cmd, "gen") == 0) {
            gen_enabled = strcmp(a1, "off") != 0;
            if (gen_enabled)
                start_generators(avr->cycle + CYCLES_PER_US);
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "reset") == 0) {
            avr_reset(avr);
            /* simavr clears the I/O registers; a real reset sets its cause in MCUSR. */
            avr->data[MCUSR_ADDR] = (uint8_t)(a1[0] ? strtoul(a1, NULL, 16) : 0x08);
            in_isr = -1;
            cli_start = 0;
            /* The rig keeps turning through the reset: restart the generators (their
             * timers may have been cleared with the MCU's) and the AD7171 idles. */
            for (int c = 0; c < 2; c++) {
                avr_cycle_timer_cancel(avr, hall_timer, &hall[c]);
                avr_cycle_timer_cancel(avr, glitch_timer, &hall[c]);
                hall[c].running = 0;
                hall[c].step = 0;
                hall[c].sensor_level = hall[c].glitch_level = hall[c].out_level = 1;
                drive_pin(hall[c].pin, 2 + c, 1);
            }
            avr_cycle_timer_cancel(avr, adc_timer, NULL);
            avr_cycle_timer_cancel(avr, adc_rdy_high, NULL);
            adc_running = 0;
            adc_bit = 24;
            adc_ready = 0;
            drive_pin(pin_dout, 5, 1);
            if (gen_enabled)
                start_generators(avr->cycle + CYCLES_PER_US);
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "stats") == 0) {
            print_stats();
        } else if (strcmp(cmd, "quit") == 0) {
            break;
        } else {
            fprintf(proto_out, "error unknown command\n");
        }
        fflush(proto_out);
        if (crashed) {
            fprintf(stderr, "harness: firmware crashed at cycle %llu pc 0x%x\n",
                    (unsigned long long)avr->cycle, avr->pc);
        }
    }
    return 0;
}
