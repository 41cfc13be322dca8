/**
 * @file clock_stm32f407.h
 * @brief Clock set-up of the reference board: 8 MHz HSE -> PLL -> 168 MHz (RM0090 sections
 *        3.5, 5.4 and 7), with the fallbacks HSI -> PLL -> 168 MHz and HSI alone at 16 MHz.
 *
 * The clocks the rest of the board uses (baud rates, I2C timing, timer prescalers, the cycle
 * counter's frequency) are decoded from RCC_CFGR and RCC_PLLCFGR after the set-up, i.e. the
 * clocks actually in use, whatever happened.
 */
#ifndef CLOCK_STM32F407_H
#define CLOCK_STM32F407_H

#include <stdint.h>

/** Where SYSCLK comes from after clocks_init(). */
typedef enum {
    CLOCKS_PLL_FROM_HSE = 0, /**< the intended configuration */
    CLOCKS_PLL_FROM_HSI = 1, /**< the crystal did not start: the same 168 MHz, HSI accuracy */
    CLOCKS_HSI = 2,          /**< the PLL (or the switch to it) failed: 16 MHz */
} clocks_source_t;

/** What the set-up did, and the clocks in use. */
typedef struct {
    clocks_source_t source;
    uint32_t sysclk_hz;     /**< SYSCLK = HCLK (AHB /1): the CPU, the DWT cycle counter */
    uint32_t hclk_hz;
    uint32_t pclk1_hz;      /**< APB1: I2C1, TIM2/TIM5's bus */
    uint32_t pclk2_hz;      /**< APB2: USART1 */
    uint32_t apb1_timer_hz; /**< the clock of the timers on APB1 (TIM2..TIM5): pclk1, doubled when APB1 is divided */
    const char *problem;    /**< what went wrong, one sentence without the final period; NULL when nothing did */
} clocks_t;

/** @brief Configure the clocks (called once, first thing after reset: bounded loop counts, no timer). */
void clocks_init(clocks_t *clocks);

/** @brief Decode the clocks in use from RCC_CFGR / RCC_PLLCFGR (clocks->source and ->problem unchanged). */
void clocks_read(clocks_t *clocks);

#endif /* CLOCK_STM32F407_H */
