/**
 * @file gy86.h
 * @brief The GY-86 module of the reference board: MPU6050 + HMC5883L (+ MS5611, not driven here).
 *
 * On the GY-86 the MPU6050 sits on the main bus at 0x68 (AD0 low) and the HMC5883L
 * on the MPU6050's auxiliary bus (XDA/XCL): the magnetometer answers at 0x1E only
 * after the MPU6050's bypass connects the two buses. gy86_init() therefore brings up
 * the MPU6050, switches the bypass on, then brings up the HMC5883L.
 *
 * gy86_read() delivers what the core consumes (imu_raw_sample_t) in the core's sensor
 * frame, which is the MPU6050's own (x right, y forward, z up; +g on z lying flat):
 * gyroscope and accelerometer as read, the magnetometer mapped into the MPU6050's
 * axes by the table in gy86.c (where the mapping is derived).
 */
#ifndef GY86_H
#define GY86_H

#include <stdint.h>

#include "hmc5883l.h"
#include "i2c.h"
#include "imu_sensor.h"
#include "mpu6050.h"
#include "sensor_status.h"

/** Addresses on the GY-86: the MPU6050's AD0 is pulled low; the HMC5883L's is fixed. */
#define GY86_MPU6050_ADDRESS MPU6050_ADDRESS_AD0_LOW
#define GY86_HMC5883L_ADDRESS HMC5883L_ADDRESS

/** Configuration of both chips. */
typedef struct {
    mpu6050_config_t mpu;  /**< gyroscope, accelerometer, low-pass filter, sample rate, interrupt */
    hmc5883l_config_t mag; /**< magnetometer averaging, output rate, gain */
} gy86_config_t;

/**
 * The reference board's configuration, matching imu_sensor_default_settings:
 * +-2000 deg/s, +-8 g, 100 Hz (1 kHz / (1 + 9)) with DLPF_CFG 3 (42/44 Hz, below the
 * 50 Hz Nyquist limit), data-ready interrupt on; HMC5883L at 75 Hz (its fastest
 * continuous rate), no averaging (the noise the simulation assumes is the data sheet's
 * single-sample noise floor), 1090 LSB/gauss.
 */
extern const gy86_config_t gy86_default_config;

/** The driven module. Members are private; gy86_init() fills them. */
typedef struct {
    mpu6050_t mpu;
    hmc5883l_t mag;
} gy86_t;

/**
 * @brief Bring up the module: MPU6050 (mpu6050_init at 0x68), bypass on
 *        (mpu6050_set_bypass), HMC5883L (hmc5883l_init at 0x1E).
 * @param gy     state to fill (may be uninitialised).
 * @param bus    the main bus; must stay valid while `gy` is used.
 * @param config configuration of both chips (copied), e.g. &gy86_default_config.
 * @return the first failing step's status (its `chip` says which chip), or SENSOR_OK.
 */
sensor_status_t gy86_init(gy86_t *gy, const i2c_bus_t *bus, const gy86_config_t *config);

/**
 * @brief Read one sample of all nine axes and the temperature: the MPU6050's 14-byte
 *        burst, then the HMC5883L's 6-byte burst (the magnetometer repeats its last
 *        measurement when read faster than its output rate).
 * @param raw         receives gyroscope, accelerometer and magnetometer counts in the
 *                    core's sensor frame; unchanged when the call fails.
 * @param temperature receives the MPU6050's TEMP_OUT counts (degC = count / 340 + 36.53);
 *                    may be NULL; unchanged when the call fails.
 * @return SENSOR_OK, SENSOR_MAG_OVERFLOW (sample delivered; the overflowed channel keeps
 *         -4096 so imu_sample_from_raw() flags it clipped; `channels` are in the
 *         HMC5883L's axes) or the failing read's status.
 */
sensor_status_t gy86_read(gy86_t *gy, imu_raw_sample_t *raw, int16_t *temperature);

/**
 * @brief The core's scale settings for a configuration: gyroscope rad/s per LSB (Q40),
 *        accelerometer m/s^2 per LSB (Q32), magnetometer uT per LSB (Q24).
 */
void gy86_sensor_settings(const gy86_config_t *config, imu_sensor_settings_t *settings);

#endif /* GY86_H */
