/**
 * @file board_stm32f407.h
 * @brief The reference board's pin and clock choices, in one place: an STM32F407 (e.g. the
 *        STM32F4-DISCOVERY with its 8 MHz crystal) and a GY-86 module on I2C1.
 *
 * Sources: RM0090 rev 19 (STM32F405/407 reference manual), DS8626 rev 9 (STM32F405xx/407xx
 * data sheet), AN2606 (system memory boot mode). docs/firmware.md, "The reference board",
 * has the wiring and the clock tree as a table.
 *
 *   signal             pin    function                   DS8626 table "Alternate function mapping"
 *   host link TX       PA9    USART1_TX, AF7, push-pull  (pin 101 in LQFP144 / 68 in LQFP100)
 *   host link RX       PA10   USART1_RX, AF7, pull-up    (pin 102 / 69)
 *   GY-86 SCL          PB8    I2C1_SCL, AF4, open-drain  (pin 139 / 95), weak pull-up
 *   GY-86 SDA          PB9    I2C1_SDA, AF4, open-drain  (pin 140 / 96), weak pull-up
 *   GY-86 INTA (MPU6050 INT) and DRDY (HMC5883L): not connected. The samples are timed by
 *   TIM2 and read by polling; the MPU6050's data-ready interrupt is configured (gy86.c) but
 *   its pin is not used. GY-86 FSYNC: to GND (the MPU6050 ignores it: EXT_SYNC_SET = 0).
 *   The GY-86 has its own I2C pull-ups; the internal ones only keep a bus without a module idle.
 */
#ifndef BOARD_STM32F407_H
#define BOARD_STM32F407_H

#include "stm32f4.h"

/* --------------------------------------------------------------------------- clocks (RM0090 section 7.2) */

#define BOARD_HSE_HZ 8000000u /**< the crystal (the STM32F4-DISCOVERY's is 8 MHz) */
/** The internal RC oscillator, +-1 % at 25 degC (DS8626, HSI oscillator characteristics). */
#define BOARD_HSI_HZ 16000000u

/* Main PLL (RM0090 section 7.3.2, RCC_PLLCFGR): f(VCO in) = source / M (1..2 MHz),
 * f(VCO) = in * N (100..432 MHz), SYSCLK = VCO / P (at most 168 MHz), 48 MHz = VCO / Q. */
#define BOARD_PLL_M_HSE 8u   /**< 8 MHz / 8 = 1 MHz */
#define BOARD_PLL_M_HSI 16u  /**< 16 MHz / 16 = 1 MHz: the same N, P, Q give the same clocks */
#define BOARD_PLL_N 336u     /**< VCO 336 MHz */
#define BOARD_PLL_P 2u       /**< SYSCLK 168 MHz */
#define BOARD_PLL_Q 7u       /**< 48 MHz (USB OTG FS, SDIO, RNG; unused here) */
#define BOARD_SYSCLK_HZ 168000000u

/* Bus prescalers (RM0090 section 7.3.3, RCC_CFGR): AHB /1 = 168 MHz, APB1 /4 = 42 MHz (its
 * maximum), APB2 /2 = 84 MHz (its maximum). A timer on an APB with a prescaler other than 1
 * runs at twice the bus clock (RM0090 section 7.2, the clock tree figure): TIM2/TIM5 84 MHz. */
#define BOARD_CFGR_PRESCALERS (RCC_CFGR_HPRE_DIV1 | RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2)

/* Flash wait states for HCLK 150..168 MHz at 2.7..3.6 V: 5 (RM0090 section 3, table "number of
 * wait states according to CPU clock (HCLK) frequency"). */
#define BOARD_FLASH_WAIT_STATES 5u

/* Bounded waits of the clock set-up, in loop iterations: no timer runs yet. One iteration is
 * at least 4 cycles of the 16 MHz HSI (a peripheral read and a branch), so these are at least
 * 100 ms for the crystal (DS8626, HSE oscillator characteristics: 2 ms typical start-up),
 * 25 ms for the PLL lock (DS8626, main PLL characteristics: 300 us at most) and for the
 * clock switch (a few cycles). */
#define BOARD_HSE_START_LOOPS 400000u
#define BOARD_PLL_LOCK_LOOPS 100000u
#define BOARD_SWITCH_LOOPS 100000u

/* --------------------------------------------------------------------------- host link: USART1 (RM0090 section 30) */

#define BOARD_LINK_BAUD 921600u
#define BOARD_LINK_GPIO GPIOA
#define BOARD_LINK_GPIO_EN RCC_AHB1ENR_GPIOAEN
#define BOARD_LINK_TX_PIN 9u
#define BOARD_LINK_RX_PIN 10u
#define BOARD_LINK_AF 7u /**< AF7: USART1..3 */

/* --------------------------------------------------------------------------- GNSS receiver: USART2 */

#define BOARD_GNSS_GPIO GPIOA
#define BOARD_GNSS_GPIO_EN RCC_AHB1ENR_GPIOAEN
#define BOARD_GNSS_TX_PIN 2u /**< PA2 USART2_TX: to the receiver's RX */
#define BOARD_GNSS_RX_PIN 3u /**< PA3 USART2_RX: from the receiver's TX */
#define BOARD_GNSS_AF 7u     /**< AF7: USART1..3 */

/* --------------------------------------------------------------------------- sensors: I2C1 (RM0090 section 27) */

#define BOARD_I2C_GPIO GPIOB
#define BOARD_I2C_GPIO_EN RCC_AHB1ENR_GPIOBEN
#define BOARD_I2C_SCL_PIN 8u
#define BOARD_I2C_SDA_PIN 9u
#define BOARD_I2C_AF 4u           /**< AF4: I2C1..3 */
#define BOARD_I2C_SPEED_HZ 400000u /**< fast mode; the MPU6050 and the HMC5883L both allow 400 kHz */

/* --------------------------------------------------------------------------- interrupts */

#define BOARD_PRIORITY_LINK 1u   /**< received bytes must not wait behind the tick */
#define BOARD_PRIORITY_TIMERS 2u /**< TIM2 sample tick, TIM5 clock wrap */
#define BOARD_PRIORITY_GNSS 1u   /**< the receiver's bytes, like the host's: a ring each, no wait */

/* --------------------------------------------------------------------------- system bootloader (AN2606) */

#define BOARD_SYSTEM_MEMORY 0x1FFF0000u /**< STM32F40xxx/41xxx: system memory, the ST bootloader (AN2606) */

#endif /* BOARD_STM32F407_H */
