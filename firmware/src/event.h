/* One timestamped event as queued by the capture ISRs and the ADC reader. Pure C. */
#ifndef DYNO_EVENT_H
#define DYNO_EVENT_H
#include <stdint.h>

/* Event tags on the wire (docs/protocol.md). */
#define TAG_PRIMARY 1u
#define TAG_SECONDARY 2u
#define TAG_ADC 3u
#define TAG_INPUT 4u    /* the engine-side input torque AD7171 (issue 27): tag 3's layout */
#define TAG_SUPERVISOR 5u  /* the run-enable output changed (issue 37): tag 3's layout, code/status below */
#define TAG_GAP 0x80u   /* or-ed into the tag: events were lost just before this one */

/* 8 bytes exactly, so the ring index math is a shift. */
typedef struct {
    uint32_t t_us;   /* device time, free-running us counter (wraps at 2^32) */
    uint16_t code;   /* ADC code (0 for Hall edges) */
    uint8_t status;  /* AD7171 status bits (0 for Hall edges) */
    uint8_t tag;     /* TAG_* */
} dyno_event_t;

#endif
