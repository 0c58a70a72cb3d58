/* CRC-32C (Castagnoli), the v2 frame check (docs/protocol.md). Pure C.
 *
 * Reflected, init and final xor 0xFFFFFFFF; check value crc32c("123456789") = 0xE3069283.
 * Nibble-wise with a 16-entry table in flash (64 B; a byte table would take 1 KiB):
 * ~60 AVR cycles per byte, ~110 us for a full frame, in the main loop only. */
#ifndef DYNO_CRC32C_H
#define DYNO_CRC32C_H
#include <stdint.h>

uint32_t crc32c(const uint8_t *data, uint8_t len);

#endif
