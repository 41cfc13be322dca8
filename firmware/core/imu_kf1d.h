/**
 * @file imu_kf1d.h
 * @brief Per-axis angle/bias Kalman filter ([seed 002] and [seed 003]:
 *        docs/filters.md, Bibliography).
 *
 * Three independent 2-state filters, x = [angle, rate bias], one per Euler angle
 * (roll, pitch, heading; conventions in imu_math.h). Prediction ([seed 002]):
 * angle += (rate - bias) dt, P = A P A^T + Q dt with A = [[1, -dt], [0, 1]].
 * Measurements: roll and pitch from the accelerometer, heading from the
 * tilt-compensated magnetometer, each with H = [1, 0]; innovations and angles are
 * wrapped to (-pi, pi].
 *
 * Deviations from the seeds (see docs/filters.md): the attitude is a quaternion,
 * advanced by the bias-corrected gyroscope, and the Euler angles are read from it
 * (exact kinematics, also at large tilt and through the gimbal lock, where the
 * seeds' per-axis rates fail); the angle corrections turn the quaternion as one
 * small rotation; roll and heading measurements are weighted by cos^2(pitch), as
 * both become unobservable when the y axis points up or down; the tilt
 * measurements also by how far |acc| is from g (acc_tolerance).
 *
 * Fixed build, covariance formats: P00 rad^2 Q35 (range 0.0625), P01 rad^2/s Q40
 * (range 0.00195), P11 rad^2/s^2 Q42 (range 4.9e-4); all updates saturate and
 * count. The settings ranges keep the steady state well inside these ranges.
 */
#ifndef IMU_KF1D_H
#define IMU_KF1D_H

#include "imu_common.h"
#include "imu_sensor.h"

/** Settings. All fields are imu_real_t: Q format in the fixed build as written. */
typedef struct {
    imu_real_t sample_rate; /**< Hz, Q16, [10, 32768) */
    imu_real_t q_angle;     /**< angle process noise density, rad^2/s, Q40, [0, 1e-3] */
    imu_real_t q_bias;      /**< bias process noise density, rad^2/s^3, Q48, [0, 5e-6] */
    imu_real_t r_angle;     /**< roll/pitch measurement variance, rad^2, Q35, [1e-6, 0.03] */
    imu_real_t r_heading;   /**< heading measurement variance, rad^2, Q35, [1e-6, 0.03] */
    imu_real_t acc_tolerance; /**< |acc| - g at which the tilt measurements' weight is 1/4, m/s^2, Q24, (0, 1.9] */
} imu_kf1d_settings_t;

extern const imu_kf1d_settings_t imu_kf1d_default_settings;
extern const imu_setting_desc_t imu_kf1d_setting_descs[];
extern const int imu_kf1d_setting_count;

/** One axis. */
typedef struct {
    imu_angle_t angle; /**< rad, Q29: read from quat at the prediction, then corrected */
    imu_q30_t bias;    /**< rad/s, Q30 (+-2 rad/s), in the sense of this angle's rate. Its
                            correction per sample is a few Q24 steps at 1 kHz, too coarse
                            for the fixed build to follow the float twin (docs/filters.md,
                            KF1D, fixed-point precision) */
    imu_real_t p00;    /**< rad^2, Q35 */
    imu_real_t p01;    /**< rad^2/s, Q40 */
    imu_real_t p11;    /**< rad^2/s^2, Q42 */
} imu_kf1d_axis_t;

/** State. All members are private. */
typedef struct {
    imu_kf1d_settings_t settings;
    imu_q30_t dt;              /**< s, Q30 */
    int initialised;           /**< 0 until the first sample set the angles */
    imu_q30_t quat[4];         /**< attitude, sensor to earth, Q30: the angles are read from it */
    imu_wide_t bias_noise_residual; /**< rounding carried between samples' q_bias dt, Q78 */
    imu_kf1d_axis_t axis[3];   /**< roll, pitch, heading */
    uint32_t saturations;      /**< saturation events since initialisation */
} imu_kf1d_t;

/** @brief Initialise with the default settings. */
void imu_kf1d_init(imu_kf1d_t *f);

/** @brief Apply settings and restart; IMU_ERR_RANGE leaves the filter unchanged. */
imu_status_t imu_kf1d_set_settings(imu_kf1d_t *f, const imu_kf1d_settings_t *settings);

/** @brief Process one sample. */
void imu_kf1d_update(imu_kf1d_t *f, const imu_sample_t *sample);

/** @brief Current estimate. */
void imu_kf1d_get(const imu_kf1d_t *f, imu_output_t *out);

#endif /* IMU_KF1D_H */
