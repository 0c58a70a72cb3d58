#include "supervisor.h"

static void event(dyno_event_t *ev, uint32_t t_us, uint16_t code, uint8_t status)
{
    ev->t_us = t_us;
    ev->code = code;
    ev->status = status;
    ev->tag = TAG_SUPERVISOR;
}

void supervisor_init(supervisor_t *s)
{
    s->beat_us = 0;
    s->min_period_us[0] = s->min_period_us[1] = 0;
    s->timeout_ms = 0;
    s->armed = 0;
    s->on = 0;
}

void supervisor_arm(supervisor_t *s, uint16_t min_primary_us, uint16_t min_secondary_us, uint16_t timeout_ms,
                    uint32_t now_us, dyno_event_t *ev)
{
    s->min_period_us[0] = min_primary_us;
    s->min_period_us[1] = min_secondary_us;
    s->timeout_ms = timeout_ms;
    s->beat_us = now_us;
    s->armed = 1;
    s->on = 1;
    event(ev, now_us, 0, SUP_ON);
}

uint8_t supervisor_period(supervisor_t *s, uint8_t ch, uint32_t period_us, uint32_t t_us, dyno_event_t *ev)
{
    uint16_t min = s->min_period_us[ch];
    if (!s->on || !min || period_us >= min)
        return 0;
    s->on = 0;
    event(ev, t_us, (uint16_t)period_us, (uint8_t)(SUP_OVERSPEED_PRIMARY + ch));  /* < min <= 65535 */
    return 1;
}

uint8_t supervisor_check(supervisor_t *s, uint32_t now_us, dyno_event_t *ev)
{
    uint32_t limit_us = (uint32_t)s->timeout_ms * 1000u;
    if (!s->on || (uint32_t)(now_us - s->beat_us) <= limit_us)
        return 0;
    s->on = 0;
    event(ev, s->beat_us + limit_us, s->timeout_ms, SUP_HEARTBEAT);
    return 1;
}
