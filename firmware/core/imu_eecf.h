/**
 * @file imu_eecf.h
 * @brief Enhanced explicit complementary filter with initial alignment (seed 004).
 *
 * Alignment (seed 004 eq. 3-8, 14): for `align_time` seconds the accelerometer
 * and magnetometer are averaged over a moving window of IMU_EECF_AVG_LEN
 * samples, roll and pitch come from the averaged specific force, heading from the
 * tilt-compensated magnetic field, and a first-order complementary filter with
 * time constant `align_tau` blends them with the integrated gyroscope. The final
 * angles become the initial quaternion. Beyond the seed: the gyro propagation
 * during alignment is exact (quaternion) rather than small-angle, and when the
 * board stayed still the mean gyroscope reading initialises the bias estimate
 * (the PI integral), sparing the slow integral convergence.
 *
 * Filtering (eq. 20-30): the gravity error e_a = a x v (a: measured unit specific
 * force, v: estimated up direction in the sensor frame) and the heading error
 * from the magnetometer correct the gyroscope through a PI law,
 * w' = w + kp e_a + kp_mag e_m + I, with I += ki (e_a + e_m) dt. The quaternion
 * is advanced with the exact exponential of the rotation vector w' dt, in two
 * steps: first the gyroscope (sample k covers the interval ending at t_k), then
 * the errors are measured against the accelerometer and magnetometer of the same
 * sample and the correction is applied.
 *
 * Deviation from the seed (see docs/filters.md): the magnetometer error uses the
 * horizontal field direction only (e_m is the sine of the heading error about the
 * earth's vertical, mapped to the sensor frame), so magnetic disturbances cannot
 * tilt roll and pitch, and its size does not depend on the dip angle.
 */
#ifndef IMU_EECF_H
#define IMU_EECF_H

#include "imu_common.h"
#include "imu_sensor.h"

/** Length of the alignment moving average, samples. */
#define IMU_EECF_AVG_LEN 8

/** Settings. All fields are imu_real_t: Q format in the fixed build as written. */
typedef struct {
    imu_real_t sample_rate; /**< Hz, Q16, [10, 32768) */
    imu_real_t kp;          /**< proportional gain of the gravity error, 1/s, Q16, [0, 100] */
    imu_real_t kp_mag;      /**< proportional gain of the heading error, 1/s, Q16, [0, 100] */
    imu_real_t ki;          /**< integral gain (bias estimation), 1/s^2, Q16, [0, 1] */
    imu_real_t bias_limit;  /**< clamp of the integral (largest bias), rad/s, Q24, [0, 1] */
    imu_real_t align_time;  /**< duration of the initial alignment, s, Q16, [0, 60] */
    imu_real_t align_tau;   /**< complementary time constant during alignment, s, Q16, [0, 10] */
} imu_eecf_settings_t;

extern const imu_eecf_settings_t imu_eecf_default_settings;
extern const imu_setting_desc_t imu_eecf_setting_descs[];
extern const int imu_eecf_setting_count;

/** State. All members are private. */
typedef struct {
    imu_eecf_settings_t settings;
    imu_q30_t dt;                 /**< sample period, s, Q30 */
    imu_q30_t align_alpha;        /**< complementary weight of the measurement, Q30 */
    int32_t align_samples;        /**< alignment length, samples */
    int32_t sample_count;         /**< samples seen since initialisation (stops counting at align_samples) */
    imu_q30_t q[4];               /**< attitude, Q30 */
    imu_q30_t integral[3];        /**< PI integral = minus the gyro bias, rad/s, Q30 */
    imu_angle_t align_euler[3];   /**< alignment angles, rad, Q29 */
    imu_rate_t align_gyro_mean[3]; /**< mean gyroscope reading during alignment, rad/s, Q24 */
    imu_rate_t align_gyro_min[3];  /**< smallest gyroscope reading during alignment, rad/s, Q24 */
    imu_rate_t align_gyro_max[3];  /**< largest gyroscope reading during alignment, rad/s, Q24 */
    imu_q16_t acc_window[IMU_EECF_AVG_LEN][3]; /**< m/s^2, Q16 */
    imu_q16_t mag_window[IMU_EECF_AVG_LEN][3]; /**< uT, Q16 */
    uint32_t saturations;         /**< saturation events since initialisation */
} imu_eecf_t;

/** @brief Initialise with the default settings; the next samples align. */
void imu_eecf_init(imu_eecf_t *f);

/** @brief Apply settings and restart alignment; IMU_ERR_RANGE leaves the filter unchanged. */
imu_status_t imu_eecf_set_settings(imu_eecf_t *f, const imu_eecf_settings_t *settings);

/** @brief Process one sample. */
void imu_eecf_update(imu_eecf_t *f, const imu_sample_t *sample);

/** @brief Current estimate. */
void imu_eecf_get(const imu_eecf_t *f, imu_output_t *out);

/** @brief 1 while the initial alignment is running. */
int imu_eecf_aligning(const imu_eecf_t *f);

#endif /* IMU_EECF_H */
