/**
 * @file imu_eskf.h
 * @brief 9-state error-state Kalman filter ([seed 000]: docs/filters.md, Bibliography), with
 *        its gaps fixed.
 *
 * Error state x = [dtheta (3), dbg (3), dba (3)]: attitude error angle in the
 * sensor frame (rad; twice the seed's error-quaternion vector part, true =
 * estimate (x) exp(dtheta)), gyro bias error (rad/s), accelerometer bias error (in
 * units of g, so that every measurement coefficient is at most 1). Without accelerometer
 * bias states (estimate_acc_bias 0) the covariance's last three states are the low-passed
 * specific force's error angle instead (imu_eskf.c, lowpass_error_states). The covariance is
 * stored in block-floating form (imu_cov.h).
 *
 * Gyro samples are consumed three at a time (three-sample rotation vector), so the
 * covariance and the measurements run at a third of the sensor rate, T = 3 / sample_rate
 * (any sensor rate: the filter rate need not be an integer). Between filter steps the
 * output is the attitude propagated by the increments received so far; an incomplete
 * group at the end of a stream is not yet fused.
 *
 * Measurements: gravity (from the specific force low-passed in the estimated earth frame),
 * heading (the horizontal field's angle from north, correcting only the vertical attitude
 * and gyro bias components) and, at rest (imu_rest.h), the gyro bias; each is down-weighted
 * smoothly as its input departs from its model. Clipped sensors skip their update or
 * re-align the attitude. Inputs beyond 1024 m/s^2 or 1024 uT are clamped and count as
 * clipped.
 *
 * The design, equation by equation, and why it departs from [seed 000]: docs/filters.md,
 * "ESKF".
 */
#ifndef IMU_ESKF_H
#define IMU_ESKF_H

#include "imu_common.h"
#include "imu_cov.h"
#include "imu_math.h"
#include "imu_rest.h"
#include "imu_sensor.h"

/** Settings. All fields are imu_real_t: Q format in the fixed build as written. */
typedef struct {
    imu_real_t sample_rate;        /**< sensor rate (filter rate x 3), Hz, Q16, [30, 32767] */
    imu_real_t gyro_arw;           /**< gyro angle random walk, rad/sqrt(s), Q32, [0, 0.49] */
    imu_real_t gyro_rrw;           /**< gyro rate random walk, rad/s/sqrt(s), Q40, [0, 1.9e-3] */
    imu_real_t acc_bias_rw;        /**< accelerometer bias random walk, m/s^2/sqrt(s), Q32, [0, 0.49] */
    imu_real_t acc_noise;          /**< specific-force noise per filter step, m/s^2, Q24, [1e-3, 100] (9 states, turning:
                                        0.22 m/s^2 more for the low-pass's error, imu_eskf.c) */
    imu_real_t mag_noise;          /**< horizontal magnetic field noise per filter step, uT, Q16, [1e-3, 1000] */
    imu_real_t init_attitude_std;  /**< initial attitude uncertainty, rad, Q28, [1e-4, 3.2] */
    imu_real_t init_gyro_bias_std; /**< initial gyro bias uncertainty, rad/s, Q30, [1e-5, 1] */
    imu_real_t init_acc_bias_std;  /**< initial accelerometer bias uncertainty, m/s^2, Q24, [1e-4, 10] */
    imu_real_t estimate_acc_bias;  /**< 1: 9 states; 0: no accelerometer bias states, Q0, {0, 1} */
    imu_real_t gravity;            /**< local gravity, m/s^2, Q24, [9, 10.5] */
    imu_real_t acc_tolerance;      /**< specific-force norm deviation scale, fraction of g, Q30, [1e-3, 1] */
    imu_real_t mag_tolerance;      /**< field norm deviation scale, fraction of the reference, Q30, [1e-3, 1] */
    imu_real_t dip_tolerance;      /**< field dip deviation scale, rad, Q30, [1e-3, 1.5] */
    imu_real_t acc_lowpass;        /**< time constant of the earth-frame specific-force low-pass, s, Q16, [0, 60] */
    imu_real_t gyro_scale_std;     /**< gyro scale-factor and misalignment uncertainty, fraction of the rotation, Q30, [0, 0.05] */
} imu_eskf_settings_t;

extern const imu_eskf_settings_t imu_eskf_default_settings;
extern const imu_setting_desc_t imu_eskf_setting_descs[];
extern const int imu_eskf_setting_count;

/** A magnetic field's norm and dip, with 30 fraction bits more than the measured ones: the
 *  reference follows a field with a time constant of up to 30 s, whose step at a high rate is
 *  a fraction of a Q16 or Q29 LSB (rounded, it would stop up to 0.4 uT short). */
typedef struct {
    imu_wide_t norm; /**< uT, Q46 */
    imu_wide_t dip;  /**< below the horizon positive, rad, Q59 */
} imu_eskf_field_t;

/** State. All members are private. */
typedef struct {
    imu_eskf_settings_t settings;
    imu_q30_t dt;                 /**< sensor period, s, Q30 */
    imu_q30_t period;             /**< filter period T = 3 dt, s, Q30 */
    imu_q30_t inv_gravity;        /**< 1 / gravity, 1/(m/s^2), Q30 */
    uint32_t saturations;         /**< saturation events since initialisation */
    imu_wide_t process_var[9];    /**< per-step process noise, Q64: rad^2, (rad/s)^2, g^2 */
    int initialised;              /**< 0 until the first sample set the attitude */
    int in_group;                 /**< gyro increments buffered in the current group, 0..2 */
    unsigned clipped;             /**< IMU_CLIPPED_* bits seen in the current group, and whether the last
                                       group's accelerometer clipped (a private bit, imu_eskf.c) */
    int realign;                  /**< 1 after a clipped gyroscope, until the next calm step re-aligns */
    int32_t steps;                /**< filter steps so far (counts up to learn_steps) */
    int32_t learn_steps;          /**< filter steps of the magnetic dip learning phase */
    imu_q30_t increments[3][3];   /**< bias-corrected gyro increments of the group, rad, Q30 */
    imu_q16_t acc_sum[3];         /**< sum of the group's specific force, m/s^2, Q16 */
    imu_q16_t acc_held[3];        /**< the last group's specific force in the estimated earth frame, m/s^2,
                                       Q16, waiting to enter the low-pass (hold_specific_force) */
    int acc_held_valid;           /**< 1 when acc_held enters the low-pass unless the next group clips */
    imu_real_t gyr_sum[3];        /**< sum of the group's angular rate, rad/s, Q22 (three times 128 rad/s fit) */
    imu_rest_t rest;              /**< rest detection on the group means */
    int at_rest;                  /**< 1 when the last filter step was at rest */
    imu_q30_t jump_turn[3];       /**< the rotation the low-passed rate (after the bias estimate) read since it
                                       first showed a bias jump, while the rest's turn tests held, rad, Q30
                                       (check_bias_jump); zero while none */
    int32_t padding_jump;         /**< explicit padding (see padding_ref) */
    imu_wide_t rest_var;          /**< variance of the rest measurement of the bias, (rad/s)^2, Q48 */
    imu_q16_t mag_sum[3];         /**< sum of the group's magnetic field, uT, Q16 */
    imu_q30_t q[4];               /**< attitude at the last filter step, Q30 */
    imu_q30_t q_out[4];           /**< attitude at the last sample, Q30 */
    imu_q30_t injected[4];        /**< the last correction's rotation exp(dtheta), Q30 (see filter_step) */
    imu_q30_t gyro_bias[3];       /**< rad/s, Q30 */
    imu_q30_t acc_bias[3];        /**< in units of g, Q30 */
    int32_t padding_ref;          /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_eskf_field_t ref;         /**< reference field; norm 0: none yet */
    imu_eskf_field_t cand;        /**< candidate reference field while disturbed; norm 0: none */
    imu_field_trust_t trust;      /**< turning filter steps the reference held and the candidate has held */
    int32_t new_field_steps;      /**< filter steps of IMU_FIELD_NEW_TIME */
    int32_t trust_limit_steps;    /**< filter steps of IMU_FIELD_TRUST_LIMIT */
    int turning;                  /**< 1 when the last filter step turned faster than 20 deg/s */
    imu_q30_t acc_alpha;          /**< low-pass weight T / (acc_lowpass + T), Q30 */
    imu_wide_t acc_earth[3];      /**< low-passed specific force in the estimated earth frame, m/s^2, Q46:
                                       a step of the low-pass or of a correction's turn is a fraction of a
                                       Q16 LSB at high rates, and such rounding errors repeat step after step */
    imu_wide_t lowpass_rotation[3][3]; /**< the same low-pass of R (earth from sensor), Q59, 9 states only:
                                       acc_earth holds lowpass(R) ba of the accelerometer bias ba, not R ba */
    imu_q30_t lowpass_settled;    /**< the low-pass's steady noise variance over its present one, Q30 in (0, 1]:
                                       n alpha / (2 - alpha) while it is the mean of n values, then up to
                                       1 (lowpass_weight); 0: it holds nothing yet */
    imu_q30_t acc_weight;         /**< weight of the last gravity update, Q30 */
    imu_q30_t mag_weight;         /**< weight of the last heading update, Q30 */
    imu_cov_t cov;                /**< error-state covariance */
} imu_eskf_t;

/** @brief Initialise with the default settings. */
void imu_eskf_init(imu_eskf_t *f);

/** @brief Apply settings and restart; IMU_ERR_RANGE leaves the filter unchanged. */
imu_status_t imu_eskf_set_settings(imu_eskf_t *f, const imu_eskf_settings_t *settings);

/** @brief Process one sensor sample. */
void imu_eskf_update(imu_eskf_t *f, const imu_sample_t *sample);

/** @brief Current estimate. */
void imu_eskf_get(const imu_eskf_t *f, imu_output_t *out);

/** @brief Accelerometer bias estimate: acc_bias[k] in m/s^2, Q24 (an imu_real_t: the arithmetic layer
 *         has no type of its own for Q24 m/s^2). */
void imu_eskf_get_acc_bias(const imu_eskf_t *f, imu_real_t acc_bias[3]);

/** @brief Weights (Q30, [0, 1]) of the last gravity and heading updates: 1 trusted, 0 rejected. */
void imu_eskf_get_weights(const imu_eskf_t *f, imu_q30_t *gravity, imu_q30_t *heading);

/** @brief Number of error states (9, or 6 without accelerometer bias). */
int imu_eskf_state_count(const imu_eskf_t *f);

/**
 * @brief Covariance element (i, j) of the error state in the state units (rad,
 *        rad/s, g): P_ij = mant * 2^(exp - 30) (fixed), mant with exp = 0 (float).
 */
void imu_eskf_covariance(const imu_eskf_t *f, int i, int j, imu_real_t *mant, int32_t *exp);

#endif /* IMU_ESKF_H */
