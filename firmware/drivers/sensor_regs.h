/**
 * @file sensor_regs.h
 * @brief Register transfers of a register-based I2C chip, with driver statuses.
 *
 * Both GY-86 chips speak the same protocol: a write transfer whose first byte is a
 * register address sets the chip's register pointer, further bytes are written from
 * there on; a write of the address followed by a repeated START and a read returns
 * registers from the pointer on (each chip has its own auto-increment rule). These
 * helpers do the two transfers and turn a failed one into a sensor_status_t naming
 * the chip and the register.
 */
#ifndef SENSOR_REGS_H
#define SENSOR_REGS_H

#include <stddef.h>
#include <stdint.h>

#include "i2c.h"
#include "sensor_status.h"

/** A chip on a bus: where its transfers go and whom its statuses name. */
typedef struct {
    const i2c_bus_t *bus; /**< the bus the chip is reachable on (not owned) */
    uint8_t address;      /**< 7-bit I2C address */
    sensor_chip_t chip;   /**< named in every status */
} sensor_device_t;

/** @brief Write `value` to register `reg` (one transfer: address, value). */
sensor_status_t sensor_write_reg(const sensor_device_t *dev, uint8_t reg, uint8_t value);

/**
 * @brief Read `len` (>= 1) registers from `first_reg` on in one transfer (the chip's
 *        auto-increment decides which registers follow).
 * @param data receives the bytes; its content is unspecified when the call fails.
 */
sensor_status_t sensor_read_regs(const sensor_device_t *dev, uint8_t first_reg, uint8_t *data, size_t len);

/**
 * @brief Read register `reg` back and compare the bits of `mask` with `wrote`.
 * @return SENSOR_OK, the read's I2C error, or SENSOR_ERR_READBACK naming the register,
 *         the value written and the value read.
 */
sensor_status_t sensor_verify_reg(const sensor_device_t *dev, uint8_t reg, uint8_t wrote, uint8_t mask);

/** @brief Wait at least `ms` milliseconds on the bus's clock. */
void sensor_delay_ms(const sensor_device_t *dev, uint32_t ms);

/** @brief The int16 of a big-endian register pair (MSB first), without implementation-defined conversions. */
int16_t sensor_be16(const uint8_t *msb_first);

#endif /* SENSOR_REGS_H */
