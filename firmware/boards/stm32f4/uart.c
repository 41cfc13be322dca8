/**
 * @file uart.c
 * @brief Ring-buffered USART (see uart.h).
 */
#include "uart.h"

/** BRR for a baud rate, oversampling by 16: pclk / baud rounded (RM0090 section 30.3.4). */
static uint32_t brr(uint32_t pclk_hz, uint32_t baud)
{
    return (pclk_hz + baud / 2u) / baud;
}

static void configure(usart_t *regs, uint32_t pclk_hz, uint32_t baud, uint32_t interrupts)
{
    regs->CR1 = 0; /* UE = 0 while configuring */
    regs->CR2 = 0; /* 1 stop bit */
    regs->CR3 = 0; /* no flow control, no DMA */
    regs->BRR = brr(pclk_hz, baud);
    regs->CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | interrupts;
}

void uart_set_baud(uart_t *u, uint32_t pclk_hz, uint32_t baud)
{
    uint32_t cr1, primask;
    uart_flush(u);
    primask = irq_save(); /* CR1 is also written by the interrupt handler */
    cr1 = u->regs->CR1;
    u->regs->CR1 = cr1 & ~USART_CR1_UE;
    u->regs->BRR = brr(pclk_hz, baud);
    u->regs->CR1 = cr1;
    irq_restore(primask);
}

void uart_init(uart_t *u, usart_t *regs, int irq, uint32_t pclk_hz, uint32_t baud, uint8_t priority)
{
    u->regs = regs;
    u->irq = irq;
    u->rx_head = u->rx_tail = 0;
    u->tx_head = u->tx_tail = 0;
    u->rx_overruns = 0;
    configure(regs, pclk_hz, baud, USART_CR1_RXNEIE);
    irq_enable(irq, priority);
}

void uart_irq(uart_t *u)
{
    usart_t *regs = u->regs;
    const uint32_t sr = regs->SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        const uint8_t byte = (uint8_t)regs->DR; /* reading SR then DR clears RXNE and ORE */
        if (sr & USART_SR_ORE) {
            ++u->rx_overruns;
        }
        if (sr & USART_SR_RXNE) {
            if (u->rx_head - u->rx_tail < UART_RX_SIZE) {
                u->rx[u->rx_head % UART_RX_SIZE] = byte;
                ++u->rx_head;
            } else {
                ++u->rx_overruns;
            }
        }
    }
    if ((sr & USART_SR_TXE) && (regs->CR1 & USART_CR1_TXEIE)) {
        if (u->tx_tail != u->tx_head) {
            regs->DR = u->tx[u->tx_tail % UART_TX_SIZE];
            ++u->tx_tail;
        } else {
            regs->CR1 &= ~USART_CR1_TXEIE; /* in the handler: the main loop only sets it with interrupts masked */
        }
    }
}

size_t uart_read(uart_t *u, uint8_t *buf, size_t cap)
{
    size_t n = 0;
    while (n < cap && u->rx_tail != u->rx_head) {
        buf[n++] = u->rx[u->rx_tail % UART_RX_SIZE];
        ++u->rx_tail;
    }
    return n;
}

int uart_has_byte(const uart_t *u)
{
    return u->rx_tail != u->rx_head;
}

size_t uart_space(const uart_t *u)
{
    return UART_TX_SIZE - (u->tx_head - u->tx_tail);
}

void uart_pump(uart_t *u)
{
    const uint32_t primask = irq_save(); /* the interrupt handler takes bytes from the same ring */
    while (u->tx_tail != u->tx_head && (u->regs->SR & USART_SR_TXE)) {
        u->regs->DR = u->tx[u->tx_tail % UART_TX_SIZE];
        ++u->tx_tail;
    }
    irq_restore(primask);
}

void uart_write(uart_t *u, const uint8_t *data, size_t len)
{
    while (len > 0) {
        uint32_t primask;
        while (uart_space(u) == 0) {
            uart_pump(u); /* and the TXE interrupt makes room */
        }
        while (len > 0 && uart_space(u) > 0) {
            u->tx[u->tx_head % UART_TX_SIZE] = *data++;
            ++u->tx_head;
            --len;
        }
        primask = irq_save(); /* CR1 is also written by the interrupt handler */
        u->regs->CR1 |= USART_CR1_TXEIE;
        irq_restore(primask);
        uart_pump(u);
    }
}

void uart_flush(uart_t *u)
{
    /* Bounded: a USART without its clock never sets TC, and a reset must still happen. At most
     * a full ring at the slowest rate in use (4 KB at 115200 baud: 0.36 s) is waited for. */
    uint32_t spins = 100000000u;
    while (u->tx_tail != u->tx_head && --spins > 0) {
        uart_pump(u);
    }
    while (!(u->regs->SR & USART_SR_TC) && --spins > 0) {
    }
}

void uart_poll_init(usart_t *regs, uint32_t pclk_hz, uint32_t baud)
{
    configure(regs, pclk_hz, baud, 0);
}

void uart_poll_put(usart_t *regs, uint8_t byte)
{
    while (!(regs->SR & USART_SR_TXE)) {
    }
    regs->DR = byte;
}

int uart_poll_get(usart_t *regs, uint8_t *byte)
{
    if (!(regs->SR & USART_SR_RXNE)) {
        return 0;
    }
    *byte = (uint8_t)regs->DR;
    return 1;
}
