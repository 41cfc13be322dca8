/**
 * @file mpu6050.h
 * @brief InvenSense MPU-6050 gyroscope + accelerometer over the portable I2C interface.
 *
 * Follows the Register Map and Descriptions RM-MPU-6000A-00 rev 4.2 ("RM") and the
 * Product Specification PS-MPU-6000A-00 rev 3.4 ("PS"); register names are theirs.
 *
 * mpu6050_init() checks WHO_AM_I, resets the chip (PWR_MGMT_1.DEVICE_RESET) and waits,
 * bounded, for the reset to complete, wakes it with the PLL on the X gyroscope as clock,
 * writes the sample rate, low-pass filter, full-scale ranges and the data-ready
 * interrupt, and reads every register it wrote back. mpu6050_read() is one 14-byte
 * burst from ACCEL_XOUT_H. mpu6050_set_bypass() connects the chip's auxiliary I2C bus
 * (XDA/XCL) to the main bus, which is how the GY-86 reaches its HMC5883L.
 *
 * Every call returns a sensor_status_t and returns in bounded time: the only waits are
 * the bus's delay_ms calls of the reset (100 ms, then at most 9 more polls 10 ms apart)
 * and of the gyroscope start-up (30 ms), all in mpu6050_init(); every loop has a fixed
 * bound. No dynamic memory, integer only.
 */
#ifndef MPU6050_H
#define MPU6050_H

#include <stdint.h>

#include "i2c.h"
#include "imu_sensor.h"
#include "sensor_regs.h"
#include "sensor_status.h"

/** 7-bit I2C addresses: AD0 pin low (the GY-86) or high. */
#define MPU6050_ADDRESS_AD0_LOW 0x68u
#define MPU6050_ADDRESS_AD0_HIGH 0x69u

/** WHO_AM_I (0x75) of an MPU-6050: bits 6:1 = 0x34, bits 7 and 0 zero, whatever AD0 is. */
#define MPU6050_WHO_AM_I_VALUE 0x68u

/** Gyroscope full-scale range, GYRO_CONFIG (0x1B) FS_SEL. */
typedef enum {
    MPU6050_GYRO_250DPS = 0,  /**< +-250 deg/s, 131 LSB/(deg/s) */
    MPU6050_GYRO_500DPS = 1,  /**< +-500 deg/s, 65.5 LSB/(deg/s) */
    MPU6050_GYRO_1000DPS = 2, /**< +-1000 deg/s, 32.8 LSB/(deg/s) */
    MPU6050_GYRO_2000DPS = 3, /**< +-2000 deg/s, 16.4 LSB/(deg/s) */
} mpu6050_gyro_range_t;

/** Accelerometer full-scale range, ACCEL_CONFIG (0x1C) AFS_SEL. */
typedef enum {
    MPU6050_ACC_2G = 0,  /**< +-2 g, 16384 LSB/g */
    MPU6050_ACC_4G = 1,  /**< +-4 g, 8192 LSB/g */
    MPU6050_ACC_8G = 2,  /**< +-8 g, 4096 LSB/g */
    MPU6050_ACC_16G = 3, /**< +-16 g, 2048 LSB/g */
} mpu6050_acc_range_t;

/** Largest DLPF_CFG value: 7 is reserved (RM, register 26 CONFIG). */
#define MPU6050_DLPF_CFG_MAX 6u

/** What mpu6050_init() writes. */
typedef struct {
    mpu6050_gyro_range_t gyro_range; /**< GYRO_CONFIG.FS_SEL */
    mpu6050_acc_range_t acc_range;   /**< ACCEL_CONFIG.AFS_SEL */
    /** CONFIG (0x1A) DLPF_CFG, 0..6: gyroscope bandwidth 256, 188, 98, 42, 20, 10, 5 Hz
     *  (accelerometer 260, 184, 94, 44, 21, 10, 5 Hz); 0 runs the gyroscope output at
     *  8 kHz, 1..6 at 1 kHz. See mpu6050_dlpf_for_rate(). */
    uint8_t dlpf_cfg;
    /** SMPLRT_DIV (0x19): sample rate = gyroscope output rate / (1 + sample_rate_div). */
    uint8_t sample_rate_div;
    /** Nonzero: INT_ENABLE.DATA_RDY_EN, the INT pin pulses (50 us, active high, push-pull)
     *  at every new sample; INT_STATUS is cleared by any register read (INT_RD_CLEAR). */
    uint8_t data_ready_interrupt;
} mpu6050_config_t;

/** Range of a data register's counts (every full-scale range spans the int16 range). */
#define MPU6050_COUNT_MIN (-32768)
#define MPU6050_COUNT_MAX 32767

/** One burst of the data registers ACCEL_XOUT_H (0x3B) .. GYRO_ZOUT_L (0x48), in the chip's axes. */
typedef struct {
    int16_t acc[3];      /**< ACCEL_XOUT, _YOUT, _ZOUT: counts (see mpu6050_acc_scale) */
    int16_t temperature; /**< TEMP_OUT: counts; degC = count / 340 + 36.53 */
    int16_t gyr[3];      /**< GYRO_XOUT, _YOUT, _ZOUT: counts (see mpu6050_gyro_scale) */
} mpu6050_sample_t;

/** A driven chip. Members are private; mpu6050_init() fills them. */
typedef struct {
    sensor_device_t dev;     /**< bus, address, chip name for statuses */
    mpu6050_config_t config; /**< as written by mpu6050_init() */
    uint8_t int_pin_cfg;     /**< INT_PIN_CFG as last written (the bypass switch keeps its interrupt bits) */
} mpu6050_t;

/**
 * @brief Identify, reset, wake and configure the chip, and verify the configuration.
 *
 * Sequence: WHO_AM_I must read MPU6050_WHO_AM_I_VALUE (checked first, so nothing is
 * written to another chip that answers the address); PWR_MGMT_1 = DEVICE_RESET, wait
 * 100 ms (PS start-up time), then poll DEVICE_RESET up to 10 times 10 ms apart;
 * PWR_MGMT_1 = CLKSEL 1 (PLL with X gyro reference, as RM register 107 recommends) with
 * SLEEP = 0; SMPLRT_DIV, CONFIG, GYRO_CONFIG, ACCEL_CONFIG, INT_PIN_CFG, INT_ENABLE;
 * read back each register written; wait 30 ms of gyroscope start-up (PS, gyroscope
 * specifications).
 *
 * @param mpu     state to fill (may be uninitialised).
 * @param bus     the bus; must stay valid while `mpu` is used.
 * @param address MPU6050_ADDRESS_AD0_LOW or MPU6050_ADDRESS_AD0_HIGH.
 * @param config  what to configure (copied).
 * @return SENSOR_OK; SENSOR_ERR_CONFIG (nothing sent), SENSOR_ERR_I2C, SENSOR_ERR_IDENTITY
 *         (got[0] = WHO_AM_I read), SENSOR_ERR_RESET or SENSOR_ERR_READBACK.
 */
sensor_status_t mpu6050_init(mpu6050_t *mpu, const i2c_bus_t *bus, uint8_t address, const mpu6050_config_t *config);

/**
 * @brief Connect (`enable` nonzero) or disconnect the auxiliary I2C bus to the main bus.
 *
 * Enabling clears USER_CTRL (0x6A) I2C_MST_EN (the chip's own I2C master must not drive
 * the auxiliary bus) and then sets INT_PIN_CFG (0x37) I2C_BYPASS_EN (RM register 55: the host
 * reaches the auxiliary bus directly only when I2C_BYPASS_EN = 1 and I2C_MST_EN = 0).
 * Both registers are read back. Disabling clears I2C_BYPASS_EN only.
 * Call after mpu6050_init() (the reset clears the bypass).
 */
sensor_status_t mpu6050_set_bypass(mpu6050_t *mpu, int enable);

/**
 * @brief Read accelerometer, temperature and gyroscope in one 14-byte burst from
 *        ACCEL_XOUT_H (the chip updates all of them together, so they are one sample).
 * @param sample receives the counts; unchanged when the call fails.
 */
sensor_status_t mpu6050_read(mpu6050_t *mpu, mpu6050_sample_t *sample);

/**
 * @brief DLPF_CFG with the widest bandwidth below half the sample rate (both the
 *        gyroscope's and the accelerometer's bandwidth), so the filter removes what
 *        the sample rate would alias. Rates of 10 Hz or less get the narrowest (6, 5 Hz).
 * @param sample_rate_hz the rate samples are read at, Hz.
 */
uint8_t mpu6050_dlpf_for_rate(uint32_t sample_rate_hz);

/**
 * @brief The sample rate a configuration produces, mHz: 8 kHz (DLPF_CFG 0) or 1 kHz
 *        (DLPF_CFG 1..6) divided by (1 + SMPLRT_DIV), truncated to 1 mHz. Above 1 kHz
 *        the accelerometer repeats samples (its output rate is 1 kHz, RM register 25).
 */
uint32_t mpu6050_sample_rate_mhz(const mpu6050_config_t *config);

/**
 * @brief Gyroscope sensitivity of a range: rad/s per LSB, Q40 (fixed build), i.e.
 *        (pi/180) / (LSB per deg/s); 0 for a value outside the enum.
 *        Equals host imulink: to_fixed(SensorProfile.gyro_scale, 40).
 */
imu_real_t mpu6050_gyro_scale(mpu6050_gyro_range_t range);

/**
 * @brief Accelerometer sensitivity of a range: m/s^2 per LSB, Q32 (fixed build), i.e.
 *        9.80665 / (LSB per g); 0 for a value outside the enum.
 *        Equals host imulink: to_fixed(SensorProfile.acc_scale, 32).
 */
imu_real_t mpu6050_acc_scale(mpu6050_acc_range_t range);

#endif /* MPU6050_H */
