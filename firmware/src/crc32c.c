#include "crc32c.h"
#include "port.h"

/* T[i] = i run through 4 steps of the reflected polynomial 0x82F63B78. */
static const uint32_t crc32c_nibble[16] PORT_FLASH = {
    0x00000000ul, 0x105EC76Ful, 0x20BD8EDEul, 0x30E349B1ul, 0x417B1DBCul, 0x5125DAD3ul,
    0x61C69362ul, 0x7198540Dul, 0x82F63B78ul, 0x92A8FC17ul, 0xA24BB5A6ul, 0xB21572C9ul,
    0xC38D26C4ul, 0xD3D3E1ABul, 0xE330A81Aul, 0xF36E6F75ul,
};

uint32_t crc32c(const uint8_t *data, uint8_t len)
{
    uint32_t c = 0xFFFFFFFFul;
    while (len--) {
        c ^= *data++;
        c = (c >> 4) ^ PORT_FLASH_U32(&crc32c_nibble[c & 15u]);
        c = (c >> 4) ^ PORT_FLASH_U32(&crc32c_nibble[c & 15u]);
    }
    return c ^ 0xFFFFFFFFul;
}
