/**
 * @file link.h
 * @brief The host link of both STM32F4 boards: USART1 through the ring-buffered driver
 *        (uart.h). It implements the link part of app/board.h (board_link_read, _space,
 *        _write, _flush) and USART1's interrupt handler; the board sets it up and configures
 *        the pins.
 */
#ifndef LINK_H
#define LINK_H

#include <stdint.h>

/** @brief USART1 at `baud` from its bus clock `pclk2_hz`, receive interrupt at `priority`. */
void link_init(uint32_t pclk2_hz, uint32_t baud, uint8_t priority);

/** @brief 1 when a received byte waits (the idle check). */
int link_has_byte(void);

#endif /* LINK_H */
