/* COBS framing for the USB-serial link (docs/protocol.md): packets contain no 0x00, a
 * 0x00 ends each one, so a receiver resynchronises at the next 0x00 after garbage. */
#ifndef DYNO_COBS_H
#define DYNO_COBS_H
#include <stdint.h>

/* Encodes n bytes (n <= 253) into out (n + 1 bytes); no terminator. Returns length. */
uint8_t cobs_encode(const uint8_t *in, uint8_t n, uint8_t *out);
/* Decodes n bytes (no terminator) into out (<= n - 1 bytes). Returns length, or 0xFF
 * on malformed input (a zero byte or a code running past the end). */
uint8_t cobs_decode(const uint8_t *in, uint8_t n, uint8_t *out);

#endif
