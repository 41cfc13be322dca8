/**
 * @file imu_eecf.h
 * @brief Enhanced explicit complementary filter with initial alignment ([seed 004]:
 *        docs/filters.md, Bibliography).
 *
 * Alignment ([seed 004] eq. 3-8, 14): for `align_time` seconds the accelerometer
 * and magnetometer are averaged over a moving window of IMU_EECF_AVG_LEN
 * samples, roll and pitch come from the averaged specific force, heading from the
 * tilt-compensated magnetic field, and a first-order complementary filter with
 * time constant `align_tau` blends them with the integrated gyroscope. The final
 * angles become the initial quaternion. Beyond the seed: the gyro propagation
 * during alignment is exact (quaternion) rather than small-angle; and when the rest
 * detector (below) saw the board still through the whole alignment, the angles come
 * from its low-passed specific force and field, free of the bias the complementary
 * filter integrated, and the first rest (with the defaults the sample after the
 * alignment) sets the bias estimate to the mean gyroscope reading since power-up. A
 * board that turned steadily (a turntable at power-up) fails the turn tests, and its
 * rate is not taken for bias.
 *
 * Filtering (eq. 20-30): the gravity error e_a = a x v (a: measured unit specific
 * force, v: estimated up direction in the sensor frame) and the heading error
 * from the magnetometer correct the gyroscope through a PI law,
 * w' = w + kp e_a + kp_mag e_m + I, with I += w_a (ki e_a + ki_mag e_m) dt and
 * |I| <= bias_limit per axis; -I is the gyro bias estimate. The weight
 * w_a = 1 / (1 + (| |a| - g | / acc_tolerance)^2)^2 keeps linear accelerations out
 * of the integral (g: |a| at the last rest, standard gravity before). The
 * errors are measured against the accelerometer and magnetometer of the same
 * sample (sample k covers the interval ending at t_k): against the attitude the
 * gyroscope's step reaches, predicted to first order in the step (a step beyond
 * 2^-2 rad on an axis is integrated first). The quaternion is then advanced once,
 * with the exact exponential of the rotation vector w' dt.
 *
 * Rest detection: the core's one rest detector (imu_rest.h), the ESKF's too, updated
 * every sample with this filter's settings and its turn tests (no rate test):
 *  - steady: each gyroscope and accelerometer sample within `rest_gyro` and `rest_acc`
 *    of the detector's low-passes (time constant `rest_tau`);
 *  - turn tests: once steady for `rest_tau`, the low-passed specific force and field
 *    are references; a turn of either beyond `rest_turn` takes a new reference and
 *    restarts that test's count;
 *  - quiet (steady, gravity unturned for `rest_time`): no linear acceleration. The
 *    proportional gains become `rest_kp` and `rest_kp_mag` (the gains for sensor noise
 *    alone), and |a| at the gravity reference becomes the g of the weight w_a;
 *  - at rest (quiet, and the field unturned for `rest_time` too): the bias estimate
 *    follows the mean gyroscope reading with time constant `rest_tau`; while the board
 *    has been still since power-up it is that mean. The mean is this filter's: it starts
 *    when the detector begins to see the board still and averages over up to
 *    `rest_bias_tau` (the detector's own low-pass, over `rest_tau`, is too short an
 *    average for the bias).
 * Why turn tests and not the ESKF's rate test (bias-corrected low-passed rate below
 * 2 deg/s): the MPU6050's zero-rate offset may reach 20 deg/s, and this filter has no
 * estimate of it at power-up; with the rate test a board lying still with a 10 deg/s
 * offset is never at rest and its attitude is lost (docs/filters.md). The turn tests'
 * limit: a rotation slower than about rest_turn / (rest_time sin(angle between axis and
 * field)) -- 0.85 deg/s about the vertical at 67 deg dip with the defaults -- can pass
 * for rest, and its rate be taken for bias. The decisions depend on the sensor readings
 * alone, so the fixed build and the float twin take the same ones except within
 * rounding of a limit.
 *
 * Deviation from the seed (see docs/filters.md): the magnetometer error uses the
 * horizontal field direction only (e_m is the sine of the heading error about the
 * earth's vertical, mapped to the sensor frame), so magnetic disturbances cannot
 * tilt roll and pitch, and its size does not depend on the dip angle.
 */
#ifndef IMU_EECF_H
#define IMU_EECF_H

#include "imu_common.h"
#include "imu_rest.h"
#include "imu_sensor.h"

/** Length of the alignment moving average, samples. */
#define IMU_EECF_AVG_LEN 8

/** Settings. All fields are imu_real_t: Q format in the fixed build as written.
 *  New fields are appended, so the indices of the older ones stay. */
typedef struct {
    imu_real_t sample_rate; /**< Hz, Q16, [10, 32768) */
    imu_real_t kp;          /**< proportional gain of the gravity error, 1/s, Q16, [0, 100] */
    imu_real_t kp_mag;      /**< proportional gain of the heading error, 1/s, Q16, [0, 100] */
    imu_real_t ki;          /**< integral gain of the gravity error (bias estimation), 1/s^2, Q30, [0, 1] */
    imu_real_t bias_limit;  /**< clamp of each axis of the bias estimate, rad/s, Q24, [0, 1] */
    imu_real_t align_time;  /**< duration of the initial alignment, s, Q16, [0, 60] */
    imu_real_t align_tau;   /**< complementary time constant during alignment, s, Q16, [0, 10] */
    imu_real_t ki_mag;      /**< integral gain of the heading error, 1/s^2, Q30, [0, 1] */
    imu_real_t rest_time;   /**< rest detector: time the tests must hold (the turn tests after rest_tau steady), s, Q16, [0, 60] */
    imu_real_t rest_tau;    /**< rest detector's low-pass time constant; also of the bias learnt at rest, s, Q16, [0, 10] */
    imu_real_t rest_gyro;   /**< rest detector: largest deviation of a gyro sample from its low-pass, rad/s, Q24, [0, 1]; 0: no rest detection */
    imu_real_t rest_acc;    /**< rest detector: largest deviation of an accelerometer sample from its low-pass, m/s^2, Q16, [0, 100] */
    imu_real_t rest_turn;   /**< rest detector: largest turn of the low-passed specific force and field, rad, Q30, [0, 0.5] */
    imu_real_t rest_kp;     /**< kp while quiet (see above), 1/s, Q16, [0, 100] */
    imu_real_t rest_kp_mag; /**< kp_mag while quiet, 1/s, Q16, [0, 100] */
    imu_real_t acc_tolerance; /**< | |acc| - g | where the integral's weight w_a is 1/4, m/s^2, Q24, (0, 1.9] */
    imu_real_t rest_bias_tau; /**< longest averaging of the gyroscope at rest, s, Q16, [0, 1000] */
} imu_eecf_settings_t;

extern const imu_eecf_settings_t imu_eecf_default_settings;
extern const imu_setting_desc_t imu_eecf_setting_descs[];
extern const int imu_eecf_setting_count;

/** State. All members are private. */
typedef struct {
    imu_eecf_settings_t settings;
    imu_q30_t dt;                 /**< sample period, s, Q30 */
    imu_q30_t align_alpha;        /**< complementary weight of the measurement, Q30 */
    imu_q30_t rest_alpha;         /**< weight dt / (rest_tau + dt) of the bias learnt at rest, Q30 */
    imu_q30_t bias_alpha;         /**< low-pass weight dt / (rest_bias_tau + dt), Q30 */
    imu_real_t ki_dt;             /**< ki dt, 1/s, Q34 (at most 0.1: below 2^31) */
    imu_real_t ki_mag_dt;         /**< ki_mag dt, 1/s, Q34 */
    int32_t align_samples;        /**< alignment length, samples */
    int32_t bias_warmup;          /**< rest_bias_tau in samples plus one (below 2^25) */
    int32_t sample_count;         /**< samples seen since initialisation (stops counting at align_samples) */
    int32_t gyr_count;            /**< samples in the gyroscope mean (saturates) */
    int32_t at_rest;              /**< 1 when the rest detector found the last sample at rest */
    int32_t still_from_start;     /**< 1 while the rest detector has seen the board still since initialisation */
    imu_q30_t q[4];               /**< attitude, Q30 */
    imu_q16_t gravity;            /**< g of the weight w_a: |acc| when last quiet (standard gravity before), m/s^2, Q16 */
    imu_wide_t integral[3];       /**< PI integral = minus the gyro bias, rad/s, Q54 (|I| <= bias_limit <= 2^54) */
    imu_angle_t align_euler[3];   /**< alignment angles, rad, Q29 */
    imu_rate_t gyr_mean[3];       /**< mean gyroscope reading since the board was last seen still, rad/s, Q24 */
    imu_rest_t rest;              /**< the core's rest detector (imu_rest.h), updated every sample */
    imu_q16_t acc_window[IMU_EECF_AVG_LEN][3]; /**< m/s^2, Q16 */
    imu_q16_t mag_window[IMU_EECF_AVG_LEN][3]; /**< uT, Q16 */
    uint32_t saturations;         /**< saturation events since initialisation */
    uint32_t padding;             /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
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

/** @brief 1 while the rest detector found the last sample at rest (the bias estimate learns from it). */
int imu_eecf_at_rest(const imu_eecf_t *f);

#endif /* IMU_EECF_H */
