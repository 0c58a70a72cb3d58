/* Host -> device commands: [op, args..., crc_hi, crc_lo]. Pure C. */
#ifndef DYNO_CMD_H
#define DYNO_CMD_H
#include <stdint.h>

#define OP_POLL 0x10u
#define OP_ACK_POLL 0x11u
#define OP_SET_DEBOUNCE 0x20u
#define OP_CLEAR_COUNTERS 0x21u
#define OP_INFO 0x30u
#define OP_SET_CHANNELS 0x22u  /* u8 mask of optional channels to queue (bit 0: input torque) */
#define OP_CAPS 0x31u          /* the next read returns the capabilities frame */
#define OP_SET_SUPERVISOR 0x23u  /* u16 min period primary us, u16 min period secondary us, u16 timeout ms */
#define OP_PULSE_RUN_ENABLE 0x24u  /* u16 ms: drop the run-enable that long, then on again (no latch) */
#define PULSE_MS_MAX 1000u         /* a longer (or zero) pulse is ignored, counted bad ... */
#define PULSE_LATCH 0xFFFFu        /* ... but this one: off, latched until the next SET_SUPERVISOR */

#define CMD_MAX_LEN 9u  /* SET_SUPERVISOR: op + 6 + crc */

enum { CMD_OK = 0, CMD_ERR_SHORT = 1, CMD_ERR_OP = 2, CMD_ERR_LENGTH = 3, CMD_ERR_CRC = 4 };

/* Total length of a command with this op (CRC included), or 0 for an unknown op. */
static inline uint8_t cmd_length(uint8_t op)
{
    switch (op) {
    case OP_POLL: case OP_CLEAR_COUNTERS: case OP_INFO: case OP_CAPS: return 3;
    case OP_SET_CHANNELS: return 4;
    case OP_PULSE_RUN_ENABLE: return 5;
    case OP_ACK_POLL: return 6;  /* v2: op, u16 boot_id, u8 seq, crc */
    case OP_SET_DEBOUNCE: return 7;
    case OP_SET_SUPERVISOR: return 9;
    default: return 0;
    }
}

/* Check a whole command. crc_residue is the CRC-16 run over all n bytes (CRC
 * included), 0 for an intact command: the TWI ISR accumulates it byte by byte.
 * Inline: it runs in the TWI ISR, where a call costs ~50 cycles of register saves. */
static inline __attribute__((always_inline)) uint8_t cmd_check(const uint8_t *buf, uint8_t n,
                                                               uint16_t crc_residue)
{
    if (n < 3)
        return CMD_ERR_SHORT;
    uint8_t len = cmd_length(buf[0]);
    if (!len)
        return CMD_ERR_OP;
    if (n != len)
        return CMD_ERR_LENGTH;
    if (crc_residue != 0)
        return CMD_ERR_CRC;
    return CMD_OK;
}

#endif
