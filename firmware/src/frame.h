/* v2 frame encoding (docs/protocol.md). Pure C: compiled for the AVR and natively,
 * where test/native checks it byte for byte against dyno/protocol/vectors/v2.hex. */
#ifndef DYNO_FRAME_H
#define DYNO_FRAME_H
#include <stdint.h>
#include "event.h"

#define FRAME_VERSION 2u
#define FRAME_MAX 32u          /* the Nano's Wire/TWI buffer: no read is longer */
#define FRAME_HEADER_LEN 13u
#define FRAME_CRC_LEN 4u       /* CRC-32C */
#define FRAME_PAYLOAD_MAX (FRAME_MAX - FRAME_HEADER_LEN - FRAME_CRC_LEN)  /* 15 */
#define FRAME_EVENTS_MAX 5u    /* 15 / 3: five Hall edges */
#define FRAME_INFO_LEN 32u

#define KIND_DATA 0x44u  /* 'D' */
#define KIND_INFO 0x49u  /* 'I' */
#define KIND_CAPS 0x43u  /* 'C': capabilities (the optional channels fitted and enabled) */
#define FRAME_CAPS_LEN 20u
#define CHANNEL_INPUT 0x01u      /* SET_CHANNELS / capabilities bit: the input torque converter */
#define CHANNEL_SUPERVISOR 0x02u /* capabilities bit: the run-enable output (channels: exists; enabled: armed) */
#define CONVERTER_AD7171 1u

#define FLAG_RESET 0x01u     /* first frame since boot */
#define FLAG_MORE 0x02u      /* events still queued behind this frame */
#define FLAG_OVERFLOW 0x04u  /* ring overflowed since the last CLEAR_COUNTERS */
#define FLAG_RUN 0x08u       /* the run-enable output was on when the frame was built (issue 37) */
#define FLAG_CAUSE_SHIFT 4u  /* bits 4..7: reset cause (MCUSR's PORF, EXTRF, BORF, WDRF) */

typedef struct {
    uint8_t seq, flags;
    uint16_t boot_id;
    uint8_t fw_major, fw_minor, fw_patch;
    uint32_t uptime_ms;
    uint16_t debounce_primary_us, debounce_secondary_us;
    uint16_t lockout[2], glitch[2];
    uint8_t twi_timeouts, bus_errors;
} frame_info_t;

static inline uint8_t frame_event_len(uint8_t tag)
{
    /* TAG_ADC, TAG_INPUT, TAG_SUPERVISOR: [tag, i16 dt, u16 code, u8 status]; the Hall edges [tag, i16 dt] */
    return (uint8_t)(tag & (uint8_t)~TAG_GAP) >= TAG_ADC ? 6u : 3u;
}

/* How many of the n events (ev[i] from get(ctx, i)) fit one frame, by size and by the
 * i16 dt from the first event's time. */
typedef const dyno_event_t *(*frame_event_get_t)(const void *ctx, uint8_t i);
uint8_t frame_fit(frame_event_get_t get, const void *ctx, uint8_t n);

/* Writes a full 32-byte data frame (zero padded) with the first n events (frame_fit's
 * count); t0 = first event's time, or now_us when n == 0. Returns L. Bounded by
 * construction: an event that would not fit the 32 bytes (events changing under a
 * racing reader) ends the frame, never the buffer; *n_done (if not NULL) gets the
 * number of events actually encoded. */
uint8_t frame_encode_data(uint8_t *out, uint8_t seq, uint8_t flags, uint16_t boot_id,
                          uint16_t dropped, uint32_t now_us, frame_event_get_t get,
                          const void *ctx, uint8_t n, uint8_t *n_done);

uint8_t frame_encode_info(uint8_t *out, const frame_info_t *info);
/* The capabilities frame (docs/protocol.md "Input torque channel"), padded to 32 bytes. */
uint8_t frame_encode_caps(uint8_t *out, uint8_t seq, uint8_t flags, uint16_t boot_id, uint8_t channels,
                          uint8_t enabled, uint8_t converter, uint32_t rate_mhz);

/* An event array as a frame_event_get_t context (tests, simple callers). */
const dyno_event_t *frame_array_get(const void *ctx, uint8_t i);

#endif
