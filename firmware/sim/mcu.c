/* The MCU side of the simavr harness: loading the ELF, stepping (with optional ISR and
 * interrupts-off profiling), the register behaviour simavr 1.6 gets wrong, and the
 * guard bytes around the firmware's event ring. */
#define _POSIX_C_SOURCE 200809L
#include <fcntl.h>
#include <stdarg.h>
#include <stddef.h>
#include <gelf.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_elf.h"
#include "sim_interrupts.h"
#include "harness.h"
#include "ring.h"  /* the firmware's ring layout: guard offsets are the same on the AVR */

avr_t *avr;
int crashed;
int cfg_profile = 0;
double cfg_profile_from_us = 100000.0;
double wall_s;
uint64_t wall_cycles;

/* ---- stepping, with optional ISR / interrupts-off profiling ---------------------- */
typedef struct {
    uint64_t count, total, max, min;
} isr_stat_t;
static isr_stat_t isr_stat[N_VECTORS];
static int in_isr = -1;
static uint64_t isr_start;
static uint64_t cli_start, cli_max, cli_max_at;

/* DYNO_HARNESS_TRACE=<file> (a debugging aid, found for issue 27's spikes; no profile meanwhile):
 * one line per Hall line change ("P cycle ch level s=sensor g=spike", sensors.c), per ISR entry
 * ("E cycle vector pind=PIND") and per RETI ("X cycle vector", and for INT0/INT1 the channel's
 * state after it, read from capture.c's hall[2]: hall_ch_t's layout, 14 bytes, is assumed). */
FILE *trace_out;
static uint32_t trace_hall_addr;
static int trace_vec = -1;
static void trace_isr_exit(int v, uint64_t c)
{
    if (v != 1 && v != 2) {
        fprintf(trace_out, "X %llu %d\n", (unsigned long long)c, v);
        return;
    }
    const uint8_t *h = avr->data + trace_hall_addr + 14u * (unsigned)(v - 1);
    uint32_t fall = (uint32_t)h[0] | (uint32_t)h[1] << 8 | (uint32_t)h[2] << 16 | (uint32_t)h[3] << 24;
    fprintf(trace_out, "X %llu %d st=%u acc=%u fall=%lu end16=%u lock=%u\n", (unsigned long long)c, v,
            h[12], h[13], (unsigned long)fall, (unsigned)(h[8] | h[9] << 8), (unsigned)(h[10] | h[11] << 8));
}

void step(void)
{
    if (trace_out) {
        uint32_t pc = avr->pc;
        uint16_t op = (uint16_t)(avr->flash[pc] | avr->flash[pc + 1] << 8);
        int st = avr_run(avr);
        if (st == cpu_Crashed || st == cpu_Done)
            crashed = 1;
        run_enable_watch();
        if (trace_vec >= 0 && op == 0x9518) {
            trace_isr_exit(trace_vec, avr->cycle);
            trace_vec = -1;
        } else if (trace_vec < 0) {
            uint32_t npc = avr->pc;
            if (npc && npc < N_VECTORS * 4 && !(npc & 3)) {
                trace_vec = (int)(npc / 4);
                fprintf(trace_out, "E %llu %d pind=%02x eifr=%02x gpior0=%02x\n", (unsigned long long)avr->cycle, trace_vec,
                        avr->data[0x29], avr->data[0x3C], avr->data[0x3E]);
            }
        }
        return;
    }
    if (!cfg_profile) {
        int st = avr_run(avr);
        if (st == cpu_Crashed || st == cpu_Done)
            crashed = 1;
        run_enable_watch();
        return;
    }
    uint32_t pc = avr->pc;
    uint16_t op = (uint16_t)(avr->flash[pc] | avr->flash[pc + 1] << 8);
    uint64_t before = avr->cycle;
    int st = avr_run(avr);
    if (st == cpu_Crashed || st == cpu_Done)
        crashed = 1;
    run_enable_watch();
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

double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- batched stepping ------------------------------------------------------------- */
#define BATCH_MAX_CYCLES (1u << 20)
static int stop_tag, break_tag;
static int reset_unwatched;  /* a reset command cleared DDRD/PORTD with no write: D7 not watched since */

static avr_cycle_count_t no_op_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    return 0;
}

/* The batch in progress ends after the current instruction: a cycle timer due now.  (simavr recounts a batch
 * from the earliest timer whenever one is set or cancelled, so a later recount in the same instruction keeps it.) */
void batch_break(void)
{
    avr_cycle_timer_register(avr, 0, no_op_timer, &break_tag);
}

static void port_d_write_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    batch_break();
}

void run_until(uint64_t cycle)
{
    double w0 = now_s();
    uint64_t c0 = avr->cycle;
    if (!trace_out && !cfg_profile && avr->cycle < cycle) {
        /* Batched: simavr's avr_run_one runs instruction after instruction while no cycle timer is due, no
         * interrupt is pending and the CPU runs (run_cycle_limit; 1 by default: one instruction per call).
         * The same instructions at the same cycles as one per call: timers fire after the instruction that
         * reaches them, interrupts are taken after the instruction that raised them, and a timer at `cycle`
         * ends the run after the instruction that reaches it, as the loop below stops.  What the harness
         * watches between instructions ends a batch at once (batch_break): a write to PORTD or DDRD (the
         * run-enable, D7: timed to the cycle as before) and the TWI ISR's write to TWCR. */
        if (reset_unwatched) {  /* the first instruction after a reset alone: D7's drop seen after it, as before */
            reset_unwatched = 0;
            avr->run_cycle_limit = avr->run_cycle_count = 1;
            avr->run(avr);
            if (avr->state == cpu_Crashed || avr->state == cpu_Done)
                crashed = 1;
            run_enable_watch();
        }
        avr->run_cycle_limit = BATCH_MAX_CYCLES;
        avr_cycle_timer_register(avr, cycle - avr->cycle, no_op_timer, &stop_tag);
        while (avr->cycle < cycle && !crashed) {
            avr->run(avr);
            if (avr->state == cpu_Crashed || avr->state == cpu_Done)
                crashed = 1;
            run_enable_watch();
        }
        avr_cycle_timer_cancel(avr, no_op_timer, &stop_tag);
        avr->run_cycle_limit = 1;  /* step() (profiles, traces, the TWI master's waits): one instruction a call */
        avr->run_cycle_count = 1;
    }
    while (avr->cycle < cycle && !crashed)
        step();
    wall_s += now_s() - w0;
    wall_cycles += avr->cycle - c0;
}

avr_int_vector_t *find_vector(int num)
{
    for (int i = 0; i < avr->interrupts.vector_count; i++)
        if (avr->interrupts.vector[i] && avr->interrupts.vector[i]->vector == num)
            return avr->interrupts.vector[i];
    return NULL;
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

void print_profile(FILE *o)
{
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

/* ---- register behaviour simavr 1.6 lacks ------------------------------------------ */
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

/* EIFR likewise (INTF0/INTF1): 1.6 stores a 1 written to clear a flag, so after capture_init's
 * EIFR = INTF0 | INTF1 the register read INTF1 set with no INT1 pending (the firmware's INT0 ISR reads
 * INTF1 to give INT1's edge its Timer1 snapshot). Cleared as on silicon. */
#define REG_EIFR 0x3C
static avr_int_vector_t *int_vec[2];

static void eifr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    for (int b = 0; b < 2; b++)
        if (v & (1u << b)) {
            a->data[addr] &= (uint8_t)~(1u << b);
            if (int_vec[b])
                int_vec[b]->pending = 0;
        }
}

/* ---- EEPROM writes (wear: the firmware must not write per boot) ------------------- */
/* Counted at the write strobe (EEPE set in EECR); simavr's EEPROM module, registered on
 * the same address first, still performs the write. */
#define REG_EECR 0x3F
#define EECR_EEPE 0x02
uint64_t eeprom_writes;

static void eecr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)a; (void)addr; (void)param;
    if (v & EECR_EEPE)
        eeprom_writes++;
}

/* ---- guard bytes around the firmware's event ring ---------------------------------- */
/* The ELF's g_ring (found in its symbol table) starts with RING_GUARD_LEN guard bytes
 * before the entries and has as many right after them (src/ring.h: the same offsets on
 * the AVR and here, the entries being 8 bytes). Checked after every command once the
 * firmware has written them after a boot; any other value is a write outside the ring. */
static const uint8_t guard_pattern[RING_GUARD_LEN] = RING_GUARD_BYTES;
static uint32_t guard_addr[2];
static int guard_found, guard_armed;
static uint64_t guard_checks, guard_violations, guard_first_cycle;

/* A data symbol of the ELF by name; a file-static one may carry LTO's suffix ("hall.lto_priv.32"). */
static int elf_symbol(const char *path, const char *name, uint32_t *value, uint32_t *size)
{
    int fd = open(path, O_RDONLY), found = 0;
    if (fd < 0 || elf_version(EV_CURRENT) == EV_NONE)
        return 0;
    Elf *e = elf_begin(fd, ELF_C_READ, NULL);
    Elf_Scn *scn = NULL;
    while (e && !found && (scn = elf_nextscn(e, scn))) {
        GElf_Shdr sh;
        if (!gelf_getshdr(scn, &sh) || sh.sh_type != SHT_SYMTAB)
            continue;
        Elf_Data *d = elf_getdata(scn, NULL);
        for (size_t i = 0; d && i < sh.sh_size / sh.sh_entsize; i++) {
            GElf_Sym sym;
            gelf_getsym(d, (int)i, &sym);
            const char *n = elf_strptr(e, sh.sh_link, sym.st_name);
            size_t len = strlen(name);
            if (n && strncmp(n, name, len) == 0 && (n[len] == 0 || n[len] == '.')) {
                *value = (uint32_t)sym.st_value;
                *size = (uint32_t)sym.st_size;
                found = 1;
                break;
            }
        }
    }
    if (e)
        elf_end(e);
    close(fd);
    return found;
}

static void guard_init(const char *elf)
{
    uint32_t addr, size;
    size_t hi = offsetof(ring_t, guard_hi);
    if (!elf_symbol(elf, "g_ring", &addr, &size) || size < hi + RING_GUARD_LEN)
        return;  /* another sketch (the v0 one): nothing to check */
    addr &= 0xFFFFu;  /* data addresses are 0x800000 + RAM address in AVR ELFs */
    guard_addr[0] = addr + (uint32_t)offsetof(ring_t, guard_lo);
    guard_addr[1] = addr + (uint32_t)hi;
    guard_found = 1;
}

void guard_check(void)
{
    if (!guard_found)
        return;
    int ok = memcmp(avr->data + guard_addr[0], guard_pattern, RING_GUARD_LEN) == 0 &&
             memcmp(avr->data + guard_addr[1], guard_pattern, RING_GUARD_LEN) == 0;
    if (!guard_armed) {
        guard_armed = ok;  /* ring_init has run */
        return;
    }
    guard_checks++;
    if (!ok) {
        if (!guard_violations++)
            guard_first_cycle = avr->cycle;
        guard_armed = 0;  /* count each corruption once, re-arm if the firmware rewrites them */
    }
}

void print_guard(FILE *o)
{
    fprintf(o, "\"ring_guard\": {\"found\": %s, \"armed\": %s, \"checks\": %llu, "
            "\"violations\": %llu, \"first_violation_us\": %.1f}",
            guard_found ? "true" : "false", guard_armed ? "true" : "false",
            (unsigned long long)guard_checks, (unsigned long long)guard_violations,
            (double)guard_first_cycle / CYCLES_PER_US);
}

/* ---- load and reset --------------------------------------------------------------- */
static void logger(avr_t *a, const int level, const char *fmt, va_list ap)
{
    (void)a;
    if (level <= LOG_WARNING)
        vfprintf(stderr, fmt, ap);
}

int mcu_load(const char *elf)
{
    avr_global_logger_set(logger);
    static elf_firmware_t fw;
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "harness: cannot read %s\n", elf);
        return 0;
    }
    /* Arduino ELFs carry no .mmcu section. */
    strcpy(fw.mmcu, "atmega328p");
    fw.frequency = (uint32_t)F_CPU_HZ;
    avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "harness: no atmega328p in libsimavr\n");
        return 0;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->log = LOG_WARNING;
    avr->data[MCUSR_ADDR] = 0x01;  /* PORF: this is a power-on (RAM is zero in simavr) */
    for (int b = 0; b < 3; b++)
        pcint_vec[b] = find_vector(3 + b);  /* PCINT0..2 are vectors 3..5 */
    avr_register_io_write(avr, REG_PCIFR, pcifr_write_hook, NULL);
    for (int b = 0; b < 2; b++)
        int_vec[b] = find_vector(1 + b);  /* INT0, INT1 */
    avr_register_io_write(avr, REG_EIFR, eifr_write_hook, NULL);
    avr_register_io_write(avr, REG_EECR, eecr_write_hook, NULL);
    /* PORTD and DDRD writes end a batch: run_enable_watch() sees D7 after the instruction that changed it */
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), IOPORT_IRQ_REG_PORT),
                            port_d_write_notify, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), IOPORT_IRQ_DIRECTION_ALL),
                            port_d_write_notify, NULL);
    guard_init(elf);
    const char *tp = getenv("DYNO_HARNESS_TRACE");
    uint32_t sz;
    if (tp && elf_symbol(elf, "hall", &trace_hall_addr, &sz) && sz == 28) {  /* 2 x hall_ch_t */
        trace_hall_addr &= 0xFFFFu;
        trace_out = fopen(tp, "w");
    }
    return 1;
}

void mcu_reset(uint8_t mcusr)
{
    avr_reset(avr);
    reset_unwatched = 1;
    /* simavr clears the I/O registers; a real reset sets its cause in MCUSR. */
    avr->data[MCUSR_ADDR] = mcusr;
    in_isr = trace_vec = -1;
    cli_start = 0;
    guard_armed = 0;  /* RAM is kept; the new boot's ring_init rewrites the guards */
}
