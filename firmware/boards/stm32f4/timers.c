/**
 * @file timers.c
 * @brief Sample tick (TIM2) and microsecond clock (TIM5); see timers.h.
 */
#include "timers.h"

#include "stm32f4.h"

static volatile uint32_t clock_wraps;  /* TIM5 overflows: the high 32 bits of the microseconds */
static volatile uint32_t ticks_raised; /* TIM2 updates so far */
static uint32_t ticks_taken;           /* of those, handed to the application */

void timers_clock_init(uint32_t timer_clk_hz, uint8_t priority)
{
    clock_wraps = 0;
    TIM5->CR1 = TIM_CR1_URS; /* only an overflow raises the update interrupt, not the UG below */
    TIM5->PSC = timer_clk_hz / 1000000u - 1u;
    TIM5->ARR = 0xFFFFFFFFu;
    TIM5->EGR = TIM_EGR_UG; /* load the prescaler now */
    TIM5->SR = 0;
    TIM5->DIER = TIM_DIER_UIE;
    TIM5->CR1 = TIM_CR1_URS | TIM_CR1_CEN;
    irq_enable(IRQ_TIM5, priority);
}

void timers_tim5_irq(void)
{
    if (TIM5->SR & TIM_SR_UIF) {
        TIM5->SR = TIM_SR_FLAGS & ~TIM_SR_UIF; /* rc_w0: the other flags written 1 stay, reserved bits 0 */
        ++clock_wraps;
    }
}

uint64_t timers_time_us(void)
{
    const uint32_t primask = irq_save();
    uint32_t high = clock_wraps;
    const uint32_t low = TIM5->CNT;
    if ((TIM5->SR & TIM_SR_UIF) && low < 0x80000000u) {
        ++high; /* it wrapped after the interrupt was masked: the handler has not counted it yet */
    }
    irq_restore(primask);
    return ((uint64_t)high << 32) | low;
}

void timers_tick_start(uint32_t timer_clk_hz, uint32_t rate_mhz, uint8_t priority)
{
    const uint64_t period = ((uint64_t)timer_clk_hz * 1000u + rate_mhz / 2u) / rate_mhz;
    TIM2->CR1 = TIM_CR1_URS;
    TIM2->DIER = 0;
    TIM2->PSC = 0;
    TIM2->ARR = (uint32_t)(period > 1u ? period - 1u : 1u);
    TIM2->CNT = 0;
    TIM2->EGR = TIM_EGR_UG;
    TIM2->SR = 0;
    ticks_taken = ticks_raised;
    TIM2->DIER = TIM_DIER_UIE;
    TIM2->CR1 = TIM_CR1_URS | TIM_CR1_CEN;
    irq_enable(IRQ_TIM2, priority);
}

void timers_tick_stop(void)
{
    TIM2->CR1 = 0;
    TIM2->DIER = 0;
    ticks_taken = ticks_raised;
}

void timers_tim2_irq(void)
{
    if (TIM2->SR & TIM_SR_UIF) {
        TIM2->SR = TIM_SR_FLAGS & ~TIM_SR_UIF;
        ++ticks_raised;
    }
}

uint32_t timers_tick_take(void)
{
    const uint32_t raised = ticks_raised;
    const uint32_t n = raised - ticks_taken;
    ticks_taken = raised;
    return n;
}

int timers_tick_pending(void)
{
    return ticks_raised != ticks_taken;
}
