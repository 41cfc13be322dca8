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
 * tests (below) held through the whole alignment, the board was still: the mean
 * gyroscope reading initialises the bias estimate, and the angles come from the
 * rest means of specific force and field, free of the bias the complementary filter
 * integrated. A board that turned steadily (a turntable at power-up) fails the turn
 * tests, and its rate is not taken for bias.
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
 * Rest detection (the idea of VQF, Laidig and Seel 2023; own formulation). A run is
 * a stretch of samples in which each gyroscope sample deviates from the run's mean
 * gyroscope reading by less than `rest_gyro` and each accelerometer sample from the
 * run's mean specific force by less than `rest_acc` (norms). The run's means (of
 * gyroscope, specific force and field) are running means over its first `rest_tau`
 * seconds and first-order low-passes with that time constant after. Once they have
 * settled, two turn tests compare the mean specific force and the mean field with
 * references: a turn by more than `rest_turn` takes a new reference and restarts
 * that test's count.
 *  - Quiet (steady run, gravity unturned for `rest_time`): no linear acceleration.
 *    The proportional gains become `rest_kp` and `rest_kp_mag` (the gains for sensor
 *    noise alone), and |a| becomes the g of the weight w_a.
 *  - At rest (quiet, and the field unturned for `rest_time` too): the bias estimate
 *    follows the run's mean gyroscope reading with time constant `rest_tau`.
 * The mean gyroscope reading itself is not compared with a threshold (the MPU6050's
 * zero-rate offset may reach 20 deg/s): the turn tests tell an offset from a slow
 * steady rotation. Their limit: a rotation slower than about
 * rest_turn / (rest_time sin(angle between axis and field)) -- 0.85 deg/s about the
 * vertical at 67 deg dip with the defaults -- can pass for rest, and its rate be
 * taken for bias. The tests depend on the sensor readings alone, so the fixed build
 * and the float twin take the same decisions except within rounding of a limit.
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
    imu_real_t rest_time;   /**< time the turn tests must hold (after rest_tau of steady run), s, Q16, [0, 60] */
    imu_real_t rest_tau;    /**< time constant of the run's means and of the bias learnt at rest, s, Q16, [0, 10] */
    imu_real_t rest_gyro;   /**< largest deviation of a gyro sample from the run's mean, rad/s, Q24, [0, 1]; 0: no rest detection */
    imu_real_t rest_acc;    /**< largest deviation of an accelerometer sample from the run's mean, m/s^2, Q16, [0, 100] */
    imu_real_t rest_turn;   /**< largest turn of the mean specific force and field during a rest, rad, Q30, [0, 0.5] */
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
    imu_q30_t rest_alpha;         /**< low-pass weight dt / (rest_tau + dt), Q30 */
    imu_q30_t bias_alpha;         /**< low-pass weight dt / (rest_bias_tau + dt), Q30 */
    imu_real_t ki_dt;             /**< ki dt, 1/s, Q34 (at most 0.1: below 2^31) */
    imu_real_t ki_mag_dt;         /**< ki_mag dt, 1/s, Q34 */
    int32_t align_samples;        /**< alignment length, samples */
    int32_t rest_confirm;         /**< rest_time, samples (at most 2^21) */
    int32_t rest_warmup;          /**< rest_tau in samples plus one (at most 2^19): running means before the low-passes */
    int32_t bias_warmup;          /**< rest_bias_tau in samples plus one (below 2^25) */
    int32_t sample_count;         /**< samples seen since initialisation (stops counting at align_samples) */
    int32_t rest_count;           /**< samples in the current run of steady samples (saturates) */
    int32_t acc_still_count;      /**< samples since the specific force's turn reference (saturates) */
    int32_t mag_still_count;      /**< samples since the field's turn reference (saturates) */
    int32_t gyr_count;            /**< samples in the gyroscope mean (saturates) */
    imu_q30_t q[4];               /**< attitude, Q30 */
    imu_wide_t integral[3];       /**< PI integral = minus the gyro bias, rad/s, Q54 (|I| <= bias_limit <= 2^54) */
    imu_angle_t align_euler[3];   /**< alignment angles, rad, Q29 */
    imu_rate_t gyr_mean[3];       /**< gyroscope mean since the run or the last turn began, rad/s, Q24 */
    imu_q16_t acc_mean[3];        /**< specific force mean of the run, m/s^2, Q16 */
    imu_q16_t mag_mean[3];        /**< field mean of the run, uT, Q16 */
    imu_q16_t acc_turn_ref[3];    /**< acc_mean when its turn test (re)started, m/s^2, Q16 */
    imu_q16_t mag_turn_ref[3];    /**< mag_mean when its turn test (re)started, uT, Q16 */
    imu_q16_t acc_turn_limit;     /**< |acc_turn_ref| rest_turn, m/s^2, Q16 */
    imu_q16_t mag_turn_limit;     /**< |mag_turn_ref| rest_turn, uT, Q16 */
    imu_q16_t acc_ref_norm;       /**< |acc_turn_ref|, m/s^2, Q16 */
    imu_q16_t gravity;            /**< g of the weight w_a: |acc| when last quiet (standard gravity before), m/s^2, Q16 */
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

/** @brief 1 while the rest detection finds the board at rest (the bias estimate learns from it). */
int imu_eecf_at_rest(const imu_eecf_t *f);

#endif /* IMU_EECF_H */
