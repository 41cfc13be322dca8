/**
 * @file sensor_status.h
 * @brief The result of every sensor-driver call, and its text for a LOG line.
 *
 * A driver call returns a sensor_status_t by value: what happened (`result`), which
 * chip it concerns, and the details a user needs to act on it (the I2C result of a
 * failed transfer, the identification bytes a wrong chip answered, the register that
 * did not keep its value). Failures are negative results; the one positive result,
 * SENSOR_MAG_OVERFLOW, delivers its sample and only flags it.
 * sensor_status_text() turns any status into a short English sentence, e.g.
 * "MPU6050: address not acknowledged" or
 * "HMC5883L: wrong identity 0x48 0x34 0x00 (expected H43)".
 */
#ifndef SENSOR_STATUS_H
#define SENSOR_STATUS_H

#include <stddef.h>
#include <stdint.h>

#include "i2c.h"

/** The chips a status can name. */
typedef enum {
    SENSOR_CHIP_MPU6050 = 1,  /**< InvenSense MPU-6050 gyroscope + accelerometer */
    SENSOR_CHIP_HMC5883L = 2, /**< Honeywell HMC5883L magnetometer */
    SENSOR_CHIP_MS5611 = 3,   /**< MEAS MS5611-01BA barometer */
} sensor_chip_t;

/** What a driver call did. Negative: it failed (no sample, configuration incomplete). */
typedef enum {
    SENSOR_OK = 0,
    /** The sample was read and delivered, but magnetometer channel(s) reported an ADC
     *  overflow (the HMC5883L's -4096, kept in the sample); `channels` says which. */
    SENSOR_MAG_OVERFLOW = 1,
    SENSOR_ERR_I2C = -1,      /**< a transfer failed: `i2c` says how, `reg` is the register it addressed */
    SENSOR_ERR_IDENTITY = -2, /**< the identification register(s) hold other values: `got[0..count-1]` */
    SENSOR_ERR_READBACK = -3, /**< register `reg` reads `got[0]` after writing `wrote` (defined bits compared) */
    SENSOR_ERR_RESET = -4,    /**< the reset bit did not clear in time; `got[0]` is the last value read, if `count` */
    SENSOR_ERR_CONFIG = -5,   /**< the configuration asks for a value register `reg` cannot hold */
    SENSOR_ERR_PROM_CRC = -6, /**< no usable calibration: the PROM's CRC-4 is `got[1]`, its contents give `got[0]`
                                   (equal when the coefficients are all zero) */
    SENSOR_ERR_ADC = -7,      /**< the ADC read 0: no conversion result (the chip reset, or the read came early);
                                   `reg` is the conversion command that was waited for */
} sensor_result_t;

/** Bits of sensor_status_t.channels, in the magnetometer's own axes. */
#define SENSOR_CHANNEL_X 1u
#define SENSOR_CHANNEL_Y 2u
#define SENSOR_CHANNEL_Z 4u

/** Result of a driver call (returned by value; all fields defined for every result). */
typedef struct {
    sensor_result_t result; /**< what happened */
    sensor_chip_t chip;     /**< the chip concerned */
    i2c_status_t i2c;       /**< SENSOR_ERR_I2C: result of the failed transfer; I2C_OK otherwise */
    uint8_t reg;            /**< register address concerned (0 when none) */
    uint8_t wrote;          /**< SENSOR_ERR_READBACK: the value written */
    uint8_t count;          /**< number of valid bytes in `got` (0..3) */
    uint8_t got[3];         /**< byte(s) read: identity, read-back value, last reset register value */
    uint8_t channels;       /**< SENSOR_MAG_OVERFLOW: SENSOR_CHANNEL_* bits of the overflowed channels */
} sensor_status_t;

/** Size of a buffer that holds every text sensor_status_text() writes (with its NUL). */
#define SENSOR_STATUS_TEXT_SIZE 80u

/** @brief Nonzero when the call failed (negative result); OK and overflow delivered their data. */
static inline int sensor_failed(const sensor_status_t *status)
{
    return status->result < 0;
}

/** @brief Status "all went well" for `chip`. */
sensor_status_t sensor_status_ok(sensor_chip_t chip);

/** @brief Status of a failed transfer `i2c` (not I2C_OK) that addressed register `reg` of `chip`. */
sensor_status_t sensor_status_i2c(sensor_chip_t chip, i2c_status_t i2c, uint8_t reg);

/** @brief Status "wrong chip": the `count` (<= 3) identification bytes `got` read from `chip`. */
sensor_status_t sensor_status_identity(sensor_chip_t chip, const uint8_t *got, uint8_t count);

/** @brief Status "register `reg` reads `got` after writing `wrote`". */
sensor_status_t sensor_status_readback(sensor_chip_t chip, uint8_t reg, uint8_t wrote, uint8_t got);

/** @brief Status "the configuration asks for a value register `reg` of `chip` cannot hold". */
sensor_status_t sensor_status_config(sensor_chip_t chip, uint8_t reg);

/** @brief Status "the PROM's CRC-4 `stored` differs from the `computed` one". */
sensor_status_t sensor_status_prom_crc(sensor_chip_t chip, uint8_t computed, uint8_t stored);

/** @brief Status "the ADC read 0 after conversion command `command`". */
sensor_status_t sensor_status_adc(sensor_chip_t chip, uint8_t command);

/**
 * @brief One sentence for a LOG line, "<chip>: <what happened>", written to `buf`.
 * @param status the status to describe.
 * @param buf    destination; always NUL-terminated when `cap` > 0 (texts longer than
 *               `cap` - 1 are cut; SENSOR_STATUS_TEXT_SIZE is always enough).
 * @param cap    size of `buf` in bytes.
 * @return `buf` (or "" when `buf` is NULL or `cap` is 0).
 */
const char *sensor_status_text(const sensor_status_t *status, char *buf, size_t cap);

#endif /* SENSOR_STATUS_H */
