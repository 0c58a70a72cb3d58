#include "frame.h"
#include "crc32c.h"

const dyno_event_t *frame_array_get(const void *ctx, uint8_t i)
{
    return (const dyno_event_t *)ctx + i;
}

uint8_t frame_fit(frame_event_get_t get, const void *ctx, uint8_t n)
{
    uint8_t used = 0, k;
    uint32_t t0 = 0;
    for (k = 0; k < n && k < FRAME_EVENTS_MAX; k++) {
        const dyno_event_t *e = get(ctx, k);
        uint8_t size = frame_event_len(e->tag);
        if (k == 0)
            t0 = e->t_us;
        /* dt must fit an i16: the frame ends where a later event is too far away. */
        int32_t dt = (int32_t)(e->t_us - t0);
        if (used + size > FRAME_PAYLOAD_MAX || dt < -32768 || dt > 32767)
            break;
        used = (uint8_t)(used + size);
    }
    return k;
}

static uint8_t *put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
    return p + 2;
}

static uint8_t *put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v >> 24);
    p[1] = (uint8_t)(v >> 16);
    p[2] = (uint8_t)(v >> 8);
    p[3] = (uint8_t)v;
    return p + 4;
}

static uint8_t finish(uint8_t *out, uint8_t *p)
{
    uint8_t len = (uint8_t)(p - out + FRAME_CRC_LEN);
    out[1] = len;
    p = put_u32(p, crc32c(out, (uint8_t)(len - FRAME_CRC_LEN)));
    while (p < out + FRAME_MAX)
        *p++ = 0;  /* padding is checked by the host */
    return len;
}

uint8_t frame_encode_data(uint8_t *out, uint8_t seq, uint8_t flags, uint16_t boot_id,
                          uint16_t dropped, uint32_t now_us, frame_event_get_t get,
                          const void *ctx, uint8_t n, uint8_t *n_done)
{
    uint32_t t0 = n ? get(ctx, 0)->t_us : now_us;
    uint8_t *p = out;
    uint8_t *const end = out + FRAME_MAX - FRAME_CRC_LEN;
    uint8_t k;
    *p++ = FRAME_VERSION;
    *p++ = 0;  /* length, filled in by finish() */
    *p++ = KIND_DATA;
    *p++ = seq;
    *p++ = flags;
    p = put_u16(p, boot_id);
    p = put_u16(p, dropped);
    p = put_u32(p, t0);
    for (k = 0; k < n; k++) {
        const dyno_event_t *e = get(ctx, k);
        uint8_t tag = e->tag;  /* read once: the size below and the byte written agree */
        if (p + frame_event_len(tag) > end)
            break;
        *p++ = tag;
        p = put_u16(p, (uint16_t)(e->t_us - t0));  /* two's complement i16 */
        if ((uint8_t)(tag & (uint8_t)~TAG_GAP) >= TAG_ADC) {  /* TAG_ADC, TAG_INPUT, TAG_SUPERVISOR */
            p = put_u16(p, e->code);
            *p++ = e->status;
        }
    }
    if (n_done)
        *n_done = k;
    return finish(out, p);
}

uint8_t frame_encode_info(uint8_t *out, const frame_info_t *info)
{
    uint8_t *p = out;
    *p++ = FRAME_VERSION;
    *p++ = FRAME_INFO_LEN;
    *p++ = KIND_INFO;
    *p++ = info->seq;
    *p++ = info->flags;
    p = put_u16(p, info->boot_id);
    *p++ = info->fw_major;
    *p++ = info->fw_minor;
    *p++ = info->fw_patch;
    p = put_u32(p, info->uptime_ms);
    p = put_u16(p, info->debounce_primary_us);
    p = put_u16(p, info->debounce_secondary_us);
    for (uint8_t c = 0; c < 2; c++)
        p = put_u16(p, info->lockout[c]);
    for (uint8_t c = 0; c < 2; c++)
        p = put_u16(p, info->glitch[c]);
    *p++ = info->twi_timeouts;
    *p++ = info->bus_errors;
    return finish(out, p);  /* 28 bytes + CRC-32C: exactly the 32-byte buffer */
}

uint8_t frame_encode_caps(uint8_t *out, uint8_t seq, uint8_t flags, uint16_t boot_id, uint8_t channels,
                          uint8_t enabled, uint8_t converter, uint32_t rate_mhz)
{
    uint8_t *p = out;
    *p++ = FRAME_VERSION;
    *p++ = FRAME_CAPS_LEN;
    *p++ = KIND_CAPS;
    *p++ = seq;
    *p++ = flags;
    p = put_u16(p, boot_id);
    *p++ = channels;
    *p++ = enabled;
    *p++ = converter;
    p = put_u32(p, rate_mhz);
    *p++ = 0;  /* reserved */
    *p++ = 0;
    return finish(out, p);
}
