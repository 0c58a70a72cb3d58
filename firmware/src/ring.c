#include "ring.h"

ring_t g_ring;

void ring_init(ring_t *r)
{
    r->head = r->tail = 0;
    r->overflow = 0;
    r->dropped = 0;
    r->gap = 0;
}
