/* Build-time configuration of the Nano firmware (one place to change a value). */
#ifndef DYNO_CONFIG_H
#define DYNO_CONFIG_H

/* Reported in the INFO frame; bump on any behaviour change the host may care about.
 * The major version is the wire protocol's (v2). */
#define FW_VERSION_MAJOR 2
#define FW_VERSION_MINOR 1
#define FW_VERSION_PATCH 0
/* The input torque AD7171's nominal rate as announced (mHz): 125 S/s, as the brake-side one. */
#define INPUT_RATE_MHZ 125000ul
#define INPUT_PROBE_US 20000ul  /* boot: a fitted converter's RDY falls within 2.5 conversion periods */

/* docs/protocol.md: the Pi addresses the Nano at 0x03 (the thesis rig's address). */
#define I2C_ADDRESS 0x03
/* A TWI transfer open this long without progress is aborted by the slave, so the bus is
 * free within 25 ms like SMBus's (millis() ticks are 1.024 ms, hence 23 here). */
#define I2C_SLAVE_TIMEOUT_MS 23u
#define SERIAL_BAUD 115200UL

/* Hall lock-out after the end of an accepted pulse: a quarter of the last accepted
 * period, at least the floor, at most the cap. The thesis's fixed 10 ms / 6 ms from
 * the edge dropped every other edge above 6,000 / 10,000 rpm; a quarter period leaves
 * room for pulses up to 3/4 of a period and for speed doubling within a revolution
 * (far beyond the rig's inertia). The floor (SET_DEBOUNCE sets it per channel) covers
 * the first pulse, before a period is known: above the 0.74 ms of release ringing the
 * harness models, below the 3.8 ms gap between pulses at 15,000 rpm. The cap: after
 * a stop, pulses come back slower than 1,200 rpm. */
#define DEBOUNCE_PRIMARY_US_DEFAULT 1000u
#define DEBOUNCE_SECONDARY_US_DEFAULT 1000u
#define LOCKOUT_CAP_US 50000u
/* Minimum Hall pulse width: a shorter low pulse (an ignition spike) is a glitch,
 * counted and dropped. Real pulses are >= ~100 us (magnet arc at 15,000 rpm); 50 us
 * also rejects two overlapping 20 us spikes (up to 40 us low). */
#define HALL_MIN_PULSE_US 50u

/* Event ring: 64 x 8 B = 512 B holds ~0.2 s of events at 3800/7600 rpm + 125 Hz ADC
 * (~315 events/s; a poll retires up to 6), so a host that stalls for ~30 polls loses
 * nothing. 128 would not fit the 60 % RAM budget with the serial buffers. Power of 2. */
#ifndef RING_SIZE
#define RING_SIZE 64u
#endif

/* An unsent empty frame carries "device time now" as t0; refresh it this often so
 * the host's idea of device time stays within a few ms. */
#define PROTO_EMPTY_REFRESH_US 2000u
/* INFO frame (uptime) is rebuilt this often in the main loop, never in the ISR. */
#define INFO_REFRESH_MS 50u

/* 1 for Nanos with the old ATmegaBOOT bootloader (PlatformIO env nanoatmega328): no
 * watchdog, which that bootloader would turn into a reset loop. */
#ifndef DYNO_OLD_BOOTLOADER
#define DYNO_OLD_BOOTLOADER 0
#endif

/* The thesis wiring has pull-ups on the Hall sensor boards; set to 1 for bare
 * open-collector sensors. */
#define HALL_INTERNAL_PULLUP 0

#endif
