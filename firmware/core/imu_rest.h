/**
 * @file imu_rest.h
 * @brief Rest detection: is the board lying still?
 *
 * The board is at rest when, for IMU_REST_MIN_TIME, its bias-corrected angular rate
 * stays below IMU_REST_GYRO, and neither the rate nor the specific force departs
 * from its low-passed value (time constant IMU_REST_TAU_Q24) by more than IMU_REST_GYRO
 * and IMU_REST_ACC (the idea of VQF's rest detection: Laidig and Seel, 2023). At rest
 * the gyroscope reads its bias, which a filter can then learn quickly.
 *
 * A constant rotation slower than IMU_REST_GYRO (after the bias estimate) is taken
 * for rest: slower turns than that are not told apart from a bias by the gyroscope.
 */
#ifndef IMU_REST_H
#define IMU_REST_H

#include "imu_arith.h"

/** Thresholds: rate 2 deg/s in rad/s (Q24), specific force 0.5 m/s^2 (Q16), times in s (Q16). */
#define IMU_REST_GYRO IMU_QCONST(0.034906585, 24)
#define IMU_REST_ACC IMU_QCONST(0.5, 16)
#define IMU_REST_MIN_TIME IMU_QCONST(1.5, 16)
#define IMU_REST_TAU_Q24 IMU_QCONST(0.5, 24)

typedef struct {
    imu_rate_t gyr_lp[3]; /**< low-passed angular rate, rad/s, Q24 */
    imu_q16_t acc_lp[3];  /**< low-passed specific force, m/s^2, Q16 */
    imu_q30_t alpha;      /**< low-pass weight per update, period / (tau + period), Q30 */
    int32_t min_updates;  /**< still updates before rest is declared */
    int32_t still;        /**< consecutive still updates so far (stops counting at min_updates) */
    int started;          /**< 0 until the low-passes have their first value */
} imu_rest_t;

/** @brief Start with no history; updates come every `period` s (Q30, below 1 s). */
void imu_rest_init(imu_rest_t *r, imu_q30_t period, uint32_t *sat);

/**
 * @brief One update with a rate (rad/s, Q24), the current bias estimate (rad/s, Q24) and
 *        a specific force (m/s^2, Q16, below 2^29 in magnitude).
 * @return 1 when the board is at rest.
 */
int imu_rest_update(imu_rest_t *r, const imu_rate_t gyr[3], const imu_rate_t bias[3], const imu_q16_t acc[3],
                    uint32_t *sat);

/** @brief The low-passed rate (rad/s, Q24): what the gyroscope reads at rest. */
const imu_rate_t *imu_rest_rate(const imu_rest_t *r);

#endif /* IMU_REST_H */
