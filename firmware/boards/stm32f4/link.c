/**
 * @file link.c
 * @brief The host link on USART1 (see link.h).
 */
#include "link.h"

#include "board.h"
#include "uart.h"

static uart_t link_uart;

void usart1_irq_handler(void);

void usart1_irq_handler(void)
{
    uart_irq(&link_uart);
}

void link_init(uint32_t pclk2_hz, uint32_t baud, uint8_t priority)
{
    uart_init(&link_uart, USART1, IRQ_USART1, pclk2_hz, baud, priority);
}

int link_has_byte(void)
{
    return uart_has_byte(&link_uart);
}

size_t board_link_read(uint8_t *buf, size_t cap)
{
    return uart_read(&link_uart, buf, cap);
}

size_t board_link_space(void)
{
    return uart_space(&link_uart);
}

void board_link_write(const uint8_t *data, size_t len)
{
    uart_write(&link_uart, data, len);
}

void board_link_flush(void)
{
    uart_flush(&link_uart);
}
