/* Firmware-in-the-loop harness: runs any ATmega328P ELF in simavr (Debian's libsimavr
 * 1.6) with the rig around it, and plays the I2C master for a host process that talks
 * to it over stdin/stdout.
 *
 *   - Hall sensors on PD2/PD3 (INT0/INT1) and the AD7171 on PD4/PD5 as external
 *     drivers: sensors.c (one pulse per revolution, ringing, glitches; a conversion
 *     every 1/adc_hz s, shifted out on SCLK).
 *   - The host's USB serial on UART0 (uwrite/uread below).
 *   - The Pi's I2C master at the bus's bit rate, with clock stretching: twi_master.c.
 *   - The run-enable output on PD7 (issue 37), timed to the cycle, read as a static level or as a
 *     charge pump's pulse train: run_enable.c ("run_enable" in stats).
 *   - The MCU itself (ELF, stepping and profiling, register fixes for simavr 1.6, guard
 *     bytes around the firmware's event ring): mcu.c.
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
 *   poke <addr> <byte>   write one byte of data space (hex; tests of the guard check) -> "ok"
 *   stats                one JSON object (after every command the ring's guard bytes
 *                        are checked: "ring_guard" counts violations)
 *   quit
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_irq.h"
#include "harness.h"

FILE *proto_out;
static double cfg_start_us = 50000.0;

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

/* ---- stats and command loop ------------------------------------------------------ */
static void print_stats(void)
{
    FILE *o = proto_out;
    fprintf(o, "{\"cycle\": %llu, \"sim_s\": %.6f, \"wall_s\": %.4f, \"sim_per_wall\": %.3f, "
            "\"crashed\": %s, ",
            (unsigned long long)avr->cycle, (double)avr->cycle / F_CPU_HZ, wall_s,
            wall_s > 0 ? (double)wall_cycles / F_CPU_HZ / wall_s : 0.0, crashed ? "true" : "false");
    plant_print(o);
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
    input_print(o);
    run_enable_print(o);
    /* WDTCSR as the firmware left it (WDE 0x08: the watchdog resets the MCU) */
    fprintf(o, "\"wdtcsr\": %u, \"eeprom_writes\": %llu, ", avr->data[REG_WDTCSR],
            (unsigned long long)eeprom_writes);
    print_i2c(o);
    fprintf(o, ", ");
    print_guard(o);
    if (cfg_profile)
        print_profile(o);
    fprintf(o, "}\n");
}

static void start_generators(uint64_t at_cycle)
{
    for (int c = 0; c < 2; c++)
        if (!hall[c].running)
            hall_start(&hall[c], at_cycle);
    if (!adc_running)
        adc_start(at_cycle);
    input_start(at_cycle);
}

static void usage(void)
{
    fprintf(stderr,
            "usage: harness FIRMWARE.elf [--primary-rpm R] [--secondary-rpm R] [--adc-code C]\n"
            "       [--adc-status S] [--adc-error-every N] [--adc-hz F] [--bounce]\n"
            "       [--i2c-khz K] [--addr A] [--start-us T] [--pulse-us T] [--duty F]\n"
            "       [--glitch-hz N] [--glitch-us W] [--profile] [--input-hz F] [--input-code C]\n"
            "       [--profile-from-us T] [--enable-model auto|static|pump] [--plant]\n");
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
        else if (OPT("--input-hz")) cfg_input_hz = atof(v);
        else if (OPT("--input-code")) cfg_input_code = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--i2c-khz")) cfg_i2c_khz = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--addr")) cfg_addr = (unsigned)strtoul(v, NULL, 0);
        else if (OPT("--start-us")) cfg_start_us = atof(v);
        else if (OPT("--pulse-us")) cfg_pulse_us = atof(v);
        else if (OPT("--duty")) cfg_duty = atof(v);
        else if (OPT("--glitch-hz")) cfg_glitch_hz = atof(v);
        else if (OPT("--glitch-us")) cfg_glitch_us = atof(v);
        else if (OPT("--profile-from-us")) cfg_profile_from_us = atof(v);
        else if (OPT("--enable-model")) cfg_enable_model = strcmp(v, "pump") == 0 ? 2 : strcmp(v, "static") == 0 ? 1 : 0;
        else if (strcmp(a, "--bounce") == 0) cfg_bounce = 1;
        else if (strcmp(a, "--legacy-pullups") == 0) cfg_legacy_pullups = 1;
        else if (strcmp(a, "--profile") == 0) cfg_profile = 1;
        else if (strcmp(a, "--plant") == 0) cfg_plant = 1;
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
    if (!mcu_load(elf) || !i2c_init())
        return 1;

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
    input_init();
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_notify, NULL);
    start_generators((uint64_t)(cfg_start_us * CYCLES_PER_US));

    static char line[65536];
    uint8_t wr[256], rd[256];
    while (fgets(line, sizeof line, stdin)) {
        char cmd[16] = "", a1[300] = "", a2[32] = "", a3[32] = "";
        sscanf(line, "%15s %299s %31s %31s", cmd, a1, a2, a3);
        if (strcmp(cmd, "run") == 0) {
            uint64_t target = (uint64_t)(atof(a1) * CYCLES_PER_US);
            run_until(target);
            if (cfg_plant) {  /* the run-enable's changes ride on the reply (one round trip per lockstep) */
                fprintf(proto_out, "ok %.3f ", (double)avr->cycle / CYCLES_PER_US);
                plant_run_enable(proto_out);
            } else {
                fprintf(proto_out, "ok %.3f\n", (double)avr->cycle / CYCLES_PER_US);
            }
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
                if (cfg_plant)  /* the MCU's clock after the transfer: the plant keeps its events ahead of it */
                    fprintf(proto_out, " %.3f", (double)avr->cycle / CYCLES_PER_US);
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
        } else if (strcmp(cmd, "ev") == 0) {
            plant_events(line + 3);
        } else if (strcmp(cmd, "gen") == 0) {
            gen_enabled = strcmp(a1, "off") != 0;
            if (gen_enabled)
                start_generators(avr->cycle + CYCLES_PER_US);
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "reset") == 0) {
            mcu_reset((uint8_t)(a1[0] ? strtoul(a1, NULL, 16) : 0x08));
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
            input_reset();
            plant_reset();
            if (gen_enabled)
                start_generators(avr->cycle + CYCLES_PER_US);
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "poke") == 0) {
            unsigned long addr = strtoul(a1, NULL, 16);
            if (addr >= 0x100 && addr < 0x900)  /* the 2 KiB of SRAM */
                avr->data[addr] = (uint8_t)strtoul(a2, NULL, 16);
            fprintf(proto_out, "ok\n");
        } else if (strcmp(cmd, "stats") == 0) {
            print_stats();
        } else if (strcmp(cmd, "quit") == 0) {
            break;
        } else {
            fprintf(proto_out, "error unknown command\n");
        }
        guard_check();
        fflush(proto_out);
        if (crashed) {
            fprintf(stderr, "harness: firmware crashed at cycle %llu pc 0x%x\n",
                    (unsigned long long)avr->cycle, avr->pc);
        }
    }
    return 0;
}
