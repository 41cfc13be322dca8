/**
 * @file imu_rest.c
 * @brief Rest detection (see imu_rest.h).
 */
#include "imu_rest.h"

void imu_rest_init(imu_rest_t *r, imu_q30_t period, uint32_t *sat)
{
    int k;
    /* period / (tau + period) in [0, 1]: Q30 * 2^24 / Q24 -> Q30 (the numerator keeps all its bits). */
    r->alpha = IMU_DIV_SAT(period, IMU_ADD(IMU_REST_TAU_Q24, IMU_SHR(period, 6)), 24, sat);
    /* min_time / period: Q16 * 2^30 / Q30 -> Q16 (below 2^15 updates for periods above 46 us). */
    r->min_updates = IMU_TO_INT(IMU_DIV_SAT(IMU_REST_MIN_TIME, period, 30, sat), 16);
    r->still = 0;
    r->started = 0;
    for (k = 0; k < 3; ++k) {
        r->gyr_lp[k] = 0;
        r->acc_lp[k] = 0;
    }
}

/** 1 when every |v_k| < limit and |v|^2 < limit^2 (v and limit in the same Q format, limit below 2^24). */
static int shorter_than(const imu_real_t v[3], imu_real_t limit)
{
    imu_wide_t sum = 0;
    int k;
    for (k = 0; k < 3; ++k) {
        if (v[k] >= limit || v[k] <= -limit) {
            return 0;
        }
        sum += IMU_WMUL(v[k], v[k]); /* below 2^48 each */
    }
    return sum < IMU_WMUL(limit, limit);
}

int imu_rest_update(imu_rest_t *r, const imu_rate_t gyr[3], const imu_rate_t bias[3], const imu_q16_t acc[3],
                    uint32_t *sat)
{
    imu_rate_t gyr_dev[3], corrected[3];
    imu_q16_t acc_dev[3];
    int k;
    if (!r->started) {
        for (k = 0; k < 3; ++k) {
            r->gyr_lp[k] = gyr[k];
            r->acc_lp[k] = acc[k];
        }
        r->started = 1;
    }
    for (k = 0; k < 3; ++k) {
        gyr_dev[k] = IMU_SUB_SAT(gyr[k], r->gyr_lp[k], sat);
        acc_dev[k] = IMU_SUB(acc[k], r->acc_lp[k]); /* both below 2^29 */
        /* The low-passes stay between their inputs: no overflow. */
        r->gyr_lp[k] = IMU_ADD(r->gyr_lp[k], IMU_MUL(r->alpha, gyr_dev[k], 30));
        r->acc_lp[k] = IMU_ADD(r->acc_lp[k], IMU_MUL(r->alpha, acc_dev[k], 30));
        corrected[k] = IMU_SUB_SAT(r->gyr_lp[k], bias[k], sat);
    }
    if (shorter_than(gyr_dev, IMU_REST_GYRO) && shorter_than(corrected, IMU_REST_GYRO) &&
        shorter_than(acc_dev, IMU_REST_ACC)) {
        if (r->still < r->min_updates) {
            ++r->still;
        }
    } else {
        r->still = 0;
    }
    return r->still >= r->min_updates;
}

const imu_rate_t *imu_rest_rate(const imu_rest_t *r)
{
    return r->gyr_lp;
}
