/**
 * @file imu_sensor.h
 * @brief Raw sensor samples and their conversion to the filters' units.
 *
 * The core consumes what the registers give: int16 counts of a gyroscope, an
 * accelerometer and a magnetometer, in the sensor frame (x right, y forward, z up).
 * Scale settings turn them into rad/s, m/s^2 and uT, and the registers' limits say
 * which counts may stand for more. The accelerometer reads specific force: +g on z
 * when lying flat.
 */
#ifndef IMU_SENSOR_H
#define IMU_SENSOR_H

#include "imu_common.h"

/** One sample as read from the sensor registers. */
typedef struct {
    int16_t gyr[3]; /**< gyroscope counts */
    int16_t acc[3]; /**< accelerometer counts */
    int16_t mag[3]; /**< magnetometer counts */
} imu_raw_sample_t;

/** Bits of imu_sample_t.clipped: a count at its register's limit (the true value may be larger). */
#define IMU_CLIPPED_GYR 1u
#define IMU_CLIPPED_ACC 2u
#define IMU_CLIPPED_MAG 4u

/** One sample in the filters' units. */
typedef struct {
    imu_rate_t gyr[3]; /**< angular rate, rad/s (Q24) */
    imu_q16_t acc[3];  /**< specific force, m/s^2 (Q16) */
    imu_q16_t mag[3];  /**< magnetic field, uT (Q16) */
    unsigned clipped;  /**< IMU_CLIPPED_* bits */
} imu_sample_t;

/** Standard gravity, m/s^2, Q16 as imu_sample_t.acc: what a resting accelerometer reads. */
#define IMU_STANDARD_GRAVITY IMU_QCONST(9.80665, 16)

/** Sensitivities and register limits of the three sensors. A count at a limit (or beyond:
 *  a magnetometer may report overflow with a count below its range) may stand for more, and
 *  the sample says so (imu_sample_t.clipped). */
typedef struct {
    imu_real_t gyro_scale;  /**< rad/s per LSB, Q40 (MPU6050 at +-2000 deg/s: 1.0642e-3) */
    imu_real_t acc_scale;   /**< m/s^2 per LSB, Q32 (MPU6050 at +-8 g: 2.3943e-3) */
    imu_real_t mag_scale;   /**< uT per LSB, Q24 (HMC5883L at its default gain: 9.1743e-2) */
    int16_t gyro_limits[2]; /**< smallest and largest count of the gyroscope's registers (MPU6050: the int16 range) */
    int16_t acc_limits[2];  /**< ... of the accelerometer's (MPU6050: the int16 range) */
    int16_t mag_limits[2];  /**< ... of the magnetometer's (HMC5883L: -2048, 2047; -4096 on overflow) */
} imu_sensor_settings_t;

/** MPU6050 at +-2000 deg/s and +-8 g, HMC5883L at 1090 LSB/gauss (the GY-86's). */
extern const imu_sensor_settings_t imu_sensor_default_settings;

/** @brief The IMU_CLIPPED_* bits of the sensors with a count at (or beyond) its registers' limits. */
unsigned imu_sample_clipped(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw);

/**
 * @brief Scale raw counts to rad/s, m/s^2 and uT, and flag counts at their limits.
 *
 * Fixed build, scaling and overflow: |count| <= 2^15, so the gyroscope (Q40 scale,
 * >> 16) and accelerometer (Q32 scale, >> 16) results stay below 2^30 for any scale
 * in int32. The magnetometer (Q24 scale, >> 8) fits for scales below 2^23, i.e.
 * 0.5 uT/LSB (the HMC5883L's coarsest gain is 0.435 uT/LSB); beyond, the result
 * saturates and counts in *sat. The same as imu_sample_from_raw_calibrated() with
 * imu_calibration_identity.
 */
void imu_sample_from_raw(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw,
                         imu_sample_t *out, uint32_t *sat);

/** Fraction bits of a calibration's offsets (counts) and of its matrix elements. */
#define IMU_CAL_OFFSET_Q 8
#define IMU_CAL_MATRIX_Q 24
/** Largest offset magnitude accepted, counts, Q8 (65536 counts: twice a register's range).
 *  It bounds the corrected sums (see imu_sample_from_raw_calibrated). */
#define IMU_CAL_MAX_OFFSET IMU_QCONST(65536.0, 8)

/**
 * One sensor's correction of its counts, applied before the scaling:
 * corrected[i] = sum_j matrix[3 i + j] (raw[j] - offset[j]), in counts.
 * Gyroscope: offset = the bias at rest, matrix = identity; accelerometer: offset and
 * scale per axis (or a symmetric matrix); magnetometer: hard iron (offset) and soft iron
 * (matrix). The host computes them (host/imulink/analysis/calibration.py).
 */
typedef struct {
    imu_real_t offset[3]; /**< counts, Q8 (|offset| <= IMU_CAL_MAX_OFFSET) */
    imu_real_t matrix[9]; /**< row-major, dimensionless, Q24 (range +-128, resolution 6e-8) */
} imu_sensor_cal_t;

/** The calibration of the three sensors. */
typedef struct {
    imu_sensor_cal_t gyr;
    imu_sensor_cal_t acc;
    imu_sensor_cal_t mag;
} imu_calibration_t;

/** Offsets 0, identity matrices: the counts pass unchanged. */
extern const imu_calibration_t imu_calibration_identity;

/** @brief 1 when `cal` is imu_calibration_identity (the counts pass unchanged), else 0. */
int imu_calibration_is_identity(const imu_calibration_t *cal);

/** @brief IMU_OK, or IMU_ERR_RANGE when an offset lies beyond IMU_CAL_MAX_OFFSET. */
imu_status_t imu_calibration_check(const imu_calibration_t *cal);

/**
 * @brief imu_sample_from_raw() with the counts corrected by `cal` first (checked with
 *        imu_calibration_check()); the clipping flags are the raw counts'.
 *
 * Fixed build: c_j = raw_j 2^8 - offset_j (Q8 counts, |c_j| < 2^23 + 2^24 < 2^25); the
 * sum of three products with Q24 matrix elements (|m| <= 2^31) stays below 3 * 2^56;
 * rounded to Q8 and saturated, the corrected count is scaled as imu_sample_from_raw()
 * scales a count (its shift 8 bits longer). With the identity calibration every step
 * is exact and the result equals imu_sample_from_raw()'s, saturations included.
 */
void imu_sample_from_raw_calibrated(const imu_sensor_settings_t *settings, const imu_calibration_t *cal,
                                    const imu_raw_sample_t *raw, imu_sample_t *out, uint32_t *sat);

#endif /* IMU_SENSOR_H */
