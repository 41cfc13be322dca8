/**
 * @file startup.c
 * @brief Reset handler and vector table of the STM32F405/407 (RM0090 table 61: 82 interrupts).
 *
 * The reset handler copies .data from flash, zeroes .bss and calls main(). Every
 * handler a board does not define is default_handler: an unexpected interrupt or
 * a fault resets the chip, so the firmware comes back (HELLO) instead of hanging.
 * The board's own handlers override the weak ones by name.
 */
#include <stdint.h>

#include "stm32f4.h"

extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[];
int main(void);

void reset_handler(void);
void default_handler(void);

void default_handler(void)
{
    system_reset();
}

void reset_handler(void)
{
    uint32_t *from = _sidata, *to = _sdata;
    while (to < _edata) {
        *to++ = *from++;
    }
    for (to = _sbss; to < _ebss; ++to) {
        *to = 0;
    }
    (void)main();
    system_reset(); /* main never returns; if it did, start again */
}

#define WEAK_HANDLER(name) void name(void) __attribute__((weak, alias("default_handler")))
WEAK_HANDLER(nmi_handler);
WEAK_HANDLER(hard_fault_handler);
WEAK_HANDLER(mem_manage_handler);
WEAK_HANDLER(bus_fault_handler);
WEAK_HANDLER(usage_fault_handler);
WEAK_HANDLER(svc_handler);
WEAK_HANDLER(debug_monitor_handler);
WEAK_HANDLER(pendsv_handler);
WEAK_HANDLER(systick_handler);
WEAK_HANDLER(tim2_irq_handler);
WEAK_HANDLER(i2c1_ev_irq_handler);
WEAK_HANDLER(i2c1_er_irq_handler);
WEAK_HANDLER(usart1_irq_handler);
WEAK_HANDLER(usart2_irq_handler);
WEAK_HANDLER(exti9_5_irq_handler);
WEAK_HANDLER(tim5_irq_handler);
WEAK_HANDLER(dma2_stream7_irq_handler);

#define IRQ_COUNT 82

/** The vector table, placed at the start of flash by the linker script (.isr_vector). */
__attribute__((section(".isr_vector"), used)) void (*const vector_table[16 + IRQ_COUNT])(void) = {
    (void (*)(void))(uintptr_t)_estack, /* initial stack pointer */
    reset_handler,
    nmi_handler,
    hard_fault_handler,
    mem_manage_handler,
    bus_fault_handler,
    usage_fault_handler,
    0, 0, 0, 0, /* reserved */
    svc_handler,
    debug_monitor_handler,
    0, /* reserved */
    pendsv_handler,
    systick_handler,
    /* external interrupts 0..81 (RM0090 table 61): the ones in use by name */
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler,
    exti9_5_irq_handler, /* 23 */
    default_handler, default_handler, default_handler, default_handler,
    tim2_irq_handler, /* 28 */
    default_handler, default_handler,
    i2c1_ev_irq_handler, /* 31 */
    i2c1_er_irq_handler, /* 32 */
    default_handler, default_handler, default_handler, default_handler,
    usart1_irq_handler, /* 37 */
    usart2_irq_handler, /* 38 */
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler,
    tim5_irq_handler, /* 50 */
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler,
    dma2_stream7_irq_handler, /* 70 */
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler, default_handler, default_handler, default_handler, default_handler,
    default_handler,
};
