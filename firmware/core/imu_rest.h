/**
 * @file imu_rest.h
 * @brief Rest detection: is the board lying still? One detector for every filter.
 *
 * The board is *steady* while neither the angular rate nor the specific force departs
 * from its low-passed value (time constant `tau`) by more than `gyro` and `acc` (the idea
 * of VQF's rest detection: Laidig and Seel, 2023). At rest the gyroscope reads its bias,
 * which a filter can then learn quickly. A steady rotation is steady too; the detector
 * tells it from a bias by one of two tests, each filter choosing by its configuration:
 *
 *  - the *rate test* (`rate` > 0): the low-passed rate minus the filter's bias estimate
 *    stays below `rate`. A constant rotation slower than that (after the bias estimate)
 *    is taken for rest; a zero-rate offset beyond it that the filter has not yet
 *    estimated is never taken for rest.
 *  - the *turn tests* (`turn` > 0): a rotation turns gravity or the field in the sensor
 *    frame, an offset does not. Once the board has been steady for `tau` (the low-passes
 *    have settled), the low-passed specific force and field are taken as references; a
 *    turn of either beyond `turn` (rad) takes a new reference and restarts that test's
 *    count. So a zero-rate offset of any size is taken for what it is (the MPU6050's
 *    may reach 20 deg/s), and a rotation slower than about turn / (min_time sin(angle
 *    between axis and field)) passes for rest: 0.85 deg/s about the vertical at 67 deg
 *    dip with the EECF's defaults (0.5 deg in 1.5 s). The EECF's choice.
 *
 * The ESKF takes both (imu_rest_default_config): the rate test keeps a large unestimated
 * offset from being learnt as a bias at once, and the turn tests keep a slow steady
 * rotation (a turntable, a boat's swing) from being learnt as one at all (with the rate
 * test alone, tools/eval_rough.py's `slow-turn` left it 8.9 deg of heading RMS, with both
 * 0.27 deg).
 *
 * At rest: steady, and each test configured held, for `min_time`. *Quiet*: steady and
 * gravity unturned for `min_time` (the field may turn: a slow rotation about the vertical,
 * but no linear acceleration); without turn tests quiet is at rest.
 *
 * The decisions depend on the sensor readings (and the bias estimate for the rate test)
 * alone, so a fixed build and its float twin take the same ones except within rounding
 * of a limit. The detector runs once per update, at any period below 1 s: the EECF
 * updates it every sample, the ESKF once per three-sample group (on the group means).
 */
#ifndef IMU_REST_H
#define IMU_REST_H

#include "imu_arith.h"

/** The ESKF's thresholds (imu_rest_default_config): rate 2 deg/s in rad/s (Q24), specific
 *  force 0.5 m/s^2 (Q16), turn 0.5 deg in rad (Q30: 10 sigma of the field mean's
 *  direction), times in s (Q16, and the low-pass's in Q24). */
#define IMU_REST_GYRO IMU_QCONST(0.034906585, 24)
#define IMU_REST_ACC IMU_QCONST(0.5, 16)
#define IMU_REST_TURN IMU_QCONST(0.008727, 30)
#define IMU_REST_MIN_TIME IMU_QCONST(1.5, 16)
#define IMU_REST_TAU_Q24 IMU_QCONST(0.5, 24)

/** A filter's thresholds (copied at init). */
typedef struct {
    imu_rate_t gyro;    /**< largest deviation of the rate from its low-pass, rad/s, Q24, [0, 1]; 0: never at rest */
    imu_q16_t acc;      /**< largest deviation of the specific force from its low-pass, m/s^2, Q16, [0, 100] */
    imu_rate_t rate;    /**< rate test: largest bias-corrected low-passed rate, rad/s, Q24, [0, 1]; 0: no rate test */
    imu_q30_t turn;     /**< turn tests: largest turn of the low-passed specific force and field, rad, Q30,
                             [0, 0.5]; 0: no turn tests */
    imu_q16_t min_time; /**< time the tests must hold, s, Q16, [0, 60] */
    imu_rate_t tau;     /**< time constant of the low-passes, s, Q24, [0, 10] */
} imu_rest_config_t;

/** The ESKF's configuration: IMU_REST_GYRO and IMU_REST_ACC, the rate test at IMU_REST_GYRO,
 *  the turn tests at IMU_REST_TURN, IMU_REST_MIN_TIME, IMU_REST_TAU_Q24. */
extern const imu_rest_config_t imu_rest_default_config;

/** State: 30 members of 32 bits, so that it holds no implicit padding wherever a filter's
 *  checkpointed state embeds it (keep the count even). */
typedef struct {
    imu_rate_t gyro;       /**< config.gyro, rad/s, Q24 */
    imu_q16_t acc;         /**< config.acc, m/s^2, Q16 */
    imu_rate_t rate;       /**< config.rate, rad/s, Q24 */
    imu_q30_t turn;        /**< config.turn, rad, Q30 */
    imu_rate_t gyr_lp[3];  /**< low-passed angular rate, rad/s, Q24 */
    imu_q16_t acc_lp[3];   /**< low-passed specific force, m/s^2, Q16 */
    imu_q16_t mag_lp[3];   /**< low-passed field, uT, Q16 (turn tests only) */
    imu_q16_t acc_ref[3];  /**< the specific force's turn reference, m/s^2, Q16 */
    imu_q16_t mag_ref[3];  /**< the field's turn reference, uT, Q16 */
    imu_q16_t acc_limit;   /**< |acc_ref| turn, m/s^2, Q16 (0 for a zero reference: never fails) */
    imu_q16_t mag_limit;   /**< |mag_ref| turn, uT, Q16 */
    imu_q16_t acc_norm;    /**< |acc_ref|, m/s^2, Q16 (0 before the first reference) */
    imu_q30_t alpha;       /**< low-pass weight per update, period / (tau + period), Q30 */
    int32_t min_updates;   /**< updates the tests must hold before rest is declared */
    int32_t settle;        /**< steady updates before the turn references are taken: tau / period */
    int32_t still;         /**< consecutive steady updates so far (saturates below 2^31 - 1) */
    int32_t acc_count;     /**< updates since the specific force's reference (saturates) */
    int32_t mag_count;     /**< updates since the field's reference (saturates) */
    int32_t calm;          /**< consecutive updates in which no test failed (saturates) */
    int32_t started;       /**< 0 until the low-passes have their first value */
} imu_rest_t;

/** @brief Start with no history and the thresholds of `config`; updates come every
 *         `period` s (Q30, below 1 s, at least 2^-15 s). */
void imu_rest_init(imu_rest_t *r, const imu_rest_config_t *config, imu_q30_t period, uint32_t *sat);

/**
 * @brief One update with a rate (rad/s, Q24), the filter's bias estimate (rad/s, Q24; may
 *        be NULL without the rate test), a specific force (m/s^2, Q16) and a field (uT,
 *        Q16; may be NULL without the turn tests), the sensor values each below 2^29 in
 *        magnitude.
 * @return 1 when the board is at rest.
 */
int imu_rest_update(imu_rest_t *r, const imu_rate_t gyr[3], const imu_rate_t bias[3], const imu_q16_t acc[3],
                    const imu_q16_t mag[3], uint32_t *sat);

/** @brief The low-passed rate (rad/s, Q24): what the gyroscope reads at rest. */
const imu_rate_t *imu_rest_rate(const imu_rest_t *r);

/** @brief The low-passed rate's steady noise variance over one update's rate's
 *         (imu_lowpass_noise_share), Q30 in (0, 1]. */
imu_q30_t imu_rest_rate_noise_share(const imu_rest_t *r, uint32_t *sat);

/** @brief The low-passed specific force (m/s^2, Q16) and field (uT, Q16; zero without turn
 *         tests): at rest, gravity and the field in the sensor frame. */
const imu_q16_t *imu_rest_acc(const imu_rest_t *r);
const imu_q16_t *imu_rest_field(const imu_rest_t *r);

/** @brief |specific force| (m/s^2, Q16) at the turn test's reference: while quiet, the local
 *         gravity (0 before the first reference, or without turn tests). */
imu_q16_t imu_rest_gravity(const imu_rest_t *r);

/** @brief 1 while quiet (see above): after the last update, as imu_rest_update's result. */
int imu_rest_quiet(const imu_rest_t *r);

/** @brief 1 when the turn tests (configured) took their references before the last update
 *         and held them up to it: no rotation beyond `turn` since then. */
int imu_rest_unturned(const imu_rest_t *r);

/** @brief Consecutive updates, up to the last one, in which no test failed (0: it failed):
 *         how long the board has been seen still. Saturates below 2^31 - 1. */
int32_t imu_rest_calm(const imu_rest_t *r);

#endif /* IMU_REST_H */
