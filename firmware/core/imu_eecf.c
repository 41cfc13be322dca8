/**
 * @file imu_eecf.c
 * @brief Enhanced explicit complementary filter (see imu_eecf.h).
 */
#include "imu_eecf.h"

#include "imu_math.h"

/* Defaults. kp, kp_mag and the alignment's are tuned on BROAD (docs/accuracy.md); the
 * others follow from the sensors' data: [seed 000]'s gyroscope (ARW 0.049 deg/sqrt(s);
 * docs/filters.md, Bibliography), the MPU6050's accelerometer (0.02 m/s^2 rms at 100 Hz) and zero-rate offset (+-20 deg/s),
 * the HMC5883L's field noise (0.2 uT on a horizontal field near 19 uT). */
const imu_eecf_settings_t imu_eecf_default_settings = {
    IMU_QCONST(100.0, 16),    /* sample_rate, Hz */
    IMU_QCONST(0.1, 16),      /* kp, 1/s (tuned on BROAD) */
    IMU_QCONST(0.01, 16),     /* kp_mag, 1/s (tuned on BROAD) */
    IMU_QCONST(0.0025, 30),   /* ki, 1/s^2: kp^2 / 4, the critically damped PI loop */
    IMU_QCONST(0.4363, 24),   /* bias_limit, rad/s: 25 deg/s, beyond the MPU6050's +-20 deg/s offset */
    IMU_QCONST(2.0, 16),      /* align_time, s */
    IMU_QCONST(1.0, 16),      /* align_tau, s (tuned on BROAD) */
    IMU_QCONST(0.000025, 30), /* ki_mag, 1/s^2: kp_mag^2 / 4 */
    IMU_QCONST(1.5, 16),      /* rest_time, s (VQF's rest time) */
    IMU_QCONST(0.5, 16),      /* rest_tau, s (VQF's rest low-pass): mean gyro noise 0.05 deg/s */
    IMU_QCONST(0.05236, 24),  /* rest_gyro, rad/s: 3 deg/s, 6 sigma of the gyro noise per sample at 100 Hz */
    IMU_QCONST(0.5, 16),      /* rest_acc, m/s^2 (VQF's): 25 sigma of the accelerometer noise, no motion */
    IMU_REST_TURN,            /* rest_turn, rad: 0.5 deg, 10 sigma of the field mean's direction */
    IMU_QCONST(4.0, 16),      /* rest_kp, 1/s: gyro ARW / accelerometer noise density (8.6e-4 / 2.0e-4) */
    IMU_QCONST(0.8, 16),      /* rest_kp_mag, 1/s: gyro ARW / heading noise density (8.6e-4 / 1.05e-3) */
    IMU_QCONST(0.2, 24),      /* acc_tolerance, m/s^2: 10 sigma of the accelerometer noise */
    IMU_QCONST(20.0, 16),     /* rest_bias_tau, s: ARW / RRW (0.049 deg/sqrt(s) / 0.0024 deg/s/sqrt(s)) */
};

/* Each field with its Q format, unit and accepted range [lo, hi] in the unit. */
#define DESC(field, q, unit, lo, hi) \
    {#field, offsetof(imu_eecf_settings_t, field), q, unit, IMU_QCONST(lo, q), IMU_QCONST(hi, q)}
const imu_setting_desc_t imu_eecf_setting_descs[] = {
    DESC(sample_rate, 16, "Hz", 10.0, IMU_Q16_LARGEST),
    DESC(kp, 16, "1/s", 0.0, 100.0),
    DESC(kp_mag, 16, "1/s", 0.0, 100.0),
    DESC(ki, 30, "1/s^2", 0.0, 1.0),
    DESC(bias_limit, 24, "rad/s", 0.0, 1.0),
    DESC(align_time, 16, "s", 0.0, 60.0),
    DESC(align_tau, 16, "s", 0.0, 10.0),
    DESC(ki_mag, 30, "1/s^2", 0.0, 1.0),
    DESC(rest_time, 16, "s", 0.0, 60.0),
    DESC(rest_tau, 16, "s", 0.0, 10.0),
    DESC(rest_gyro, 24, "rad/s", 0.0, 1.0),
    DESC(rest_acc, 16, "m/s^2", 0.0, 100.0),
    DESC(rest_turn, 30, "rad", 0.0, 0.5),
    DESC(rest_kp, 16, "1/s", 0.0, 100.0),
    DESC(rest_kp_mag, 16, "1/s", 0.0, 100.0),
    DESC(acc_tolerance, 24, "m/s^2", IMU_Q24_SMALLEST, 1.9),
    DESC(rest_bias_tau, 16, "s", 0.0, 1000.0),
};
#undef DESC
const int imu_eecf_setting_count = (int)(sizeof imu_eecf_setting_descs / sizeof imu_eecf_setting_descs[0]);

/** | |acc| - g | beyond 32 m/s^2 (16 of the largest acc_tolerance) has weight 0 anyway:
 *  clamped there, in Q16, so that it fits Q24. */
#define GRAVITY_DEVIATION_CLAMP IMU_QCONST(32.0, 16)

void imu_eecf_init(imu_eecf_t *f)
{
    (void)imu_eecf_set_settings(f, &imu_eecf_default_settings);
}

/**
 * Weight dt / (tau + dt) of a first-order low-pass with time constant tau (s, Q16,
 * at most 1000) sampled every dt (s, Q30, at most 0.1), Q30 in [0, 1].
 *
 * The numerator keeps all of dt's bits (Q30 * 2^16 / Q16 -> Q30, below 2^43 before
 * the division). Rounded to Q16 it would carry the time constant's error: at 5 kHz
 * dt is 13.1 LSB of Q16, rounded to 13, and every low-pass would run 0.8 % slow (at
 * 1 kHz 65.5 LSB, 0.7 % fast), which moves the fixed build's alignment away from the
 * float twin's (docs/filters.md, EECF, fixed point at high sample rates). The
 * denominator's Q16 rounding (at most 2^-17 s) is small beside tau + dt. With tau near
 * zero it may lift the quotient above one: clamped there (the float value is one).
 * dt >= 2^15 (rates below 32768 Hz): the denominator is at least 2.
 */
static imu_q30_t lowpass_weight(imu_q30_t dt, imu_q16_t tau, uint32_t *sat)
{
    const imu_q30_t alpha = IMU_DIV_SAT(dt, IMU_ADD(tau, IMU_SHR(dt, 14)), 16, sat);
    return alpha > IMU_ONE_Q30 ? IMU_ONE_Q30 : alpha;
}

imu_status_t imu_eecf_set_settings(imu_eecf_t *f, const imu_eecf_settings_t *s)
{
    int i;
    if (imu_settings_check(imu_eecf_setting_descs, imu_eecf_setting_count, s) != IMU_OK) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    /* dt = 1 / rate: 2^46 / rate_q16 < 2^31 for rates above 0.5 Hz. */
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations);
    /* Low-pass weights dt / (tau + dt), Q30 (see lowpass_weight). */
    f->align_alpha = lowpass_weight(f->dt, s->align_tau, &f->saturations);
    f->rest_alpha = lowpass_weight(f->dt, s->rest_tau, &f->saturations);
    f->bias_alpha = lowpass_weight(f->dt, s->rest_bias_tau, &f->saturations);
    /* ki (Q30, <= 1) * dt (Q30, <= 0.1) >> 26 -> Q34, at most 0.1 * 2^34 < 2^31. */
    f->ki_dt = IMU_MUL(s->ki, f->dt, 26);
    f->ki_mag_dt = IMU_MUL(s->ki_mag, f->dt, 26);
    /* At most 60 s * 32768 Hz < 2^31 samples. */
    f->align_samples = IMU_MUL_TO_INT(s->align_time, s->sample_rate, 32);
    /* At most 1000 s * 32768 Hz + 1 < 2^25 samples. */
    f->bias_warmup = IMU_MUL_TO_INT(s->rest_bias_tau, s->sample_rate, 32) + 1;
    {
        /* The core's rest detector, every sample, with the turn tests and no rate test: the
         * bias may be as large as the MPU6050's zero-rate offset before it is estimated
         * (imu_eecf.h). rest_tau Q16 -> Q24 (at most 10 s: below 2^28). */
        imu_rest_config_t config;
        config.gyro = s->rest_gyro;
        config.acc = s->rest_acc;
        config.rate = 0;
        config.turn = s->rest_turn;
        config.min_time = s->rest_time;
        config.tau = IMU_SHL_SAT(s->rest_tau, 8, &f->saturations);
        imu_rest_init(&f->rest, &config, f->dt, &f->saturations);
    }
    f->sample_count = 0;
    f->gyr_count = 0;
    f->at_rest = 0;
    f->still_from_start = 1;
    f->gravity = IMU_STANDARD_GRAVITY; /* until the first quiet stretch measures it */
    f->q[0] = IMU_ONE_Q30;
    for (i = 0; i < 3; ++i) {
        f->q[i + 1] = 0;
        f->integral[i] = 0;
        f->align_euler[i] = 0;
        f->gyr_mean[i] = 0;
    }
    return IMU_OK;
}

int imu_eecf_aligning(const imu_eecf_t *f)
{
    return f->sample_count < f->align_samples;
}

int imu_eecf_at_rest(const imu_eecf_t *f)
{
    return f->at_rest;
}

/* ---- Rest detection and the gyroscope mean --------------------------------------- */

/** First-order low-pass y += alpha (x - y) of three values of one Q format: y stays
 *  between its old value and x (alpha in [0, 1]), so the sum cannot overflow. */
static void lowpass3(imu_real_t y[3], const imu_real_t x[3], imu_q30_t alpha, uint32_t *sat)
{
    int k;
    for (k = 0; k < 3; ++k) {
        y[k] = IMU_ADD(y[k], IMU_MUL(alpha, IMU_SUB_SAT(x[k], y[k], sat), 30));
    }
}

/** Running mean (weight 1/(n+1) for the sample after n) while that weighs more than
 *  `alpha`, low-pass with weight alpha after; n + 1 < 2^25 where it divides. */
static imu_q30_t mean_weight(int32_t n, int32_t warmup, imu_q30_t alpha)
{
    if (n < warmup) {
        return IMU_ONE_Q30 / (n + 1); /* 1 / (n + 1) in Q30, truncated: one 32-bit division */
    }
    return alpha;
}

/**
 * The rest detector's decisions for one sample (imu_rest.h; the decisions are all its
 * own), and the gyroscope mean the bias is learnt from. The detector's low-passed rate
 * (time constant rest_tau) is too short an average for the bias: at rest the gyroscope's
 * noise averages down with time, so the mean starts when the detector begins to see the
 * board still (its calm count is 1) and runs over every sample it stays still, a running
 * mean for rest_bias_tau, a low-pass with that time constant after.
 */
static void rest_step(imu_eecf_t *f, const imu_sample_t *s)
{
    int32_t calm;
    int k;
    f->at_rest = imu_rest_update(&f->rest, s->gyr, NULL, s->acc, s->mag, &f->saturations);
    calm = imu_rest_calm(&f->rest);
    if (calm == 0) {
        /* Moving, or gravity or the field turned: the readings held a rotation. */
        f->still_from_start = 0;
    } else if (calm == 1) {
        for (k = 0; k < 3; ++k) {
            f->gyr_mean[k] = s->gyr[k];
        }
        f->gyr_count = 1;
    } else {
        lowpass3(f->gyr_mean, s->gyr, mean_weight(f->gyr_count, f->bias_warmup, f->bias_alpha), &f->saturations);
        if (f->gyr_count < INT32_MAX) {
            ++f->gyr_count;
        }
    }
}

/** Clamp of a wide value to +-limit. */
static imu_wide_t clamp_wide(imu_wide_t v, imu_wide_t limit)
{
    return v > limit ? limit : (v < -limit ? -limit : v);
}

/* ---- Alignment --------------------------------------------------------------------- */

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

/** One alignment step: [seed 004] eq. 4-8. The rest detector saw this sample before. */
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
        /* Gyro propagation (eq. 7) with the raw rates: whether their mean is a bias or
         * a steady rotation is known only at the end (see below). Beyond the seed's
         * small-angle rates, the attitude of the current angles is advanced exactly
         * and read back, so an alignment under motion stays consistent. */
        imu_q30_t theta[3];
        imu_angle_t pred[3];
        for (k = 0; k < 3; ++k) {
            theta[k] = IMU_MUL_SAT(s->gyr[k], f->dt, 24, &f->saturations); /* Q24 * Q30 >> 24 -> rad Q30 */
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
    if (f->sample_count + 1 == f->align_samples && f->still_from_start) {
        /* The rest detector saw the board still through the whole alignment: steady
         * gyroscope and accelerometer, gravity and field unturned. The attitude is then
         * best measured directly: eq. 4-5 on the detector's low-passed specific force and
         * field (time constant rest_tau), free of the gyro bias that the complementary
         * filter integrated. The bias is the detector's to confirm: at the first rest
         * (with the defaults the next sample) the integral takes the mean gyroscope
         * reading of every sample so far. A turntable turning from power-up turns the
         * field, which tells its rate from a bias. After an alignment under motion the
         * complementary filter's angles stand and the integral starts at zero (the
         * first rest or the PI loop finds the bias). */
        if (imu_tilt_from_acc(imu_rest_acc(&f->rest), &f->align_euler[0], &f->align_euler[1])) {
            f->align_euler[2] = imu_heading_from_mag(imu_rest_field(&f->rest), f->align_euler[0], f->align_euler[1]);
        }
    }
    imu_euler_to_quat(f->align_euler, f->q);
}

/* ---- Filtering --------------------------------------------------------------------- */

/** 1 when every axis of a step (rad, Q30) is below 2^-2 rad: small enough for the
 *  first-order prediction of imu_eecf_update. */
static int step_is_small(const imu_q30_t theta[3])
{
    const imu_q30_t small = IMU_QCONST(0.25, 30);
    return theta[0] < small && theta[0] > -small && theta[1] < small && theta[1] > -small && theta[2] < small &&
           theta[2] > -small;
}

/**
 * The heading error mapped to the sensor frame, e = sin(error) up, from the field m (uT,
 * Q16, zero without a magnetometer) measured at the end of the step theta (rad, Q30,
 * each axis below 2^-2 rad), against the attitude before the step turned by it (to first
 * order, as for up). The field in the estimated earth frame has
 * east share h_e and north share h_n; h_e / |h| is the sine of the heading error
 * (eq. 29 with d = (0, |h|, h_z)), scale-free, so the field is not normalised (its Q16
 * keeps 20 bits at 20 uT). Below 1/16 of the field in the horizontal the heading is
 * not observable: e stays zero.
 */
static void heading_error(imu_eecf_t *f, const imu_q16_t mag[3], const imu_q30_t theta[3], const imu_q30_t up[3],
                          imu_q30_t e[3])
{
    imu_q16_t m[3];           /* the field in the frame before the step, Q16 (or Q13, see below) */
    imu_q30_t east[3], north[3];
    imu_q16_t h_e, h_n, h_len; /* in m's format */
    imu_wide_t m2;             /* |m|^2 */
    int k;
    /* Components below 2^28 keep |m| below 2^29 and the turned field below 2^30 (an
     * HMC5883L reads at most 2^26 in Q16); a calibration may scale beyond: then Q13, as
     * only the field's direction counts. */
    const int down = (mag[0] >= (1 << 28) || mag[0] <= -(1 << 28) || mag[1] >= (1 << 28) || mag[1] <= -(1 << 28) ||
                      mag[2] >= (1 << 28) || mag[2] <= -(1 << 28)) ? 3 : 0;
    for (k = 0; k < 3; ++k) {
        m[k] = down != 0 ? IMU_SHR(mag[k], 3) : mag[k];
    }
    {
        const imu_q30_t back[3] = {IMU_NEG_SAT(theta[0], &f->saturations), IMU_NEG_SAT(theta[1], &f->saturations),
                                   IMU_NEG_SAT(theta[2], &f->saturations)};
        imu_vec3_turn_back(m, back); /* exp([theta x]) m: the field in the frame before the step */
    }
    m2 = IMU_WMUL(m[0], m[0]) + IMU_WMUL(m[1], m[1]) + IMU_WMUL(m[2], m[2]); /* below 3 * 2^60 */
    if (m2 == 0) {
        return;
    }
    imu_quat_matrix_row(f->q, 0, east);
    imu_quat_matrix_row(f->q, 1, north);
    /* Rows of R (|row| = 1, Q30) times m >> 30 -> m's format, each below |m| < 2^31. */
    h_e = IMU_ADD(IMU_ADD(IMU_MUL(east[0], m[0], 30), IMU_MUL(east[1], m[1], 30)), IMU_MUL(east[2], m[2], 30));
    h_n = IMU_ADD(IMU_ADD(IMU_MUL(north[0], m[0], 30), IMU_MUL(north[1], m[1], 30)), IMU_MUL(north[2], m[2], 30));
    h_len = imu_hypot(h_e, h_n);
    /* h_len > |m| / 16: h_len^2 > |m|^2 / 256 (a real division in both builds: a shift would be a
     * change of Q format, which the float build leaves out) */
    if (IMU_WMUL(h_len, h_len) > m2 / 256) {
        /* |h_e| <= h_len: quotient within [-1, 1]. */
        const imu_q30_t sin_err = IMU_DIV_SAT(h_e, h_len, 30, &f->saturations);
        for (k = 0; k < 3; ++k) {
            e[k] = IMU_MUL(sin_err, up[k], 30);
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
    imu_q30_t acc_weight = 0; /* weight of the gravity error in the integral, Q30 */
    imu_q16_t acc_norm;       /* |acc|, m/s^2, Q16 */
    const imu_wide_t limit = IMU_WMUL(f->settings.bias_limit, IMU_ONE_Q30); /* Q24 -> Q54, <= 2^54 */
    imu_q16_t kp, kp_mag;     /* proportional gains of this sample, 1/s, Q16 */
    int k;

    rest_step(f, s);
    if (imu_eecf_aligning(f)) {
        align_step(f, s);
        ++f->sample_count;
        return;
    }

    if (f->at_rest) {
        /* At rest the mean gyroscope reading is the bias. Still since initialisation, the
         * mean of every reading so far is all there is to know of it (a 20 deg/s offset
         * is learnt at once): the integral (minus the bias) takes it, Q24 (< 2^31) times
         * 2^30 -> Q54 below 2^61, clamped. After motion the integral (what the PI loop
         * learnt) follows the mean with time constant rest_tau: difference in Q24
         * (saturated), times alpha (Q30, <= 1) -> Q54 below 2^61; the integral is at most
         * 2^54 before: no overflow. */
        for (k = 0; k < 3; ++k) {
            if (f->still_from_start) {
                f->integral[k] = clamp_wide(-IMU_WMUL(f->gyr_mean[k], IMU_ONE_Q30), limit);
            } else {
                const imu_rate_t current = IMU_NARROW(IMU_WSHR(f->integral[k], 30)); /* Q54 -> Q24, |.| <= 2^24 */
                const imu_rate_t diff =
                    IMU_SUB_SAT(IMU_NEG_SAT(f->gyr_mean[k], &f->saturations), current, &f->saturations);
                f->integral[k] = clamp_wide(f->integral[k] + IMU_WMUL(diff, f->rest_alpha), limit);
            }
        }
    }
    if (imu_rest_quiet(&f->rest)) {
        /* No linear acceleration (steady accelerometer, gravity unturned): the
         * attitude follows the accelerometer and magnetometer with the gains for
         * their noise alone, and |acc| is the gravity the integral's weight uses. A
         * slow steady rotation about the vertical may be quiet: it changes nothing
         * of this. */
        kp = f->settings.rest_kp;
        kp_mag = f->settings.rest_kp_mag;
        if (imu_rest_gravity(&f->rest) > 0) { /* zero: no specific force at the reference */
            f->gravity = imu_rest_gravity(&f->rest);
        }
    } else {
        kp = f->settings.kp;
        kp_mag = f->settings.kp_mag;
    }

    /* The gyroscope's step: rate (Q24) times dt (Q30) >> 24 -> rad (Q30). Sample k
     * covers the interval ending at t_k, so the errors are measured against the
     * attitude the step reaches: R_k = R_{k-1} exp([theta x]), to first order up_k =
     * up - theta x up and the field in the earth frame R_k m = R_{k-1} (m + theta x m).
     * One integration then advances by the step and the correction together. The
     * neglected second order, theta^2 / 2 of the errors (5e-5 rad at 1 rad/s and
     * 100 Hz), reaches the attitude scaled by the gains' kp dt. A step beyond 2^-2 rad
     * on an axis is integrated first instead, and the errors measured after it. */
    for (k = 0; k < 3; ++k) {
        theta[k] = IMU_MUL_SAT(s->gyr[k], f->dt, 24, &f->saturations);
    }
    if (!step_is_small(theta)) {
        imu_quat_integrate(f->q, theta);
        theta[0] = theta[1] = theta[2] = 0;
    }
    imu_quat_matrix_row(f->q, 2, up); /* R^T e_z */
    imu_vec3_turn_back(up, theta);    /* |up| <= 1: below 1.5 after */
    if (imu_vec3_normalize(s->acc, unit, &acc_norm)) {
        /* | |acc| - g |, Q16, clamped to 32 m/s^2 (< 2^22), then Q24 (< 2^30). */
        imu_q16_t deviation = IMU_SUB_SAT(acc_norm, f->gravity, &f->saturations);
        imu_vec3_cross(unit, up, e_acc);
        if (deviation > GRAVITY_DEVIATION_CLAMP) {
            deviation = GRAVITY_DEVIATION_CLAMP;
        } else if (deviation < -GRAVITY_DEVIATION_CLAMP) {
            deviation = -GRAVITY_DEVIATION_CLAMP;
        }
        acc_weight = imu_deviation_weight(IMU_SHL_SAT(deviation, 8, &f->saturations), f->settings.acc_tolerance,
                                          &f->saturations);
    }
    heading_error(f, s->mag, theta, up, e_mag);

    for (k = 0; k < 3; ++k) {
        /* Integral, Q54: the errors weighted by the accelerometer's agreement with
         * gravity (Q30 * Q30 >> 30, at most 1 + rounding), times ki dt (Q34, < 2^31)
         * -> Q64 below 2^62, >> 10 -> Q54 below 2^52 per term; |I| <= 2^54 before:
         * no overflow, and the clamp keeps |I| <= bias_limit. */
        const imu_wide_t increment = IMU_WSHR(IMU_WMUL(IMU_MUL(acc_weight, e_acc[k], 30), f->ki_dt), 10) +
                                     IMU_WSHR(IMU_WMUL(IMU_MUL(acc_weight, e_mag[k], 30), f->ki_mag_dt), 10);
        imu_rate_t rate;
        f->integral[k] = clamp_wide(f->integral[k] + increment, limit);
        /* Correction rate kp e_acc + kp_mag e_mag + I; kp (Q16) * e (Q30) >> 22 -> Q24. */
        rate = IMU_MUL_SAT(kp, e_acc[k], 22, &f->saturations);
        rate = IMU_ADD_SAT(rate, IMU_MUL_SAT(kp_mag, e_mag[k], 22, &f->saturations), &f->saturations);
        /* I (Q54, |I| <= 2^54) >> 30 -> Q24, at most 2^24: it fits int32. */
        rate = IMU_ADD_SAT(rate, IMU_NARROW(IMU_WSHR(f->integral[k], 30)), &f->saturations);
        /* rad/s Q24 * s Q30 >> 24 -> rad Q30 (below 2 for |rate| dt < 2), after the gyro's step. */
        theta[k] = IMU_ADD_SAT(theta[k], IMU_MUL_SAT(rate, f->dt, 24, &f->saturations), &f->saturations);
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
        /* Q54 -> Q24, |I| <= 2^54: fits, and its negation too. */
        out->gyro_bias[k] = -IMU_NARROW(IMU_WSHR(f->integral[k], 30));
    }
}
