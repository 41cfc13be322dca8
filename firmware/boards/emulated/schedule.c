/**
 * @file schedule.c
 * @brief Real-time sample schedule of the emulated boards (see schedule.h).
 */
#include "schedule.h"

void schedule_start(schedule_t *s, uint64_t now_us, uint32_t rate_mhz)
{
    s->origin_us = now_us;
    s->rate_mhz = rate_mhz;
    s->handed_out = 0;
}

uint32_t schedule_ticks(schedule_t *s, uint64_t now_us)
{
    /* whole periods elapsed: us * mHz / 10^9 (overflows after 18 000 years at 32 kHz) */
    const uint64_t due = (now_us - s->origin_us) * s->rate_mhz / 1000000000u;
    uint64_t lost;
    if (due <= s->handed_out) {
        return 0;
    }
    lost = due - s->handed_out > SCHEDULE_FIFO_SAMPLES ? due - s->handed_out - SCHEDULE_FIFO_SAMPLES : 0;
    s->handed_out += lost + 1u;
    return (uint32_t)(lost + 1u);
}

uint64_t schedule_next_us(const schedule_t *s)
{
    return s->origin_us + ((s->handed_out + 1u) * 1000000000u + s->rate_mhz - 1u) / s->rate_mhz;
}
