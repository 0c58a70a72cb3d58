#include "cobs.h"

uint8_t cobs_encode(const uint8_t *in, uint8_t n, uint8_t *out)
{
    uint8_t code_at = 0, w = 1, code = 1;
    for (uint8_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = w++;
            code = 1;
        } else {
            out[w++] = in[i];
            code++;
        }
    }
    out[code_at] = code;
    return w;
}

uint8_t cobs_decode(const uint8_t *in, uint8_t n, uint8_t *out)
{
    uint8_t r = 0, w = 0;
    while (r < n) {
        uint8_t code = in[r++];
        if (code == 0 || (uint16_t)r + code - 1u > n)
            return 0xFF;
        for (uint8_t k = 1; k < code; k++) {
            if (in[r] == 0)
                return 0xFF;
            out[w++] = in[r++];
        }
        /* A code below 0xFF stands for a zero, except at the very end of the packet. */
        if (code < 0xFF && r < n)
            out[w++] = 0;
    }
    return w;
}
