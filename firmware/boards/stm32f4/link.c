/**
 * @file link.c
 * @brief The host link on USART1 (see link.h).
 */
#include "link.h"

#include "board.h"
#include "uart.h"

static uart_t link_uart;

void usart1_irq_handler(void);
void dma2_stream7_irq_handler(void);

/* USART1_TX's DMA request: DMA2 stream 7, channel 4 (RM0090 table 43). */
#define LINK_DMA_STREAM 7u
#define LINK_DMA_CHANNEL 4u

void usart1_irq_handler(void)
{
    uart_irq(&link_uart);
}

void dma2_stream7_irq_handler(void)
{
    uart_dma_irq(&link_uart);
}

void link_init(uint32_t pclk2_hz, uint32_t baud, uint8_t priority)
{
    uart_init(&link_uart, USART1, IRQ_USART1, pclk2_hz, baud, priority);
    /* The transmitter on DMA: one interrupt per stretch of the ring instead of one per byte. A
     * chip model without the DMA controller (QEMU's netduinoplus2) keeps the TXE interrupt. */
    RCC->AHB1ENR |= RCC_AHB1ENR_DMA2EN;
    (void)RCC->AHB1ENR; /* the enable takes effect before the first access */
    (void)uart_tx_dma(&link_uart, DMA2, LINK_DMA_STREAM, LINK_DMA_CHANNEL, IRQ_DMA2_STREAM7, priority);
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
