/**
 * @file timers.h
 * @brief The two general-purpose timers the boards use (RM0090 section 18):
 *        TIM2 (32-bit) raises the sample tick, TIM5 (32-bit) counts microseconds.
 *
 * The boards call timers_tim2_irq() / timers_tim5_irq() from their handlers.
 */
#ifndef TIMERS_H
#define TIMERS_H

#include <stdint.h>

/** @brief TIM5 as a free-running 1 MHz counter (prescaler from `timer_clk_hz`), extended to 64 bits
 *         by its update interrupt at `priority`. */
void timers_clock_init(uint32_t timer_clk_hz, uint8_t priority);

/** @brief Microseconds since timers_clock_init(). */
uint64_t timers_time_us(void);

/** @brief Start (or restart) the TIM2 update interrupt at `rate_mhz` (mHz) from `timer_clk_hz`. */
void timers_tick_start(uint32_t timer_clk_hz, uint32_t rate_mhz, uint8_t priority);

/** @brief Stop the tick. */
void timers_tick_stop(void);

/** @brief Ticks since the last call. */
uint32_t timers_tick_take(void);

/** @brief 1 when a tick is waiting (for the idle check). */
int timers_tick_pending(void);

void timers_tim2_irq(void);
void timers_tim5_irq(void);

#endif /* TIMERS_H */
