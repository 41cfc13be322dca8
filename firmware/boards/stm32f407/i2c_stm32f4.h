/**
 * @file i2c_stm32f4.h
 * @brief i2c_bus_t (drivers/i2c.h) on the STM32F405/407's I2C1, master, polled, fast mode,
 *        on the pins of board_stm32f407.h (PB8 SCL, PB9 SDA).
 *
 * The transfers follow the master sequences of RM0090 section 27.3.3 (see i2c_stm32f4.c).
 * Every wait is bounded twice: by the microsecond clock (boards/stm32f4/timers.h, TIM5,
 * started before i2c_stm32f4_init) and by a count of polls that cannot run out before that
 * time on a CPU clocked at `cpu_hz` (each poll takes at least one cycle), so the code also
 * returns on a model where the I2C registers read as zero. After a timeout, a bus error or
 * a lost arbitration the peripheral is reset through RCC, the bus is cleared by hand (up
 * to 9 SCL pulses while SDA is held low, then a STOP) and I2C1 is configured again.
 */
#ifndef I2C_STM32F4_H
#define I2C_STM32F4_H

#include <stdint.h>

#include "i2c.h"

/** State of the lines when the bus was looked at by hand (start-up, recovery). */
typedef enum {
    I2C_LINES_IDLE = 0,    /**< SCL and SDA high: nothing to do */
    I2C_LINES_FREED = 1,   /**< SDA was held low; SCL pulses freed it and a STOP followed */
    I2C_LINES_SCL_LOW = 2, /**< SCL stays low (shorted, or a chip stretches it for ever) */
    I2C_LINES_SDA_LOW = 3, /**< SDA stays low after 9 SCL pulses */
} i2c_lines_t;

/** The bus. Members are private except the counters, which a board may report. */
typedef struct {
    uint32_t pclk1_hz;      /**< APB1 clock: the peripheral's timing */
    uint32_t cpu_mhz;       /**< CPU clock, MHz: the poll-count backstop of every wait */
    uint32_t transfers;     /**< transfers attempted */
    uint32_t failures;      /**< transfers that did not return I2C_OK */
    uint32_t recoveries;    /**< peripheral resets after a timeout, bus error or lost arbitration */
    uint32_t bus_clears;    /**< times SDA was found held low and SCL was pulsed by hand */
    i2c_lines_t start_lines; /**< what i2c_stm32f4_init() found on the lines */
} i2c_stm32f4_t;

/**
 * @brief Clock, reset and pins of I2C1, a bus clear when SDA is held low, then the peripheral
 *        configured for 400 kHz fast mode from `pclk1_hz`; fills `bus` (context = `dev`).
 * @param pclk1_hz APB1 clock in use (FREQ, CCR and TRISE are computed from it; 4..42 MHz).
 * @param cpu_hz   CPU clock in use (backstop of the bounded waits).
 * @return what was found on the lines (also kept in dev->start_lines).
 */
i2c_lines_t i2c_stm32f4_init(i2c_stm32f4_t *dev, uint32_t pclk1_hz, uint32_t cpu_hz, i2c_bus_t *bus);

/** @brief i2c_bus_t.write: START, address + W, `len` bytes, STOP. */
i2c_status_t i2c_stm32f4_write(void *context, uint8_t address, const uint8_t *data, size_t len);

/** @brief i2c_bus_t.write_read: START, address + W, bytes, repeated START, address + R, bytes, STOP. */
i2c_status_t i2c_stm32f4_write_read(void *context, uint8_t address, const uint8_t *write_data, size_t write_len,
                                    uint8_t *read_data, size_t read_len);

/** @brief i2c_bus_t.delay_ms: at least `ms` milliseconds of the microsecond clock. */
void i2c_stm32f4_delay_ms(void *context, uint32_t ms);

/** @brief At least `us` microseconds of the microsecond clock (poll-count backstop at `cpu_mhz`). */
void i2c_stm32f4_delay_us(const i2c_stm32f4_t *dev, uint32_t us);

/** @brief FREQ, CCR and TRISE for `pclk1_hz` in fast mode (RM0090 section 27.6), for tests and docs. */
void i2c_stm32f4_timing(uint32_t pclk1_hz, uint32_t *freq, uint32_t *ccr, uint32_t *trise);

#endif /* I2C_STM32F4_H */
