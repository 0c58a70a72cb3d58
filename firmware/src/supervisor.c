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
    s->pulsing = 0;
    s->pulse_ms = 0;
    s->pulse_start_us = 0;
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
    s->pulsing = 0;
    event(ev, now_us, 0, SUP_ON);
}

uint8_t supervisor_period(supervisor_t *s, uint8_t ch, uint32_t period_us, uint32_t t_us, dyno_event_t *ev)
{
    uint16_t min = s->min_period_us[ch];
    if (!(s->on || s->pulsing) || !min || period_us >= min)
        return 0;
    s->on = 0;
    s->pulsing = 0;  /* an over-speed during a pulse latches it off */
    event(ev, t_us, (uint16_t)period_us, (uint8_t)(SUP_OVERSPEED_PRIMARY + ch));  /* < min <= 65535 */
    return 1;
}

uint8_t supervisor_pulse(supervisor_t *s, uint16_t ms, uint32_t now_us, dyno_event_t *ev)
{
    if (ms == 0xFFFFu && (s->on || s->pulsing)) {  /* PULSE_LATCH */
        s->on = 0;
        s->pulsing = 0;
        event(ev, now_us, ms, SUP_PULSE);
        return 1;
    }
    if (!s->on)
        return 0;
    s->on = 0;
    s->pulsing = 1;
    s->pulse_ms = ms;
    s->pulse_start_us = now_us;
    event(ev, now_us, ms, SUP_PULSE);
    return 1;
}

uint8_t supervisor_check(supervisor_t *s, uint32_t now_us, dyno_event_t *ev)
{
    uint32_t limit_us = (uint32_t)s->timeout_ms * 1000u;
    if (s->pulsing) {
        uint32_t len_us = (uint32_t)s->pulse_ms * 1000u;
        if ((uint32_t)(now_us - s->pulse_start_us) < len_us)
            return 0;
        uint32_t end_us = s->pulse_start_us + len_us;
        s->pulsing = 0;
        if ((uint32_t)(now_us - s->beat_us) > limit_us) {
            /* the host fell silent meanwhile: off for good, as if the pulse had not been */
            event(ev, s->beat_us + limit_us, s->timeout_ms, SUP_HEARTBEAT);
            return 1;
        }
        s->on = 1;
        event(ev, end_us, 0, SUP_ON);
        return 1;
    }
    if (!s->on || (uint32_t)(now_us - s->beat_us) <= limit_us)
        return 0;
    s->on = 0;
    event(ev, s->beat_us + limit_us, s->timeout_ms, SUP_HEARTBEAT);
    return 1;
}
