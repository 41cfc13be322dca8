/**
 * @file uart.h
 * @brief Interrupt-driven USART with receive and transmit ring buffers (RM0090 section 30),
 *        and a polled mode for a UART that is read on demand.
 *
 * Interrupt mode: RXNE moves every received byte into the receive ring (a full ring
 * drops the byte and counts it); uart_write() fills the transmit ring and enables
 * TXEIE, and the TXE interrupt moves the ring to DR one byte at a time until it is
 * empty. With uart_tx_dma(), a DMA stream moves the transmit ring instead, a contiguous
 * stretch per transfer (one interrupt per stretch, not per byte: RM0090 section 10.3 and
 * 30.3.13, "transmission using DMA"); the stream's interrupt handler calls uart_dma_irq(). The USART's interrupt handler must call uart_irq(). The writing calls also
 * move bytes themselves while TXE is set: one at a time on a real USART (TXE clears
 * until the byte has moved on), all of them on a model whose transmission is
 * synchronous and which raises no TXE interrupt (QEMU 7.2's), so the same code works on
 * both.
 */
#ifndef UART_H
#define UART_H

#include <stddef.h>
#include <stdint.h>

#include "stm32f4.h"

#define UART_RX_SIZE 1024u /**< receive ring, bytes (a power of two) */
#define UART_TX_SIZE 4096u /**< transmit ring, bytes (a power of two): 44 ms at 921600 baud */

/** The DMA stream that moves a transmit ring, when there is one. */
typedef struct {
    dma_t *controller;          /**< NULL: the TXE interrupt moves the bytes */
    dma_stream_t *stream;
    uint32_t flags_shift;       /**< the stream's flags in LISR/HISR (DMA_FLAGS_SHIFT) */
    volatile uint32_t moving;   /**< bytes of the transfer under way (0: the stream is idle) */
} uart_dma_t;

typedef struct {
    usart_t *regs;
    int irq;
    uart_dma_t dma;
    uint8_t rx[UART_RX_SIZE];
    uint8_t tx[UART_TX_SIZE];
    volatile uint32_t rx_head, rx_tail; /* written by the interrupt / the main loop */
    volatile uint32_t tx_head, tx_tail; /* written by the main loop / the interrupt */
    volatile uint32_t rx_overruns;      /* bytes lost: ring full or hardware overrun */
} uart_t;

/**
 * @brief Set up a USART, 8N1, `baud` from its bus clock `pclk_hz` (oversampling by 16:
 *        BRR = pclk / baud rounded, RM0090 section 30.3.4), interrupts enabled at `priority`.
 *        The pins and the peripheral clock are the board's job.
 */
void uart_init(uart_t *u, usart_t *regs, int irq, uint32_t pclk_hz, uint32_t baud, uint8_t priority);

/**
 * @brief Another baud rate: waits until what was queued has left (TC), then UE off, BRR,
 *        UE on (RM0090 section 30.6.3: BRR must not change during a transfer).
 */
void uart_set_baud(uart_t *u, uint32_t pclk_hz, uint32_t baud);

/** @brief The USART's interrupt handler calls this. */
void uart_irq(uart_t *u);

/**
 * @brief Move the transmit ring with DMA stream `stream` of `dma` on `channel` (the USART's TX
 *        request: RM0090 tables 42-43), its transfer-complete interrupt `irq` at `priority`.
 *        The controller's clock must be on. Returns 1 when the stream answers (its NDTR reads
 *        back what was written), 0 when it does not (a model without DMA): the TXE interrupt
 *        then moves the bytes as before.
 */
int uart_tx_dma(uart_t *u, dma_t *dma, uint32_t stream, uint32_t channel, int irq, uint8_t priority);

/** @brief The DMA stream's interrupt handler calls this. */
void uart_dma_irq(uart_t *u);

/** @brief Received bytes, at most `cap`; never waits. */
size_t uart_read(uart_t *u, uint8_t *buf, size_t cap);

/** @brief Free bytes in the transmit ring. */
size_t uart_space(const uart_t *u);

/** @brief Queue bytes; waits for room while the ring is full. */
void uart_write(uart_t *u, const uint8_t *data, size_t len);

/** @brief Move bytes from the ring to DR while TXE is set (or start the DMA stream); never waits. */
void uart_pump(uart_t *u);

/** @brief Wait until the ring is empty and the last byte has left the shift register (TC). */
void uart_flush(uart_t *u);

/** @brief 1 when a byte has been received and not read yet. */
int uart_has_byte(const uart_t *u);

/* --------------------------------------------------------------------------- polled mode */

/** @brief Set up a USART without interrupts (8N1): read with uart_poll_get(). */
void uart_poll_init(usart_t *regs, uint32_t pclk_hz, uint32_t baud);

/** @brief Send one byte, waiting for TXE. */
void uart_poll_put(usart_t *regs, uint8_t byte);

/** @brief 1 and the byte when one was received, 0 otherwise; never waits. */
int uart_poll_get(usart_t *regs, uint8_t *byte);

#endif /* UART_H */
