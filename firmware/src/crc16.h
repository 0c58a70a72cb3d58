/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, MSB first, no final xor). Pure C.
 *
 * Byte-wise without a table (the classic shift/xor form): ~25 AVR cycles per byte and
 * no 512-byte table in flash. Because there is no final xor, running the CRC over a
 * message *and* its big-endian CRC gives 0: the TWI ISR uses that to check a command
 * incrementally, one byte per interrupt. */
#ifndef DYNO_CRC16_H
#define DYNO_CRC16_H
#include <stdint.h>

#define CRC16_INIT 0xFFFFu

static inline uint16_t crc16_update(uint16_t crc, uint8_t byte)
{
    uint8_t x = (uint8_t)(crc >> 8) ^ byte;
    x ^= (uint8_t)(x >> 4);
    return (uint16_t)((crc << 8) ^ ((uint16_t)x << 12) ^ ((uint16_t)x << 5) ^ x);
}

uint16_t crc16(const uint8_t *data, uint8_t len);

#endif
