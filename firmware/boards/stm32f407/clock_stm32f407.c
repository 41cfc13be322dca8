/**
 * @file clock_stm32f407.c
 * @brief Clock set-up of the reference board (see clock_stm32f407.h).
 *
 * The sequence (RM0090 rev 19):
 *  1. PWR interface clock on (RCC_APB1ENR.PWREN, section 7.3.13), then PWR_CR.VOS = 1, regulator
 *     scale 1, needed above 144 MHz (section 5.4.1; it is the reset value on the F405/407, and
 *     VOS may only be written while the PLL is off, which it is here).
 *  2. HSEON, wait HSERDY (section 7.3.1). If the crystal does not start, HSEON is cleared again
 *     and the PLL takes the HSI (16 MHz, M = 16) instead: the same 168 MHz.
 *  3. RCC_PLLCFGR (section 7.3.2, written while the PLL is off; reserved bits kept): M, N = 336,
 *     P = 2, Q = 7, source. PLLON, wait PLLRDY.
 *  4. FLASH_ACR (section 3, flash interface registers): LATENCY = 5 wait states, prefetch,
 *     instruction and data caches, and read back before the clock rises (section 3, "relation
 *     between CPU clock frequency and flash memory read time": "check that the new number of
 *     wait states is taken into account to access the flash memory by reading the FLASH_ACR
 *     register"; the read is repeated, bounded, until it shows the new value).
 *  5. RCC_CFGR (section 7.3.3): prescalers AHB /1, APB1 /4, APB2 /2 first (the buses never run
 *     above their maximum), then SW = PLL, wait SWS = PLL.
 * Every wait counts loop iterations (no timer is clocked yet). When the PLL does not lock, the
 * wait states are not taken or the switch does not happen, the chip stays on the HSI at 16 MHz
 * with every bus at /1, the PLL and the HSE off. The clocks actually in use are then decoded
 * from the registers (clocks_read), so a failure anywhere still gives right baud rates and
 * timer periods; on a model where RCC reads as zero (QEMU) that is the HSI at 16 MHz.
 */
#include "clock_stm32f407.h"

#include "board_stm32f407.h"
#include "text.h"

/** 1 when (*reg & mask) == value within `loops` reads, 0 otherwise. */
static int wait_for(volatile uint32_t *reg, uint32_t mask, uint32_t value, uint32_t loops)
{
    while (loops-- > 0u) {
        if ((*reg & mask) == value) {
            return 1;
        }
    }
    return 0;
}

/** Back to the HSI (if the switch went anywhere), buses at /1, PLL and HSE off. */
static void stay_on_hsi(void)
{
    RCC->CFGR = (RCC->CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_HSI;
    (void)wait_for(&RCC->CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_HSI, BOARD_SWITCH_LOOPS);
    RCC->CFGR = (RCC->CFGR & ~(RCC_CFGR_HPRE_MASK | RCC_CFGR_PPRE1_MASK | RCC_CFGR_PPRE2_MASK)) |
                RCC_CFGR_HPRE_DIV1 | RCC_CFGR_PPRE1_DIV1 | RCC_CFGR_PPRE2_DIV1;
    RCC->CR &= ~RCC_CR_PLLON;
    RCC->CR &= ~RCC_CR_HSEON;
}

void clocks_init(clocks_t *clocks)
{
    static char problem[120];
    text_t t;
    uint32_t pll_m, pll_source;
    const char *failure = 0;

    text_start(&t, problem, sizeof problem);
    clocks->problem = 0;

    /* Started by a debugger on a running PLL? Leave it first: PLLCFGR is written with the PLL off. */
    if ((RCC->CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_HSI) {
        stay_on_hsi();
    }
    RCC->CR &= ~RCC_CR_PLLON;
    (void)wait_for(&RCC->CR, RCC_CR_PLLRDY, 0u, BOARD_PLL_LOCK_LOOPS);

    /* 1. Regulator scale 1. */
    RCC->APB1ENR |= RCC_APB1ENR_PWREN;
    (void)RCC->APB1ENR; /* the enable takes effect before the first access to PWR (a read back) */
    PWR->CR |= PWR_CR_VOS;

    /* 2. The crystal. */
    RCC->CR |= RCC_CR_HSEON;
    if (wait_for(&RCC->CR, RCC_CR_HSERDY, RCC_CR_HSERDY, BOARD_HSE_START_LOOPS)) {
        clocks->source = CLOCKS_PLL_FROM_HSE;
        pll_m = BOARD_PLL_M_HSE;
        pll_source = RCC_PLLCFGR_PLLSRC_HSE;
    } else {
        RCC->CR &= ~RCC_CR_HSEON;
        clocks->source = CLOCKS_PLL_FROM_HSI;
        pll_m = BOARD_PLL_M_HSI;
        pll_source = 0u;
        text_add(&t, "clock: the 8 MHz crystal (HSE) did not start");
    }

    /* 3. The PLL. */
    RCC->PLLCFGR = (RCC->PLLCFGR & ~(RCC_PLLCFGR_PLLM_MASK | RCC_PLLCFGR_PLLN_MASK | RCC_PLLCFGR_PLLP_MASK |
                                     RCC_PLLCFGR_PLLSRC_HSE | RCC_PLLCFGR_PLLQ_MASK)) |
                   (pll_m << RCC_PLLCFGR_PLLM_POS) | (BOARD_PLL_N << RCC_PLLCFGR_PLLN_POS) |
                   ((BOARD_PLL_P / 2u - 1u) << RCC_PLLCFGR_PLLP_POS) | pll_source |
                   (BOARD_PLL_Q << RCC_PLLCFGR_PLLQ_POS);
    RCC->CR |= RCC_CR_PLLON;
    if (!wait_for(&RCC->CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY, BOARD_PLL_LOCK_LOOPS)) {
        failure = "the PLL did not lock";
    }

    /* 4. Flash wait states before the clock rises, read back. */
    if (failure == 0) {
        FLASH->ACR = (FLASH->ACR & ~(FLASH_ACR_LATENCY_MASK | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN)) |
                     FLASH_ACR_LATENCY(BOARD_FLASH_WAIT_STATES) | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
        if (!wait_for(&FLASH->ACR, FLASH_ACR_LATENCY_MASK, BOARD_FLASH_WAIT_STATES, BOARD_SWITCH_LOOPS)) {
            failure = "FLASH_ACR did not take 5 wait states";
        }
    }

    /* 5. Prescalers, then the switch. */
    if (failure == 0) {
        RCC->CFGR = (RCC->CFGR & ~(RCC_CFGR_HPRE_MASK | RCC_CFGR_PPRE1_MASK | RCC_CFGR_PPRE2_MASK)) |
                    BOARD_CFGR_PRESCALERS;
        RCC->CFGR = (RCC->CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_PLL;
        if (!wait_for(&RCC->CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL, BOARD_SWITCH_LOOPS)) {
            failure = "SYSCLK did not switch to the PLL";
        }
    }

    if (failure != 0) {
        stay_on_hsi();
        clocks->source = CLOCKS_HSI;
        text_add(&t, text_length(problem) > 0 ? " and " : "clock: ");
        text_add(&t, failure);
        text_add(&t, ": running on the 16 MHz HSI");
    } else if (clocks->source == CLOCKS_PLL_FROM_HSI) {
        text_add(&t, ": 168 MHz from the HSI through the PLL (+-1 %)");
    }
    if (text_length(problem) > 0) {
        clocks->problem = text_end(&t);
    }
    clocks_read(clocks);
}

void clocks_read(clocks_t *clocks)
{
    /* RCC_CFGR HPRE: 0xxx /1, 1000 /2 ... 1111 /512; PPREx: 0xx /1, 100 /2 ... 111 /16. */
    static const uint16_t ahb_divider[16] = {1, 1, 1, 1, 1, 1, 1, 1, 2, 4, 8, 16, 64, 128, 256, 512};
    static const uint8_t apb_divider[8] = {1, 1, 1, 1, 2, 4, 8, 16};
    const uint32_t cfgr = RCC->CFGR;
    uint32_t sysclk = BOARD_HSI_HZ;
    uint32_t apb1, apb2;

    if ((cfgr & RCC_CFGR_SWS_MASK) == RCC_CFGR_SWS_HSE) {
        sysclk = BOARD_HSE_HZ;
    } else if ((cfgr & RCC_CFGR_SWS_MASK) == RCC_CFGR_SWS_PLL) {
        const uint32_t pllcfgr = RCC->PLLCFGR;
        const uint32_t input = (pllcfgr & RCC_PLLCFGR_PLLSRC_HSE) ? BOARD_HSE_HZ : BOARD_HSI_HZ;
        const uint32_t m = (pllcfgr & RCC_PLLCFGR_PLLM_MASK) >> RCC_PLLCFGR_PLLM_POS;
        const uint32_t n = (pllcfgr & RCC_PLLCFGR_PLLN_MASK) >> RCC_PLLCFGR_PLLN_POS;
        const uint32_t p = 2u * (((pllcfgr & RCC_PLLCFGR_PLLP_MASK) >> RCC_PLLCFGR_PLLP_POS) + 1u);
        sysclk = m >= 2u ? (uint32_t)((uint64_t)input / m * n / p) : BOARD_SYSCLK_HZ;
    }
    clocks->sysclk_hz = sysclk;
    clocks->hclk_hz = sysclk / ahb_divider[(cfgr & RCC_CFGR_HPRE_MASK) >> RCC_CFGR_HPRE_POS];
    apb1 = apb_divider[(cfgr & RCC_CFGR_PPRE1_MASK) >> RCC_CFGR_PPRE1_POS];
    apb2 = apb_divider[(cfgr & RCC_CFGR_PPRE2_MASK) >> RCC_CFGR_PPRE2_POS];
    clocks->pclk1_hz = clocks->hclk_hz / apb1;
    clocks->pclk2_hz = clocks->hclk_hz / apb2;
    clocks->apb1_timer_hz = apb1 == 1u ? clocks->pclk1_hz : 2u * clocks->pclk1_hz;
}
