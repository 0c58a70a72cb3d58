/* Boot identity and reset cause, taken in .init3 before the C runtime touches RAM. AVR only.
 *
 * g_boot_id differs on every boot without any EEPROM write (docs/protocol.md, "Boots
 * and resets"): it lives in .noinit, so RAM that survives a watchdog, external or
 * brown-out reset carries the previous boot's id and the new boot takes id + 1; after
 * a power-on (RAM undefined; SRAM's power-up pattern is largely the same on every
 * power-up of a given chip) it is a CRC-16 over all 2 KiB of SRAM as found, whose
 * noisy bits make it differ from the previous power-up's. simavr starts with zeroed
 * RAM, so there the ids are deterministic and still differ on every reset.
 *
 * g_reset_cause is MCUSR's low nibble (PORF, EXTRF, BORF, WDRF). Optiboot (the new
 * Nano bootloader) clears MCUSR and hands its value over in r2; the old ATmegaBOOT
 * leaves MCUSR alone. */
#ifndef DYNO_BOOT_H
#define DYNO_BOOT_H
#include <stdint.h>

extern uint16_t g_boot_id;
extern uint8_t g_reset_cause;

#endif
