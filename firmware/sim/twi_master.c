/* The Pi's I2C master in the simavr harness. simavr 1.6 cannot complete a slave-transmit
 * (it never produces TWI status 0xB8/0xC0; fixed upstream in 2022), so the harness does
 * not use simavr's TWI message IRQs at all: it is the bus. For every bus event it waits
 * one byte time (9 SCL clocks), writes the TWI status the real hardware would produce
 * into TWSR (keeping the prescaler bits), puts received data into TWDR, raises the TWI
 * vector, and waits for the ISR to clear TWINT -- the time SCL is held low, i.e. clock
 * stretching, which it measures. Transmitted bytes are taken from TWDR after the ISR. Any
 * slave (our driver, or Arduino's Wire for the v0 sketch) sees the same register
 * behaviour as on silicon. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>

#include "sim_avr.h"
#include "sim_interrupts.h"
#include "harness.h"

/* ATmega328P data-space addresses of the TWI registers. */
#define REG_TWSR 0xB9
#define REG_TWAR 0xBA
#define REG_TWDR 0xBB
#define REG_TWCR 0xBC
#define TWCR_TWINT 0x80
#define TWCR_TWEA 0x40
#define TWCR_TWEN 0x04
#define TWI_VECTOR 24

unsigned cfg_i2c_khz = 100, cfg_addr = 0x03;
uint64_t i2c_transfers, i2c_nacks, i2c_timeouts;
static uint64_t stretch_max, stretch_total, stretch_n;
static uint64_t byte_cycles, bit_cycles;
static avr_int_vector_t *twi_vec;

/* simavr 1.6 does not clear TWINT when the ISR writes 1 to it (TWI's vector is
 * "sticky"), so "the slave released SCL" is detected from the write itself. */
static int twint_written;

/* A master that gave up mid-read leaves the slave transmitter driving SDA: the bus is
 * held until the slave disables its TWI unit (TWEN written 0: its timeout). */
static int bus_held;
static uint64_t bus_held_since, bus_release_cycles, bus_aborts;

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

static void twcr_write_hook(avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)a; (void)addr; (void)param;
    if (v & TWCR_TWINT)
        twint_written = 1;
    batch_break();  /* (the master acts after the instruction that wrote TWCR) */
    if (bus_held && !(v & TWCR_TWEN)) {
        bus_held = 0;
        bus_release_cycles = avr->cycle - bus_held_since;
    }
}

int i2c_init(void)
{
    /* The TWI peripheral is number 0 (not '0') on the mega328. */
    twi_vec = find_vector(TWI_VECTOR);
    if (!twi_vec) {
        fprintf(stderr, "harness: TWI vector not found\n");
        return 0;
    }
    avr_register_io_write(avr, REG_TWCR, twcr_write_hook, NULL);
    bit_cycles = F_CPU_HZ / (cfg_i2c_khz * 1000ull);
    byte_cycles = 9 * bit_cycles;
    return 1;
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
int i2c_transfer(const uint8_t *wr, int nw, uint8_t *rd, int nr, int abort_after)
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

void print_i2c(FILE *o)
{
    fprintf(o, "\"i2c\": {\"khz\": %u, \"transfers\": %llu, \"nacks\": %llu, \"timeouts\": %llu, "
            "\"stretch_max_us\": %.3f, \"stretch_mean_us\": %.3f, \"aborts\": %llu, "
            "\"bus_held\": %s, \"last_release_after_us\": %.1f}",
            cfg_i2c_khz, (unsigned long long)i2c_transfers, (unsigned long long)i2c_nacks,
            (unsigned long long)i2c_timeouts, (double)stretch_max / CYCLES_PER_US,
            stretch_n ? (double)stretch_total / (double)stretch_n / CYCLES_PER_US : 0.0,
            (unsigned long long)bus_aborts, bus_held ? "true" : "false",
            (double)bus_release_cycles / CYCLES_PER_US);
}
