/**
 * @file imu_eskf.h
 * @brief 9-state error-state Kalman filter (seed 000), with its gaps fixed.
 *
 * Error state x = [dtheta (3), dbg (3), dba (3)]: attitude error angle in the
 * sensor frame (rad; twice the seed's error-quaternion vector part, true =
 * estimate (x) exp(dtheta)), gyro bias error (rad/s), accelerometer bias error (in
 * units of g, so that every measurement coefficient is at most 1).
 *
 * Propagation (eq. 15-16): gyro samples are consumed three at a time; their
 * bias-corrected increments (each limited to 1 rad: a sample rate far too low for the
 * motion) form the three-sample rotation vector
 * phi = t1 + t2 + t3 + 33/80 t1 x t3 + 57/80 t2 x (t3 - t1) (up to 5.3 rad, kept wide),
 * and q <- q (x) exp(phi).
 * The filter (covariance and measurements) therefore runs at a third of the
 * sensor rate, whatever that rate is (a sensor rate that is not a multiple of
 * three gives a non-integer filter rate, which is fine: T = 3 / sample_rate).
 * Between filter steps the output is the attitude propagated by the increments
 * received so far, so every sample has an up-to-date estimate; an incomplete
 * group at the end of a stream is simply not yet fused.
 *
 * Covariance (eq. 17-18): Phi = [[R(phi)^T, -T I, 0], [0, I, 0], [0, 0, I]], the exact
 * transition of the attitude error (the seed's first-order I - [phi x] inflates the
 * variance step after step in fast rotation), and Q = diag(arw^2, rrw^2, acc_bias_rw^2) T,
 * the Allan-variance
 * angle random walk and rate random walk directly; the seed's
 * Gamma = (I + T F) G T adds only terms of order T^2 to this Q, dropped here.
 * Stored in block-floating form (imu_cov.h); the attitude variances are kept below
 * 1 rad^2 (imu_cov_cap_unit_variance).
 *
 * Measurements (eq. 8-9), as sequential scalar updates (no matrix inverse):
 * - gravity: a / g = v + [v x] dtheta + ba, where v is the estimated up direction
 *   in the sensor frame, read along the estimated east and north and (9 states) as
 *   the norm of a / g - ba, which does not depend on the attitude. The accelerometer bias is
 *   observable through rotations (it is not in the seed's H); it can be switched
 *   off (`estimate_acc_bias` = 0: 6 states).
 * - heading: the east share of the unit magnetic field in the estimated earth
 *   frame, z = m_E, with H = [m_N v^T - m_U n^T, 0, 0] (n the estimated north): the
 *   heading error and the tilt about north that the field's vertical part turns
 *   into east. The seed's 2[m x] would let the magnetometer tilt roll and pitch;
 *   here it never does: a gain map (imu_cov_update) lets this update correct only
 *   the vertical components of the attitude and the gyro bias, and P, in Joseph's
 *   form for that gain, keeps the tilt's uncertainty.
 * - rest (imu_rest.h): the low-passed rate measures the gyro bias; at rest gravity
 *   and the field correct everything but the gyro bias and the rest measurement the
 *   gyro bias alone (the same gyroscope noise drives the attitude they observe).
 * Gravity is measured from the specific force low-passed in the estimated earth
 * frame (time constant acc_lowpass): rotations do not change gravity there, while
 * the accelerations of a back-and-forth translation average out.
 * Robustness: a specific-force norm away from g (taps, translation, free fall) and
 * a field whose norm or dip departs from the reference (a magnet nearby)
 * down-weight their measurement smoothly: w = 1 / (1 + d^2)^2 with d the
 * deviation over its tolerance; the effective variance is R / w. The reference
 * field is acquired from the first plausible field (5-500 uT, unclipped, with a
 * horizontal share; an HMC5883L reads zeros before its first conversion: the heading
 * is then aligned when the first plausible field comes); its norm and dip are learnt
 * during the next 10 s (time constant 1 s: one sample's noise and an unconverged
 * attitude), then follow slow changes (time constant 30 s) while the field is
 * undisturbed. A disturbed field that keeps one norm and dip in the earth frame for
 * 20 s while the board turns (faster than 20 deg/s) is fixed to the earth, not to the
 * board: it becomes the new reference.
 *
 * Rest (imu_rest.h): when the board lies still, the gyroscope reads its bias; the
 * low-passed rate is then a measurement of the bias states (variance arw^2 / T).
 *
 * A sensor at its register limit is not trusted: a clipped accelerometer or
 * magnetometer skips its update for that step; after a clipped gyroscope (an
 * unknown part of the rotation lost, possibly half a turn) the attitude is
 * re-aligned from gravity and the field at the first step whose specific force is
 * within acc_tolerance of g, with the initial attitude uncertainty.
 *
 * After each filter step the error is injected (q <- q (x) exp(dtheta), dtheta
 * limited to 1 rad; biases += their errors) and the error state restarts at zero; the
 * next prediction turns P by that correction as well as by the step's rotation.
 *
 * Inputs beyond 1024 m/s^2 or 1024 uT (beyond every MPU6050 and HMC5883L range; only
 * scale settings no real sensor has produce them) are clamped and count as clipped.
 */
#ifndef IMU_ESKF_H
#define IMU_ESKF_H

#include "imu_common.h"
#include "imu_cov.h"
#include "imu_rest.h"
#include "imu_sensor.h"

/** Settings. All fields are imu_real_t: Q format in the fixed build as written. */
typedef struct {
    imu_real_t sample_rate;        /**< sensor rate (filter rate x 3), Hz, Q16, [30, 32767] */
    imu_real_t gyro_arw;           /**< gyro angle random walk, rad/sqrt(s), Q32, [0, 0.49] */
    imu_real_t gyro_rrw;           /**< gyro rate random walk, rad/s/sqrt(s), Q40, [0, 1.9e-3] */
    imu_real_t acc_bias_rw;        /**< accelerometer bias random walk, m/s^2/sqrt(s), Q32, [0, 0.49] */
    imu_real_t acc_noise;          /**< specific-force noise per filter step, m/s^2, Q24, [1e-3, 100] */
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
    imu_wide_t process_var[9];    /**< per-step process noise, Q64: rad^2, (rad/s)^2, g^2 */
    int initialised;              /**< 0 until the first sample set the attitude */
    int in_group;                 /**< gyro increments buffered in the current group, 0..2 */
    unsigned clipped;             /**< IMU_CLIPPED_* bits seen in the current group */
    int realign;                  /**< 1 after a clipped gyroscope, until the next calm step re-aligns */
    int32_t steps;                /**< filter steps so far (counts up to learn_steps) */
    int32_t learn_steps;          /**< filter steps of the magnetic dip learning phase */
    imu_q30_t increments[3][3];   /**< bias-corrected gyro increments of the group, rad, Q30 */
    imu_q16_t acc_sum[3];         /**< sum of the group's specific force, m/s^2, Q16 */
    imu_real_t gyr_sum[3];        /**< sum of the group's angular rate, rad/s, Q22 (three times 128 rad/s fit) */
    imu_rest_t rest;              /**< rest detection on the group means */
    int at_rest;                  /**< 1 when the last filter step was at rest */
    imu_wide_t rest_var;          /**< variance of the rest measurement of the bias, (rad/s)^2, Q48 */
    imu_q16_t mag_sum[3];         /**< sum of the group's magnetic field, uT, Q16 */
    imu_q30_t q[4];               /**< attitude at the last filter step, Q30 */
    imu_q30_t q_out[4];           /**< attitude at the last sample, Q30 */
    imu_q30_t injected[4];        /**< the last correction's rotation exp(dtheta), Q30 (see filter_step) */
    imu_q30_t gyro_bias[3];       /**< rad/s, Q30 */
    imu_q30_t acc_bias[3];        /**< in units of g, Q30 */
    imu_eskf_field_t ref;         /**< reference field; norm 0: none yet */
    imu_eskf_field_t cand;        /**< candidate reference field while disturbed; norm 0: none */
    int32_t cand_steps;           /**< turning filter steps the candidate has held */
    int32_t new_field_steps;      /**< filter steps of NEW_FIELD_TIME */
    int turning;                  /**< 1 when the last filter step turned faster than 20 deg/s */
    imu_q30_t acc_alpha;          /**< low-pass weight T / (acc_lowpass + T), Q30 */
    imu_wide_t acc_earth[3];      /**< low-passed specific force in the estimated earth frame, m/s^2, Q46:
                                       a step of the low-pass or of a correction's turn is a fraction of a
                                       Q16 LSB at high rates, and such rounding errors repeat step after step */
    int acc_earth_valid;          /**< 0 until the low-pass has its first value */
    imu_q30_t acc_weight;         /**< weight of the last gravity update, Q30 */
    imu_q30_t mag_weight;         /**< weight of the last heading update, Q30 */
    imu_cov_t cov;                /**< error-state covariance */
    uint32_t saturations;         /**< saturation events since initialisation */
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
