/**
 * @file imu_eecf.c
 * @brief Enhanced explicit complementary filter (see imu_eecf.h).
 */
#include "imu_eecf.h"

#include "imu_math.h"

const imu_eecf_settings_t imu_eecf_default_settings = {
    IMU_QCONST(100.0, 16), /* sample_rate, Hz */
    IMU_QCONST(0.1, 16),   /* kp, 1/s (tuned on BROAD, docs/accuracy.md) */
    IMU_QCONST(0.01, 16),  /* kp_mag, 1/s (tuned on BROAD) */
    IMU_QCONST(0.0, 16),   /* ki, 1/s^2 (tuned on BROAD: bias from the still alignment only) */
    IMU_QCONST(0.1745, 24), /* bias_limit, rad/s (10 deg/s) */
    IMU_QCONST(2.0, 16),   /* align_time, s */
    IMU_QCONST(1.0, 16),   /* align_tau, s (tuned on BROAD) */
};

#define DESC(field, q, unit) {#field, offsetof(imu_eecf_settings_t, field), q, unit}
const imu_setting_desc_t imu_eecf_setting_descs[] = {
    DESC(sample_rate, 16, "Hz"), DESC(kp, 16, "1/s"),         DESC(kp_mag, 16, "1/s"),
    DESC(ki, 16, "1/s^2"),       DESC(bias_limit, 24, "rad/s"), DESC(align_time, 16, "s"),
    DESC(align_tau, 16, "s"),
};
#undef DESC
const int imu_eecf_setting_count = (int)(sizeof imu_eecf_setting_descs / sizeof imu_eecf_setting_descs[0]);

/** Largest spread (max - min) of each gyro axis over an alignment at rest: 10 deg/s in rad/s, Q24
 *  (noise of a consumer MEMS gyro, e.g. seed 000: 0.5 deg/s rms at 100 Hz, stays well inside). */
#define STILL_GYRO_SPAN IMU_QCONST(0.17453, 24)

/** Below this horizontal share of the unit field (Q30) the heading is not observable. */
#define MIN_HORIZONTAL_FIELD IMU_QCONST(0.05, 30)

void imu_eecf_init(imu_eecf_t *f)
{
    (void)imu_eecf_set_settings(f, &imu_eecf_default_settings);
}

static int in_range(imu_real_t v, imu_real_t lo, imu_real_t hi)
{
    return v >= lo && v <= hi;
}

imu_status_t imu_eecf_set_settings(imu_eecf_t *f, const imu_eecf_settings_t *s)
{
    imu_q16_t dt_q16;
    int i;
    if (s->sample_rate < IMU_QCONST(10.0, 16) || !in_range(s->kp, 0, IMU_QCONST(100.0, 16)) ||
        !in_range(s->kp_mag, 0, IMU_QCONST(100.0, 16)) || !in_range(s->ki, 0, IMU_QCONST(1.0, 16)) ||
        !in_range(s->bias_limit, 0, IMU_QCONST(1.0, 24)) || !in_range(s->align_time, 0, IMU_QCONST(60.0, 16)) ||
        !in_range(s->align_tau, 0, IMU_QCONST(10.0, 16))) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    /* dt = 1 / rate: 2^46 / rate_q16 < 2^31 for rates above 0.5 Hz. */
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations);
    dt_q16 = IMU_SHR(f->dt, 14);
    /* alpha = dt / (tau + dt) in [0, 1], Q30. */
    f->align_alpha = IMU_DIV_SAT(dt_q16, IMU_ADD(s->align_tau, dt_q16), 30, &f->saturations);
    /* At most 60 s * 32768 Hz < 2^31 samples. */
    f->align_samples = IMU_MUL_TO_INT(s->align_time, s->sample_rate, 32);
    f->sample_count = 0;
    f->q[0] = IMU_ONE_Q30;
    for (i = 0; i < 3; ++i) {
        f->q[i + 1] = 0;
        f->integral[i] = 0;
        f->align_euler[i] = 0;
        f->align_gyro_mean[i] = 0;
        f->align_gyro_min[i] = 0;
        f->align_gyro_max[i] = 0;
    }
    return IMU_OK;
}

int imu_eecf_aligning(const imu_eecf_t *f)
{
    return f->sample_count < f->align_samples;
}

/** Mean of the filled part of a moving-average window (n samples). Each entry is a
 *  sensor value below 2^27 in Q16 (2048 m/s^2 or uT), so the sum of 8 fits. */
static void window_mean(imu_q16_t window[IMU_EECF_AVG_LEN][3], int n, imu_q16_t mean[3], uint32_t *sat)
{
    int i, k;
    for (k = 0; k < 3; ++k) {
        imu_q16_t sum = 0;
        for (i = 0; i < n; ++i) {
            sum = IMU_ADD_SAT(sum, window[i][k], sat);
        }
        mean[k] = sum / n;
    }
}

/** One alignment step: seed 004 eq. 4-8. */
static void align_step(imu_eecf_t *f, const imu_sample_t *s)
{
    const int slot = f->sample_count % IMU_EECF_AVG_LEN;
    const int filled = f->sample_count < IMU_EECF_AVG_LEN ? f->sample_count + 1 : IMU_EECF_AVG_LEN;
    imu_q16_t acc[3], mag[3];
    imu_angle_t meas[3];
    int k;
    for (k = 0; k < 3; ++k) {
        f->acc_window[slot][k] = s->acc[k];
        f->mag_window[slot][k] = s->mag[k];
        if (f->sample_count == 0 || s->gyr[k] < f->align_gyro_min[k]) {
            f->align_gyro_min[k] = s->gyr[k];
        }
        if (f->sample_count == 0 || s->gyr[k] > f->align_gyro_max[k]) {
            f->align_gyro_max[k] = s->gyr[k];
        }
        /* Running mean: the difference of two rates (< 2^31) over the sample number. */
        f->align_gyro_mean[k] = IMU_ADD(f->align_gyro_mean[k],
                                        IMU_SUB_SAT(s->gyr[k], f->align_gyro_mean[k], &f->saturations) /
                                            (f->sample_count + 1));
    }
    window_mean(f->acc_window, filled, acc, &f->saturations);
    window_mean(f->mag_window, filled, mag, &f->saturations);
    if (f->sample_count == 0) {
        /* Start from the measured angles (eq. 7's initial value). */
        meas[0] = meas[1] = 0;
        (void)imu_tilt_from_acc(acc, &meas[0], &meas[1]);
        meas[2] = imu_heading_from_mag(mag, meas[0], meas[1]);
        for (k = 0; k < 3; ++k) {
            f->align_euler[k] = meas[k];
        }
    } else {
        /* Gyro propagation (eq. 7), with the running gyro mean removed (a bias
         * would tilt the angles and, through the tilt compensation, the
         * heading). Beyond the seed's small-angle rates, the attitude of the
         * current angles is advanced exactly and read back, so an alignment
         * under motion stays consistent. */
        imu_q30_t theta[3];
        imu_angle_t pred[3];
        for (k = 0; k < 3; ++k) {
            const imu_rate_t w = IMU_SUB_SAT(s->gyr[k], f->align_gyro_mean[k], &f->saturations);
            theta[k] = IMU_MUL_SAT(w, f->dt, 24, &f->saturations); /* Q24 * Q30 >> 24 -> rad Q30 */
        }
        imu_quat_integrate(f->q, theta); /* f->q holds the quaternion of align_euler */
        imu_quat_to_euler(f->q, pred);
        meas[0] = pred[0];
        meas[1] = pred[1];
        (void)imu_tilt_from_acc(acc, &meas[0], &meas[1]);
        meas[2] = imu_heading_from_mag(mag, pred[0], pred[1]);
        /* Eq. 8: angle = pred + alpha * wrap(meas - pred), alpha in [0, 1]. */
        for (k = 0; k < 3; ++k) {
            const imu_angle_t innovation = imu_angle_diff(meas[k], pred[k]);
            f->align_euler[k] = imu_angle_add(pred[k], IMU_MUL(f->align_alpha, innovation, 30));
        }
    }
    imu_euler_to_quat(f->align_euler, f->q);
    if (f->sample_count + 1 == f->align_samples) {
        /* A board that stayed still (every gyro axis within STILL_GYRO_SPAN)
         * read its bias: start the integral there. After an alignment under
         * motion the mean is no bias estimate, and the integral starts at zero. */
        const imu_q30_t limit = IMU_SHL_SAT(f->settings.bias_limit, 6, &f->saturations);
        int still = 1;
        for (k = 0; k < 3; ++k) {
            still = still && IMU_SUB_SAT(f->align_gyro_max[k], f->align_gyro_min[k], &f->saturations) < STILL_GYRO_SPAN;
        }
        for (k = 0; k < 3 && still; ++k) {
            imu_q30_t integral = IMU_NEG_SAT(IMU_SHL_SAT(f->align_gyro_mean[k], 6, &f->saturations), &f->saturations);
            f->integral[k] = integral > limit ? limit : (integral < -limit ? -limit : integral);
        }
    }
}

void imu_eecf_update(imu_eecf_t *f, const imu_sample_t *s)
{
    imu_q30_t up[3];          /* estimated up direction in the sensor frame, Q30 */
    imu_q30_t unit[3];        /* measured unit vector, Q30 */
    imu_q30_t e_acc[3] = {0, 0, 0}; /* gravity error, rad (small-angle), Q30 */
    imu_q30_t e_mag[3] = {0, 0, 0}; /* heading error mapped to the sensor frame, Q30 */
    imu_q30_t theta[3];       /* rotation vector of this step, rad, Q30 */
    int k;

    if (imu_eecf_aligning(f)) {
        align_step(f, s);
        ++f->sample_count;
        return;
    }

    /* Propagate with the gyroscope first: sample k covers the interval ending at
     * t_k, so the attitude then matches the accelerometer and magnetometer of the
     * same sample. Rate (Q24) times dt (Q30) >> 24 -> rad (Q30). */
    for (k = 0; k < 3; ++k) {
        theta[k] = IMU_MUL_SAT(s->gyr[k], f->dt, 24, &f->saturations);
    }
    imu_quat_integrate(f->q, theta);

    imu_quat_matrix_row(f->q, 2, up); /* R^T e_z */
    if (imu_vec3_normalize(s->acc, unit, 0)) {
        imu_vec3_cross(unit, up, e_acc);
    }
    if (imu_vec3_normalize(s->mag, unit, 0)) {
        /* Field in the estimated earth frame; its east share over its horizontal
         * length is the sine of the heading error (eq. 29 with d = (0, |h|, h_z)). */
        imu_q30_t earth[3], h_len;
        imu_quat_rotate(f->q, unit, earth);
        h_len = imu_hypot(earth[0], earth[1]);
        if (h_len > MIN_HORIZONTAL_FIELD) {
            /* |h_east| <= h_len: quotient within [-1, 1]. */
            const imu_q30_t sin_err = IMU_DIV_SAT(earth[0], h_len, 30, &f->saturations);
            for (k = 0; k < 3; ++k) {
                e_mag[k] = IMU_MUL(sin_err, up[k], 30);
            }
        }
    }

    for (k = 0; k < 3; ++k) {
        /* Integral: e (Q30, |e| <= 2) * ki (Q16) >> 16 -> rad/s^2 Q30; * dt >> 30 -> rad/s Q30. */
        const imu_q30_t e_sum = IMU_ADD_SAT(e_acc[k], e_mag[k], &f->saturations);
        const imu_q30_t limit = IMU_SHL_SAT(f->settings.bias_limit, 6, &f->saturations);
        imu_q30_t integral = IMU_ADD_SAT(
            f->integral[k], IMU_MUL_SAT(IMU_MUL_SAT(e_sum, f->settings.ki, 16, &f->saturations), f->dt, 30, &f->saturations),
            &f->saturations);
        imu_rate_t rate;
        if (integral > limit) {
            integral = limit;
        } else if (integral < -limit) {
            integral = -limit;
        }
        f->integral[k] = integral;
        /* Correction rate kp e_acc + kp_mag e_mag + I; kp (Q16) * e (Q30) >> 22 -> Q24. */
        rate = IMU_MUL_SAT(f->settings.kp, e_acc[k], 22, &f->saturations);
        rate = IMU_ADD_SAT(rate, IMU_MUL_SAT(f->settings.kp_mag, e_mag[k], 22, &f->saturations), &f->saturations);
        rate = IMU_ADD_SAT(rate, IMU_SHR(integral, 6), &f->saturations);
        /* rad/s Q24 * s Q30 >> 24 -> rad Q30 (below 2 for |rate| dt < 2). */
        theta[k] = IMU_MUL_SAT(rate, f->dt, 24, &f->saturations);
    }
    imu_quat_integrate(f->q, theta);
}

void imu_eecf_get(const imu_eecf_t *f, imu_output_t *out)
{
    int k;
    for (k = 0; k < 4; ++k) {
        out->quat[k] = f->q[k];
    }
    imu_quat_to_euler(f->q, out->euler);
    for (k = 0; k < 3; ++k) {
        out->gyro_bias[k] = -IMU_SHR(f->integral[k], 6);
    }
}
