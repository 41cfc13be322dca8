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
    u->dma.controller = 0;
    u->dma.moving = 0;
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

int uart_tx_dma(uart_t *u, dma_t *dma, uint32_t stream, uint32_t channel, int irq, uint8_t priority)
{
    dma_stream_t *s = &dma->S[stream & 7u];
    s->CR = 0; /* disabled: every register may be written */
    s->NDTR = 1u;
    if (s->NDTR != 1u) {
        return 0; /* no DMA controller answers here */
    }
    s->NDTR = 0;
    s->PAR = (uint32_t)(uintptr_t)&u->regs->DR;
    s->FCR = 0; /* direct mode: one byte per request */
    s->CR = DMA_SxCR_CHSEL(channel) | DMA_SxCR_MINC | DMA_SxCR_DIR_M2P | DMA_SxCR_TCIE | DMA_SxCR_TEIE;
    u->dma.controller = dma;
    u->dma.stream = s;
    u->dma.flags_shift = DMA_FLAGS_SHIFT(stream);
    u->dma.moving = 0;
    u->regs->CR3 |= USART_CR3_DMAT;
    irq_enable(irq, priority);
    return 1;
}

static volatile uint32_t *dma_flags_clear(const uart_dma_t *d)
{
    return d->stream >= &d->controller->S[4] ? &d->controller->HIFCR : &d->controller->LIFCR;
}

/** Start a transfer of the ring's next contiguous stretch when the stream is idle; interrupts masked. */
static void dma_start(uart_t *u)
{
    uart_dma_t *d = &u->dma;
    uint32_t offset, n;
    if (d->moving != 0u || u->tx_tail == u->tx_head) {
        return;
    }
    offset = u->tx_tail % UART_TX_SIZE;
    n = u->tx_head - u->tx_tail;
    if (n > UART_TX_SIZE - offset) {
        n = UART_TX_SIZE - offset; /* up to the ring's end; the rest is the next transfer */
    }
    *dma_flags_clear(d) = DMA_FLAGS_ALL << d->flags_shift; /* RM0090 10.3.17: clear them before EN */
    d->stream->M0AR = (uint32_t)(uintptr_t)&u->tx[offset];
    d->stream->NDTR = n;
    d->moving = n;
    /* RM0090 30.3.13 step 6: TC cleared by writing 0 to it (the DMA's writes to DR do not clear
     * it), so that uart_flush waits for these bytes; the other rc_w0 flags are written 1. */
    u->regs->SR = USART_SR_RXNE | USART_SR_LBD | USART_SR_CTS;
    d->stream->CR |= DMA_SxCR_EN;
}

void uart_dma_irq(uart_t *u)
{
    uart_dma_t *d = &u->dma;
    const volatile uint32_t *status = d->stream >= &d->controller->S[4] ? &d->controller->HISR : &d->controller->LISR;
    const uint32_t flags = (*status >> d->flags_shift) & DMA_FLAGS_ALL;
    if (flags & (DMA_FLAG_TCIF | DMA_FLAG_TEIF)) {
        /* done (or, after a transfer error, given up: those bytes are lost, the link's
         * sequence numbers tell the host) */
        *dma_flags_clear(d) = flags << d->flags_shift;
        u->tx_tail += d->moving;
        d->moving = 0;
        dma_start(u);
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
    if (u->dma.controller != 0) {
        dma_start(u);
        irq_restore(primask);
        return;
    }
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
        if (u->dma.controller == 0) {
            primask = irq_save(); /* CR1 is also written by the interrupt handler */
            u->regs->CR1 |= USART_CR1_TXEIE;
            irq_restore(primask);
        }
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
