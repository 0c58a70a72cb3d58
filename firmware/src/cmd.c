#include "cmd.h"

uint8_t cmd_check(const uint8_t *buf, uint8_t n, uint16_t crc_residue)
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
