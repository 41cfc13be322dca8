/**
 * @file imu_rest.c
 * @brief Rest detection (see imu_rest.h).
 */
#include "imu_rest.h"

#include <stddef.h>

#include "imu_math.h"

const imu_rest_config_t imu_rest_default_config = {
    IMU_REST_GYRO,     /* gyro, rad/s */
    IMU_REST_ACC,      /* acc, m/s^2 */
    IMU_REST_GYRO,     /* rate, rad/s: the rate test */
    IMU_REST_TURN,     /* turn, rad: the turn tests */
    IMU_REST_MIN_TIME, /* min_time, s */
    IMU_REST_TAU_Q24,  /* tau, s */
};

void imu_rest_init(imu_rest_t *r, const imu_rest_config_t *config, imu_q30_t period, uint32_t *sat)
{
    int k;
    r->gyro = config->gyro;
    r->acc = config->acc;
    r->rate = config->rate;
    r->turn = config->turn;
    /* period / (tau + period) in [0, 1]: Q30 * 2^24 / Q24 -> Q30 (the numerator keeps all its
     * bits). With tau near zero the denominator's rounding may lift it above one: clamped
     * there (the float value is one). */
    r->alpha = IMU_DIV_SAT(period, IMU_ADD(config->tau, IMU_SHR(period, 6)), 24, sat);
    if (r->alpha > IMU_ONE_Q30) {
        r->alpha = IMU_ONE_Q30;
    }
    /* min_time / period: Q16 * 2^22 / Q30 -> Q8, below 2^29 (60 s at 2^15 updates per s),
     * rounded to an integer. Truncated to Q8 or to Q16 before the rounding, the quotient
     * rounds to the same integer (x >= n + 1/2 exactly when its truncation is). */
    r->min_updates = IMU_TO_INT(IMU_DIV_SAT(config->min_time, period, 22, sat), 8);
    /* tau / period: Q24 * 2^14 / Q30 -> Q8, below 2^27 (10 s at 2^15 updates per s). */
    r->settle = IMU_TO_INT(IMU_DIV_SAT(config->tau, period, 14, sat), 8);
    r->still = 0;
    r->acc_count = 0;
    r->mag_count = 0;
    r->calm = 0;
    r->started = 0;
    r->acc_limit = 0;
    r->mag_limit = 0;
    r->acc_norm = 0;
    for (k = 0; k < 3; ++k) {
        r->gyr_lp[k] = 0;
        r->acc_lp[k] = 0;
        r->mag_lp[k] = 0;
        r->acc_ref[k] = 0;
        r->mag_ref[k] = 0;
    }
}

/** 1 when every |v_k| < limit and |v|^2 < limit^2 (v and limit in the same Q format, limit
 *  below 2^30: the sum of the three squares stays below 2^62). */
static int shorter_than(const imu_real_t v[3], imu_real_t limit)
{
    imu_wide_t sum = 0;
    int k;
    for (k = 0; k < 3; ++k) {
        if (v[k] >= limit || v[k] <= -limit) {
            return 0;
        }
        sum += IMU_WMUL(v[k], v[k]); /* below 2^60 each */
    }
    return sum < IMU_WMUL(limit, limit);
}

/** 1 when |a - b| <= limit (a, b and limit in one Q format, 0 <= limit < 2^30): a turn test.
 *  A limit of zero (a zero reference: no magnetometer) holds while the vector stays zero. */
static int turned_within(const imu_real_t a[3], const imu_real_t b[3], imu_real_t limit, uint32_t *sat)
{
    imu_wide_t sum = 0;
    int k;
    for (k = 0; k < 3; ++k) {
        const imu_real_t d = IMU_SUB_SAT(a[k], b[k], sat);
        if (d > limit || d < -limit) {
            return 0;
        }
        sum += IMU_WMUL(d, d); /* below 2^60 each */
    }
    return sum <= IMU_WMUL(limit, limit);
}

/** A new turn reference: the low-passed vector now, its turn limit |v| turn (Q16 |v| times
 *  Q30 turn <= 0.5 >> 30 -> Q16, below 2^30) and its length. Returns |v| (0 for zero). */
static imu_q16_t take_reference(imu_q16_t ref[3], const imu_q16_t lp[3], imu_q30_t turn, imu_q16_t *limit)
{
    imu_real_t norm = 0;
    int k;
    for (k = 0; k < 3; ++k) {
        ref[k] = lp[k];
    }
    if (!imu_vec3_normalize(ref, NULL, &norm)) {
        norm = 0;
    }
    *limit = IMU_MUL(norm, turn, 30);
    return norm;
}

/** Saturating count up (the counts stop below 2^31 - 1). */
static int32_t count_up(int32_t n)
{
    return n < INT32_MAX - 1 ? n + 1 : n;
}

/** The turn tests of one steady update (the low-passes already hold it). Returns 0 when
 *  either vector turned beyond its limit (it then has a new reference). */
static int turn_tests(imu_rest_t *r, uint32_t *sat)
{
    int held = 1;
    if (r->still == r->settle + 1) {
        /* Steady for tau: the low-passes have settled on this stretch. */
        r->acc_norm = take_reference(r->acc_ref, r->acc_lp, r->turn, &r->acc_limit);
        (void)take_reference(r->mag_ref, r->mag_lp, r->turn, &r->mag_limit);
        r->acc_count = 0;
        r->mag_count = 0;
    } else if (r->still > r->settle + 1) {
        /* Gravity turned: a slow rotation about a horizontal axis, or a steady acceleration
         * began. The field turned: a slow rotation, or the field changed. */
        if (turned_within(r->acc_lp, r->acc_ref, r->acc_limit, sat)) {
            r->acc_count = count_up(r->acc_count);
        } else {
            r->acc_norm = take_reference(r->acc_ref, r->acc_lp, r->turn, &r->acc_limit);
            r->acc_count = 0;
            held = 0;
        }
        if (turned_within(r->mag_lp, r->mag_ref, r->mag_limit, sat)) {
            r->mag_count = count_up(r->mag_count);
        } else {
            (void)take_reference(r->mag_ref, r->mag_lp, r->turn, &r->mag_limit);
            r->mag_count = 0;
            held = 0;
        }
    }
    return held;
}

int imu_rest_update(imu_rest_t *r, const imu_rate_t gyr[3], const imu_rate_t bias[3], const imu_q16_t acc[3],
                    const imu_q16_t mag[3], uint32_t *sat)
{
    imu_rate_t gyr_dev[3];
    imu_q16_t acc_dev[3];
    int steady;
    int k;
    if (!r->started) {
        for (k = 0; k < 3; ++k) {
            r->gyr_lp[k] = gyr[k];
            r->acc_lp[k] = acc[k];
            if (r->turn > 0) {
                r->mag_lp[k] = mag[k];
            }
        }
        r->started = 1;
    }
    for (k = 0; k < 3; ++k) {
        gyr_dev[k] = IMU_SUB_SAT(gyr[k], r->gyr_lp[k], sat);
        acc_dev[k] = IMU_SUB(acc[k], r->acc_lp[k]); /* both below 2^29 */
        /* The low-passes stay between their inputs: no overflow. */
        r->gyr_lp[k] = IMU_ADD(r->gyr_lp[k], IMU_MUL(r->alpha, gyr_dev[k], 30));
        r->acc_lp[k] = IMU_ADD(r->acc_lp[k], IMU_MUL(r->alpha, acc_dev[k], 30));
    }
    steady = shorter_than(gyr_dev, r->gyro) && shorter_than(acc_dev, r->acc);
    if (steady && r->rate > 0) {
        imu_rate_t corrected[3];
        for (k = 0; k < 3; ++k) {
            corrected[k] = IMU_SUB_SAT(r->gyr_lp[k], bias[k], sat);
        }
        steady = shorter_than(corrected, r->rate);
    }
    if (r->turn > 0) {
        for (k = 0; k < 3; ++k) {
            /* A calibrated field may exceed 2^29: the difference saturates, and the low-pass
             * still stays between its inputs. */
            r->mag_lp[k] = IMU_ADD(r->mag_lp[k], IMU_MUL(r->alpha, IMU_SUB_SAT(mag[k], r->mag_lp[k], sat), 30));
        }
    }
    if (!steady) {
        /* The counts restart with the next steady stretch (the references too). */
        r->still = 0;
        r->acc_count = 0;
        r->mag_count = 0;
        r->calm = 0;
        return 0;
    }
    r->still = count_up(r->still);
    if (r->turn > 0 && !turn_tests(r, sat)) {
        r->calm = 0;
    } else {
        r->calm = count_up(r->calm);
    }
    return r->still >= r->min_updates &&
           (r->turn == 0 || (r->acc_count >= r->min_updates && r->mag_count >= r->min_updates));
}

const imu_rate_t *imu_rest_rate(const imu_rest_t *r)
{
    return r->gyr_lp;
}

imu_q30_t imu_rest_rate_noise_share(const imu_rest_t *r, uint32_t *sat)
{
    return imu_lowpass_noise_share(r->alpha, sat);
}

const imu_q16_t *imu_rest_acc(const imu_rest_t *r)
{
    return r->acc_lp;
}

const imu_q16_t *imu_rest_field(const imu_rest_t *r)
{
    return r->mag_lp;
}

imu_q16_t imu_rest_gravity(const imu_rest_t *r)
{
    return r->acc_norm;
}

int imu_rest_quiet(const imu_rest_t *r)
{
    /* still > 0: the last update was steady (with min_time 0, as soon as it is). */
    return r->still > 0 && r->still >= r->min_updates && (r->turn == 0 || r->acc_count >= r->min_updates);
}

int imu_rest_unturned(const imu_rest_t *r)
{
    /* calm counts from the update after a failed test (which took a new reference) or
     * from the steady stretch's start (the references come settle + 1 updates into it) */
    return r->turn > 0 && r->calm > r->settle + 1;
}

int32_t imu_rest_calm(const imu_rest_t *r)
{
    return r->calm;
}
