/**
 * @file hmc5883l.h
 * @brief Honeywell HMC5883L 3-axis magnetometer over the portable I2C interface.
 *
 * Follows the data sheet "3-Axis Digital Compass IC HMC5883L", Form #900405 Rev E
 * ("DS"); register names are its own.
 *
 * hmc5883l_init() checks the identification registers A, B, C (10, 11, 12: 'H', '4',
 * '3'), writes Configuration A (averaging, data output rate, measurement mode) and B
 * (gain), puts the chip in continuous-measurement mode and reads the three back.
 * hmc5883l_read() reads the six data registers 0x03..0x08 in one burst; the chip
 * stores them in the order X, Z, Y, each big-endian, and the driver returns x, y, z.
 * A channel whose ADC over- or underflowed reads -4096 (DS, data output registers):
 * the value is kept (the core then sees a count beyond -2048 and flags the sample as
 * clipped) and the call returns SENSOR_MAG_OVERFLOW naming the channel(s).
 *
 * All calls return in bounded time (the only wait is 6 ms after entering continuous
 * mode, DS operational example). No dynamic memory, integer only.
 */
#ifndef HMC5883L_H
#define HMC5883L_H

#include <stdint.h>

#include "i2c.h"
#include "imu_sensor.h"
#include "sensor_regs.h"
#include "sensor_status.h"

/** 7-bit I2C address (fixed). */
#define HMC5883L_ADDRESS 0x1Eu

/** Range of a data register's counts (its 12-bit ADC's). */
#define HMC5883L_COUNT_MIN (-2048)
#define HMC5883L_COUNT_MAX 2047

/** What a data register holds after an ADC overflow or underflow in its channel: below HMC5883L_COUNT_MIN. */
#define HMC5883L_OVERFLOW (-4096)

/** Samples averaged per output, Configuration A MA1..MA0. */
typedef enum {
    HMC5883L_AVERAGE_1 = 0, /**< 1 sample (default) */
    HMC5883L_AVERAGE_2 = 1,
    HMC5883L_AVERAGE_4 = 2,
    HMC5883L_AVERAGE_8 = 3,
} hmc5883l_averaging_t;

/** Data output rate in continuous-measurement mode, Configuration A DO2..DO0. */
typedef enum {
    HMC5883L_RATE_0_75HZ = 0,
    HMC5883L_RATE_1_5HZ = 1,
    HMC5883L_RATE_3HZ = 2,
    HMC5883L_RATE_7_5HZ = 3,
    HMC5883L_RATE_15HZ = 4, /**< default */
    HMC5883L_RATE_30HZ = 5,
    HMC5883L_RATE_75HZ = 6, /**< fastest; 7 is reserved */
} hmc5883l_rate_t;

/** Measurement configuration, Configuration A MS1..MS0: the self-test bias current. */
typedef enum {
    HMC5883L_BIAS_NONE = 0,     /**< normal measurement (default) */
    HMC5883L_BIAS_POSITIVE = 1, /**< positive bias field on all three axes (self test) */
    HMC5883L_BIAS_NEGATIVE = 2, /**< negative bias field on all three axes (self test) */
} hmc5883l_bias_t;

/** Gain, Configuration B GN2..GN0, named by its sensitivity in LSB/gauss (DS, gain settings
 *  of Configuration Register B).
 *  The output range is -2048..2047 at every gain. */
typedef enum {
    HMC5883L_GAIN_1370 = 0, /**< 1370 LSB/gauss, +-0.88 gauss */
    HMC5883L_GAIN_1090 = 1, /**< 1090 LSB/gauss, +-1.3 gauss (default) */
    HMC5883L_GAIN_820 = 2,  /**< 820 LSB/gauss, +-1.9 gauss */
    HMC5883L_GAIN_660 = 3,  /**< 660 LSB/gauss, +-2.5 gauss */
    HMC5883L_GAIN_440 = 4,  /**< 440 LSB/gauss, +-4.0 gauss */
    HMC5883L_GAIN_390 = 5,  /**< 390 LSB/gauss, +-4.7 gauss */
    HMC5883L_GAIN_330 = 6,  /**< 330 LSB/gauss, +-5.6 gauss */
    HMC5883L_GAIN_230 = 7,  /**< 230 LSB/gauss, +-8.1 gauss */
} hmc5883l_gain_t;

/** What hmc5883l_init() writes (the operating mode is always continuous measurement). */
typedef struct {
    hmc5883l_averaging_t averaging; /**< Configuration A MA */
    hmc5883l_rate_t rate;           /**< Configuration A DO */
    hmc5883l_bias_t bias;           /**< Configuration A MS (HMC5883L_BIAS_NONE to measure the field) */
    /** Configuration B GN. A new gain takes effect from the second measurement after it
     *  is written (DS, Configuration Register B). */
    hmc5883l_gain_t gain;
} hmc5883l_config_t;

/** A driven chip. Members are private; hmc5883l_init() fills them. */
typedef struct {
    sensor_device_t dev;       /**< bus, address, chip name for statuses */
    hmc5883l_config_t config;  /**< as written by hmc5883l_init() */
} hmc5883l_t;

/**
 * @brief Identify and configure the chip, start continuous measurement, verify.
 *
 * Sequence: identification registers A, B, C (one 3-byte burst from 10) must read
 * 'H', '4', '3'; Configuration A, Configuration B, Mode (continuous) are written one
 * register per transfer and read back in one burst; the six data registers are read
 * once (reading the Mode register locked them, DS Status register); then 6 ms for the
 * first measurement (DS operational example).
 *
 * @param mag     state to fill (may be uninitialised).
 * @param bus     the bus the chip is reachable on (on the GY-86: only once the MPU6050's
 *                bypass is on); must stay valid while `mag` is used.
 * @param address HMC5883L_ADDRESS.
 * @param config  what to configure (copied).
 * @return SENSOR_OK; SENSOR_ERR_CONFIG (nothing sent), SENSOR_ERR_I2C, SENSOR_ERR_IDENTITY
 *         (got[0..2] = identification registers read) or SENSOR_ERR_READBACK.
 */
sensor_status_t hmc5883l_init(hmc5883l_t *mag, const i2c_bus_t *bus, uint8_t address, const hmc5883l_config_t *config);

/**
 * @brief Read the field: one 6-byte burst from Data Output X MSB (0x03).
 * @param xyz receives x, y, z in the chip's axes, counts (-2048..2047, or
 *            HMC5883L_OVERFLOW); unchanged when the call fails.
 * @return SENSOR_OK, SENSOR_MAG_OVERFLOW (xyz delivered; `channels` names the
 *         overflowed axes) or SENSOR_ERR_I2C.
 */
sensor_status_t hmc5883l_read(hmc5883l_t *mag, int16_t xyz[3]);

/** @brief Sensitivity of a gain, LSB/gauss (DS gain settings); 0 for a value outside the enum. */
uint16_t hmc5883l_lsb_per_gauss(hmc5883l_gain_t gain);

/**
 * @brief Magnetometer scale of a gain: uT per LSB, Q24 (fixed build), i.e.
 *        100 / (LSB per gauss); 0 for a value outside the enum.
 *        Equals host imulink: to_fixed(SensorProfile.mag_scale, 24).
 */
imu_real_t hmc5883l_mag_scale(hmc5883l_gain_t gain);

#endif /* HMC5883L_H */
