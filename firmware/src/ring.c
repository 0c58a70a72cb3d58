#include "ring.h"

ring_t g_ring;

void ring_init(ring_t *r)
{
    static const uint8_t guard[RING_GUARD_LEN] = RING_GUARD_BYTES;
    for (uint8_t i = 0; i < RING_GUARD_LEN; i++)
        r->guard_lo[i] = r->guard_hi[i] = guard[i];
    r->head = r->tail = 0;
    r->overflow = 0;
    r->dropped = 0;
    r->gap = 0;
}
