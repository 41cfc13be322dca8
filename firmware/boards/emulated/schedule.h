/**
 * @file schedule.h
 * @brief When an emulated board's samples are due, in real time.
 *
 * Sample k is due k periods after the clock started, on the board's microsecond clock.
 * The emulated sensor keeps its samples in a FIFO (as the MPU6050 can): a board that got
 * the CPU late (its host was busy) catches up from it, one sample per call, instead of
 * losing the samples it missed; only beyond SCHEDULE_FIFO_SAMPLES late are samples lost,
 * and the application counts them as dropped.
 */
#ifndef SCHEDULE_H
#define SCHEDULE_H

#include <stdint.h>

/** Samples a late board can still catch up. */
#define SCHEDULE_FIFO_SAMPLES 64u

/** A running sample clock. All members are private. */
typedef struct {
    uint64_t origin_us;  /**< when the clock started */
    uint32_t rate_mhz;   /**< sample rate, mHz */
    uint64_t handed_out; /**< samples given to the application since origin_us */
} schedule_t;

/** @brief Start at `now_us` with `rate_mhz` (> 0). */
void schedule_start(schedule_t *s, uint64_t now_us, uint32_t rate_mhz);

/** @brief board_sample_ticks(): 0 (none due), 1 (one due), or 1 + the samples lost beyond the FIFO. */
uint32_t schedule_ticks(schedule_t *s, uint64_t now_us);

/** @brief When the next sample is due, us on the same clock. */
uint64_t schedule_next_us(const schedule_t *s);

#endif /* SCHEDULE_H */
