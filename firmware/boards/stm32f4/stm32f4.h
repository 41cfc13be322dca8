/**
 * @file stm32f4.h
 * @brief The STM32F405/407 registers the boards use, from the reference manual RM0090
 *        (rev 19) and the Cortex-M4 generic user guide. Our own small header: no vendor
 *        HAL or CMSIS is needed. Offsets are checked at compile time below.
 */
#ifndef STM32F4_H
#define STM32F4_H

#include <stddef.h>
#include <stdint.h>

#define REG volatile uint32_t

/* --------------------------------------------------------------------------- core peripherals */

typedef struct {
    REG CPUID, ICSR, VTOR, AIRCR, SCR, CCR;
    volatile uint8_t SHPR[12];
    REG SHCSR, CFSR, HFSR, DFSR, MMFAR, BFAR, AFSR;
} scb_t;
#define SCB ((scb_t *)0xE000ED00u)
#define SCB_AIRCR_SYSRESETREQ (0x05FA0000u | (1u << 2)) /* VECTKEY + SYSRESETREQ */
#define SCB_SCR_SEVONPEND (1u << 4)

#define NVIC_ISER ((REG *)0xE000E100u) /* set-enable, 32 interrupts per word */
#define NVIC_ICER ((REG *)0xE000E180u) /* clear-enable */
#define NVIC_IPR ((volatile uint8_t *)0xE000E400u) /* priority, one byte per interrupt (top 4 bits used) */

typedef struct {
    REG CTRL, LOAD, VAL, CALIB;
} systick_t;
#define SYSTICK ((systick_t *)0xE000E010u)

/** Debug exception and monitor control: TRCENA enables the DWT. */
#define DEMCR (*(REG *)0xE000EDFCu)
#define DEMCR_TRCENA (1u << 24)
typedef struct {
    REG CTRL, CYCCNT;
} dwt_t;
#define DWT ((dwt_t *)0xE0001000u)
#define DWT_CTRL_CYCCNTENA (1u << 0)

/** Set the main stack pointer and branch to `entry` (a Thumb address): never returns. Used to
 *  start another program image (the system-memory bootloader) from its vector table. */
static inline void jump_to_image(uint32_t stack_pointer, uint32_t entry) __attribute__((noreturn));
static inline void jump_to_image(uint32_t stack_pointer, uint32_t entry)
{
    __asm__ volatile("dsb\n\t"
                     "msr msp, %0\n\t"
                     "isb\n\t"
                     "bx %1" ::"r"(stack_pointer),
                     "r"(entry)
                     : "memory");
    __builtin_unreachable();
}

/* --------------------------------------------------------------------------- RCC (RM0090 section 7.3) */

typedef struct {
    REG CR, PLLCFGR, CFGR, CIR, AHB1RSTR, AHB2RSTR, AHB3RSTR, reserved0, APB1RSTR, APB2RSTR, reserved1[2];
    REG AHB1ENR, AHB2ENR, AHB3ENR, reserved2, APB1ENR, APB2ENR;
} rcc_t;
#define RCC ((rcc_t *)0x40023800u)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_HSEBYP (1u << 18)
#define RCC_CR_CSSON (1u << 19)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_PLLSRC_HSE (1u << 22)
/* RCC_PLLCFGR fields (RM0090 section 7.3.2); bits 15, 23:18 except 22, 31:28 are reserved
 * (reset value 0x24003010: keep them). P is encoded as P/2 - 1. */
#define RCC_PLLCFGR_PLLM_POS 0u
#define RCC_PLLCFGR_PLLM_MASK (0x3Fu << 0)
#define RCC_PLLCFGR_PLLN_POS 6u
#define RCC_PLLCFGR_PLLN_MASK (0x1FFu << 6)
#define RCC_PLLCFGR_PLLP_POS 16u
#define RCC_PLLCFGR_PLLP_MASK (3u << 16)
#define RCC_PLLCFGR_PLLQ_POS 24u
#define RCC_PLLCFGR_PLLQ_MASK (0xFu << 24)
#define RCC_CFGR_SW_MASK 3u
#define RCC_CFGR_SW_HSI 0u
#define RCC_CFGR_SW_HSE 1u
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_HSI (0u << 2)
#define RCC_CFGR_SWS_HSE (1u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_HPRE_POS 4u
#define RCC_CFGR_HPRE_MASK (0xFu << 4)
#define RCC_CFGR_PPRE1_POS 10u
#define RCC_CFGR_PPRE1_MASK (7u << 10)
#define RCC_CFGR_PPRE2_POS 13u
#define RCC_CFGR_PPRE2_MASK (7u << 13)
#define RCC_CFGR_HPRE_DIV1 (0u << 4)
#define RCC_CFGR_PPRE1_DIV1 (0u << 10)
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_DIV1 (0u << 13)
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)
#define RCC_AHB1ENR_GPIOAEN (1u << 0)
#define RCC_AHB1ENR_GPIOBEN (1u << 1)
#define RCC_AHB1ENR_DMA2EN (1u << 22)
#define RCC_APB2ENR_SYSCFGEN (1u << 14)
#define RCC_APB1ENR_TIM2EN (1u << 0)
#define RCC_APB1ENR_TIM5EN (1u << 3)
#define RCC_APB1ENR_USART2EN (1u << 17)
#define RCC_APB1ENR_I2C1EN (1u << 21)
#define RCC_APB1ENR_PWREN (1u << 28)
#define RCC_APB1RSTR_I2C1RST (1u << 21)
#define RCC_APB2ENR_USART1EN (1u << 4)

/* --------------------------------------------------------------------------- PWR, FLASH interface */

typedef struct {
    REG CR, CSR;
} pwr_t;
#define PWR ((pwr_t *)0x40007000u)
#define PWR_CR_VOS (1u << 14) /* scale 1 mode: needed for 168 MHz */

typedef struct {
    REG ACR, KEYR, OPTKEYR, SR, CR, OPTCR;
} flash_t;
#define FLASH ((flash_t *)0x40023C00u)
#define FLASH_ACR_LATENCY_MASK 7u
#define FLASH_ACR_LATENCY(ws) ((uint32_t)(ws) & 7u)
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

/* --------------------------------------------------------------------------- GPIO (RM0090 section 8.4) */

typedef struct {
    REG MODER, OTYPER, OSPEEDR, PUPDR, IDR, ODR, BSRR, LCKR, AFR[2];
} gpio_t;
#define GPIOA ((gpio_t *)0x40020000u)
#define GPIOB ((gpio_t *)0x40020400u)
#define GPIO_MODE_INPUT 0u
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u
#define GPIO_MODE_ANALOG 3u
#define GPIO_OTYPE_PUSH_PULL 0u
#define GPIO_OTYPE_OPEN_DRAIN 1u
#define GPIO_SPEED_LOW 0u    /* OSPEEDR 00 */
#define GPIO_SPEED_MEDIUM 1u /* OSPEEDR 01 */
#define GPIO_SPEED_FAST 2u   /* OSPEEDR 10 */
#define GPIO_SPEED_HIGH 3u   /* OSPEEDR 11 */
#define GPIO_PULL_NONE 0u
#define GPIO_PULL_UP 1u
#define GPIO_PULL_DOWN 2u

/* --------------------------------------------------------------------------- SYSCFG (RM0090 section 9.2) */

typedef struct {
    REG MEMRMP, PMC, EXTICR[4], reserved0[2], CMPCR;
} syscfg_t;
#define SYSCFG ((syscfg_t *)0x40013800u)
#define SYSCFG_MEMRMP_MEM_MODE_MASK 3u
#define SYSCFG_MEMRMP_MEM_MODE_SYSTEM_FLASH 1u /* system memory (the ST bootloader) at 0x00000000 */

/* --------------------------------------------------------------------------- USART (RM0090 section 30.6) */

typedef struct {
    REG SR, DR, BRR, CR1, CR2, CR3, GTPR;
} usart_t;
#define USART1 ((usart_t *)0x40011000u)
#define USART2 ((usart_t *)0x40004400u)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TC (1u << 6)
#define USART_SR_TXE (1u << 7)
#define USART_SR_LBD (1u << 8)
#define USART_SR_CTS (1u << 9)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)
#define USART_CR3_DMAT (1u << 7)

/* --------------------------------------------------------------------------- DMA (RM0090 section 10.5) */

typedef struct {
    REG CR, NDTR, PAR, M0AR, M1AR, FCR;
} dma_stream_t;
typedef struct {
    REG LISR, HISR, LIFCR, HIFCR;
    dma_stream_t S[8];
} dma_t;
#define DMA2 ((dma_t *)0x40026400u)
#define DMA_SxCR_EN (1u << 0)
#define DMA_SxCR_TEIE (1u << 2)
#define DMA_SxCR_TCIE (1u << 4)
#define DMA_SxCR_DIR_M2P (1u << 6)
#define DMA_SxCR_MINC (1u << 10)
#define DMA_SxCR_CHSEL(ch) ((uint32_t)(ch) << 25)
/* A stream's flags (FEIF, DMEIF, TEIF, HTIF, TCIF) in LISR/HISR and LIFCR/HIFCR: streams 0 and 4
 * at bit 0, 1 and 5 at bit 6, 2 and 6 at bit 16, 3 and 7 at bit 22. */
#define DMA_FLAGS_SHIFT(stream) (((stream) & 2u) ? (((stream) & 1u) ? 22u : 16u) : (((stream) & 1u) ? 6u : 0u))
#define DMA_FLAG_TEIF 0x08u
#define DMA_FLAG_TCIF 0x20u
#define DMA_FLAGS_ALL 0x3Du

/* --------------------------------------------------------------------------- TIM2..TIM5 (RM0090 section 18.4) */

typedef struct {
    REG CR1, CR2, SMCR, DIER, SR, EGR, CCMR1, CCMR2, CCER, CNT, PSC, ARR;
} tim_t;
#define TIM2 ((tim_t *)0x40000000u)
#define TIM5 ((tim_t *)0x40000C00u)
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2)
#define TIM_DIER_UIE (1u << 0)
#define TIM_SR_UIF (1u << 0)
/* The rc_w0 flags of TIM2..TIM5 SR (UIF, CC1IF..CC4IF, TIF, CC1OF..CC4OF): write this mask with
 * the flag to clear taken out; the reserved bits are written with their reset value 0. */
#define TIM_SR_FLAGS 0x1E5Fu
#define TIM_EGR_UG (1u << 0)

/* --------------------------------------------------------------------------- I2C (RM0090 section 27.6) */

typedef struct {
    REG CR1, CR2, OAR1, OAR2, DR, SR1, SR2, CCR, TRISE, FLTR;
} i2c_regs_t;
#define I2C1 ((i2c_regs_t *)0x40005400u)
#define I2C_CR1_PE (1u << 0)
#define I2C_CR1_SMBUS (1u << 1)
#define I2C_CR1_NOSTRETCH (1u << 7)
#define I2C_CR1_START (1u << 8)
#define I2C_CR1_STOP (1u << 9)
#define I2C_CR1_ACK (1u << 10)
#define I2C_CR1_POS (1u << 11)
#define I2C_CR1_SWRST (1u << 15)
#define I2C_SR1_SB (1u << 0)
#define I2C_SR1_ADDR (1u << 1)
#define I2C_SR1_BTF (1u << 2)
#define I2C_SR1_RXNE (1u << 6)
#define I2C_SR1_TXE (1u << 7)
#define I2C_SR1_BERR (1u << 8)
#define I2C_SR1_ARLO (1u << 9)
#define I2C_SR1_AF (1u << 10)
#define I2C_SR1_OVR (1u << 11)
#define I2C_SR1_PECERR (1u << 12)
#define I2C_SR1_TIMEOUT (1u << 14)
#define I2C_SR1_SMBALERT (1u << 15)
/* The rc_w0 error flags of SR1 (BERR, ARLO, AF, OVR, PECERR, TIMEOUT, SMBALERT): write this mask
 * with the flag to clear taken out (reserved bits 5 and 13 written as 0, read-only bits ignore it). */
#define I2C_SR1_ERROR_FLAGS 0xDF00u
#define I2C_SR2_MSL (1u << 0)
#define I2C_SR2_BUSY (1u << 1)
#define I2C_SR2_TRA (1u << 2)
#define I2C_CR2_FREQ_MASK 0x3Fu
#define I2C_OAR1_BIT14 (1u << 14) /* "should always be kept at 1 by software" (RM0090 section 27.6.3) */
#define I2C_CCR_FS (1u << 15)
#define I2C_CCR_DUTY (1u << 14)
#define I2C_CCR_MASK 0xFFFu
#define I2C_TRISE_MASK 0x3Fu

/* --------------------------------------------------------------------------- interrupt numbers (RM0090 table 61) */

#define IRQ_TIM2 28
#define IRQ_I2C1_EV 31
#define IRQ_I2C1_ER 32
#define IRQ_USART1 37
#define IRQ_USART2 38
#define IRQ_TIM5 50
#define IRQ_DMA2_STREAM7 70

/* --------------------------------------------------------------------------- helpers */

static inline void irq_enable(int irq, uint8_t priority)
{
    NVIC_IPR[irq] = (uint8_t)(priority << 4);
    NVIC_ISER[irq >> 5] = 1u << (irq & 31);
}

static inline void irq_disable(int irq)
{
    NVIC_ICER[irq >> 5] = 1u << (irq & 31);
}

/** PRIMASK: mask every configurable interrupt; returns the previous mask for irq_restore(). */
static inline uint32_t irq_save(void)
{
    uint32_t primask;
    __asm__ volatile("mrs %0, primask\n\tcpsid i" : "=r"(primask)::"memory");
    return primask;
}

static inline void irq_restore(uint32_t primask)
{
    __asm__ volatile("msr primask, %0" ::"r"(primask) : "memory");
}

/** Sleep until an interrupt is pending (it wakes the core even while PRIMASK masks it). */
static inline void wait_for_interrupt(void)
{
    __asm__ volatile("dsb\n\twfi" ::: "memory");
}

/** Reset the whole chip (RM0090 section 7.1.2: a software reset through the AIRCR). */
static inline void system_reset(void)
{
    __asm__ volatile("dsb" ::: "memory");
    SCB->AIRCR = SCB_AIRCR_SYSRESETREQ;
    __asm__ volatile("dsb" ::: "memory");
    for (;;) {
    }
}

/* Register offsets as in RM0090 (a typo in a struct above would move every register after it). */
#define STM32F4_OFFSET_CHECK(type, member, offset) \
    typedef char check_##type##_##member[(offsetof(type, member) == (offset)) ? 1 : -1]
STM32F4_OFFSET_CHECK(rcc_t, AHB1ENR, 0x30);
STM32F4_OFFSET_CHECK(rcc_t, APB2ENR, 0x44);
STM32F4_OFFSET_CHECK(gpio_t, AFR, 0x20);
STM32F4_OFFSET_CHECK(usart_t, GTPR, 0x18);
STM32F4_OFFSET_CHECK(dma_t, S, 0x10);
STM32F4_OFFSET_CHECK(dma_stream_t, FCR, 0x14);
STM32F4_OFFSET_CHECK(tim_t, ARR, 0x2C);
STM32F4_OFFSET_CHECK(i2c_regs_t, FLTR, 0x24);
STM32F4_OFFSET_CHECK(syscfg_t, CMPCR, 0x20);
STM32F4_OFFSET_CHECK(rcc_t, APB1RSTR, 0x20);
STM32F4_OFFSET_CHECK(rcc_t, APB1ENR, 0x40);
STM32F4_OFFSET_CHECK(scb_t, SHCSR, 0x24);
STM32F4_OFFSET_CHECK(scb_t, BFAR, 0x38);

#endif /* STM32F4_H */
