/**
 * @file i2c.h
 * @brief The portable I2C interface the sensor drivers talk through.
 *
 * A board implements the two transfers of a register-based I2C sensor and a
 * delay; the drivers (mpu6050, hmc5883l, gy86) never touch hardware registers.
 * The host tests implement it in Python on register-level chip models
 * (host/imulink/chips), the reference board on the STM32F4's I2C1 peripheral.
 *
 * Every call returns within a bounded time: a peripheral that stops answering is
 * an I2C_ERR_TIMEOUT, never a hang. On any error the implementation has released
 * the bus (STOP sent, peripheral ready for the next transfer).
 */
#ifndef I2C_H
#define I2C_H

#include <stddef.h>
#include <stdint.h>

/** Result of a transfer. */
typedef enum {
    I2C_OK = 0,
    I2C_ERR_NACK_ADDRESS = -1, /**< nobody acknowledged the address: the chip is absent, unpowered or unreachable */
    I2C_ERR_NACK_DATA = -2,    /**< the chip refused a data byte */
    I2C_ERR_TIMEOUT = -3,      /**< the transfer did not complete in time (clock stretched, peripheral stuck) */
    I2C_ERR_BUS = -4,          /**< misplaced START/STOP seen on the bus (noise, a second master) */
    I2C_ERR_ARBITRATION = -5,  /**< arbitration lost to another master (or SDA held low) */
} i2c_status_t;

/** A bus: transfers, a delay, and the context they receive. */
typedef struct {
    /** START, address + write, `len` bytes, STOP. */
    i2c_status_t (*write)(void *context, uint8_t address, const uint8_t *data, size_t len);
    /** START, address + write, `write_len` bytes, repeated START, address + read, `read_len`
     *  bytes (the last one NACKed), STOP. `read_len` >= 1. */
    i2c_status_t (*write_read)(void *context, uint8_t address, const uint8_t *write_data, size_t write_len,
                               uint8_t *read_data, size_t read_len);
    /** Wait at least `ms` milliseconds (chip start-up and reset times). */
    void (*delay_ms)(void *context, uint32_t ms);
    void *context;
} i2c_bus_t;

/** @brief Short English name of a status ("address not acknowledged", ...), for LOG lines. */
const char *i2c_status_text(i2c_status_t status);

#endif /* I2C_H */
