/**
 * @file imu_eskf.c
 * @brief 9-state error-state Kalman filter (see imu_eskf.h).
 */
#include "imu_eskf.h"

#include "imu_math.h"

enum { ATT = 0, GYRO_BIAS = 3, ACC_BIAS = 6 };

/* Defaults: seed 000's angle random walk; the rest chosen on the BROAD trials
 * (one set for all, docs/accuracy.md): a rate random walk below seed 000's (its
 * 520 deg/h^1.5 makes the bias wander faster than MEMS parts of the GY-86 class
 * do), no accelerometer-bias states (without rotation they absorb translation
 * accelerations, docs/filters.md). */
const imu_eskf_settings_t imu_eskf_default_settings = {
    IMU_QCONST(100.0, 16),    /* sample_rate, Hz */
    IMU_QCONST(8.7e-4, 32),   /* gyro_arw, rad/sqrt(s) (seed 000 table 1: 3 deg/sqrt(h)) */
    IMU_QCONST(1e-5, 40),     /* gyro_rrw, rad/s/sqrt(s) (124 deg/h^1.5) */
    IMU_QCONST(1e-4, 32),     /* acc_bias_rw, m/s^2/sqrt(s) */
    IMU_QCONST(0.3, 24),      /* acc_noise, m/s^2 */
    IMU_QCONST(1.0, 16),      /* mag_noise, uT */
    IMU_QCONST(0.1, 28),      /* init_attitude_std, rad */
    IMU_QCONST(0.01, 30),     /* init_gyro_bias_std, rad/s */
    IMU_QCONST(0.1, 24),      /* init_acc_bias_std, m/s^2 */
    IMU_QCONST(0.0, 0),       /* estimate_acc_bias */
    IMU_QCONST(9.80665, 24),  /* gravity, m/s^2 */
    IMU_QCONST(0.25, 30),     /* acc_tolerance, fraction of g */
    IMU_QCONST(0.05, 30),     /* mag_tolerance, fraction of the reference field */
    IMU_QCONST(0.02, 30),     /* dip_tolerance, rad */
    IMU_QCONST(3.0, 16),      /* acc_lowpass, s */
};

#define DESC(field, q, unit) {#field, offsetof(imu_eskf_settings_t, field), q, unit}
const imu_setting_desc_t imu_eskf_setting_descs[] = {
    DESC(sample_rate, 16, "Hz"),
    DESC(gyro_arw, 32, "rad/s^0.5"),
    DESC(gyro_rrw, 40, "rad/s^1.5"),
    DESC(acc_bias_rw, 32, "m/s^2.5"),
    DESC(acc_noise, 24, "m/s^2"),
    DESC(mag_noise, 16, "uT"),
    DESC(init_attitude_std, 28, "rad"),
    DESC(init_gyro_bias_std, 30, "rad/s"),
    DESC(init_acc_bias_std, 24, "m/s^2"),
    DESC(estimate_acc_bias, 0, "1"),
    DESC(gravity, 24, "m/s^2"),
    DESC(acc_tolerance, 30, "1"),
    DESC(mag_tolerance, 30, "1"),
    DESC(dip_tolerance, 30, "rad"),
    DESC(acc_lowpass, 16, "s"),
};
#undef DESC
const int imu_eskf_setting_count = (int)(sizeof imu_eskf_setting_descs / sizeof imu_eskf_setting_descs[0]);

/** Magnetic reference (norm and dip) tracking: 1 / time constant, 1/s, Q30: 30 s in normal
 *  operation, 1 s while the dip is learnt (the first REF_LEARN_TIME seconds). */
#define REF_RATE IMU_QCONST(0.033333333333333333, 30)
#define LEARN_RATE IMU_QCONST(1.0, 30)
#define REF_LEARN_TIME IMU_QCONST(10.0, 16)
/** Below this horizontal share of the unit field (Q30) the heading is not observable. */
#define MIN_HORIZONTAL_FIELD IMU_QCONST(0.05, 30)
/** Three-sample coning coefficients of eq. 15, Q30. */
#define CONING_13 IMU_QCONST(0.4125, 30) /* 33/80 */
#define CONING_2 IMU_QCONST(0.7125, 30)  /* 57/80 */

static int in_range(imu_real_t v, imu_real_t lo, imu_real_t hi)
{
    return v >= lo && v <= hi;
}

void imu_eskf_init(imu_eskf_t *f)
{
    (void)imu_eskf_set_settings(f, &imu_eskf_default_settings);
}

int imu_eskf_state_count(const imu_eskf_t *f)
{
    return f->settings.estimate_acc_bias != 0 ? 9 : 6;
}

imu_status_t imu_eskf_set_settings(imu_eskf_t *f, const imu_eskf_settings_t *s)
{
    imu_q30_t t;
    int k;
    if (!in_range(s->sample_rate, IMU_QCONST(30.0, 16), IMU_QCONST(32767.0, 16)) ||
        !in_range(s->gyro_arw, 0, IMU_QCONST(0.49, 32)) || !in_range(s->gyro_rrw, 0, IMU_QCONST(1.9e-3, 40)) ||
        !in_range(s->acc_bias_rw, 0, IMU_QCONST(0.49, 32)) ||
        !in_range(s->acc_noise, IMU_QCONST(1e-3, 24), IMU_QCONST(100.0, 24)) ||
        !in_range(s->mag_noise, IMU_QCONST(1e-3, 16), IMU_QCONST(1000.0, 16)) ||
        !in_range(s->init_attitude_std, IMU_QCONST(1e-4, 28), IMU_QCONST(3.2, 28)) ||
        !in_range(s->init_gyro_bias_std, IMU_QCONST(1e-5, 30), IMU_QCONST(1.0, 30)) ||
        !in_range(s->init_acc_bias_std, IMU_QCONST(1e-4, 24), IMU_QCONST(10.0, 24)) ||
        (s->estimate_acc_bias != 0 && s->estimate_acc_bias != IMU_QCONST(1.0, 0)) ||
        !in_range(s->gravity, IMU_QCONST(9.0, 24), IMU_QCONST(10.5, 24)) ||
        !in_range(s->acc_tolerance, IMU_QCONST(1e-3, 30), IMU_QCONST(1.0, 30)) ||
        !in_range(s->mag_tolerance, IMU_QCONST(1e-3, 30), IMU_QCONST(1.0, 30)) ||
        !in_range(s->dip_tolerance, IMU_QCONST(1e-3, 30), IMU_QCONST(1.5, 30)) ||
        !in_range(s->acc_lowpass, 0, IMU_QCONST(60.0, 16))) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations); /* < 1/30 s */
    f->period = IMU_ADD(IMU_ADD(f->dt, f->dt), f->dt);                              /* < 0.1 s */
    /* 1/g: Q24 in, 2^24 * 2^30 / g -> Q30 (about 0.1). */
    f->inv_gravity = IMU_DIV_SAT(IMU_QCONST(1.0, 24), s->gravity, 30, &f->saturations);
    /* Per-step variances: (noise * T) * noise. arw Q32 * T Q30 >> 30 -> Q32, * arw Q32 -> Q64. */
    t = IMU_MUL(s->gyro_arw, f->period, 30);
    for (k = 0; k < 3; ++k) {
        f->process_var[ATT + k] = IMU_WMUL(t, s->gyro_arw);
    }
    /* rrw Q40 * T Q30 >> 30 -> Q40, * rrw Q40 -> Q80. */
    t = IMU_MUL(s->gyro_rrw, f->period, 30);
    for (k = 0; k < 3; ++k) {
        f->process_var[GYRO_BIAS + k] = IMU_WMUL(t, s->gyro_rrw);
    }
    /* In g units: rw Q32 / g (Q32 * Q30 >> 30 -> Q32), then as the angle: Q64. */
    {
        const imu_real_t rw_g = IMU_MUL(s->acc_bias_rw, f->inv_gravity, 30);
        t = IMU_MUL(rw_g, f->period, 30);
        for (k = 0; k < 3; ++k) {
            f->process_var[ACC_BIAS + k] = IMU_WMUL(t, rw_g);
        }
    }
    /* Low-pass weight T / (tau + T) in [0, 1] (Q16 / Q16 -> Q30; T as Q16). */
    {
        const imu_q16_t period_q16 = IMU_SHR(f->period, 14);
        f->acc_alpha = IMU_DIV_SAT(period_q16, IMU_ADD(s->acc_lowpass, period_q16), 30, &f->saturations);
    }
    f->acc_earth_valid = 0;
    for (k = 0; k < 3; ++k) {
        f->acc_earth[k] = 0;
    }
    f->initialised = 0;
    f->in_group = 0;
    f->clipped = 0;
    f->realign = 0;
    f->steps = 0;
    /* learning time * filter rate: Q16 * Q16 >> 32; the rate is sample_rate / 3. */
    f->learn_steps = IMU_MUL_TO_INT(REF_LEARN_TIME, s->sample_rate, 32) / 3;
    for (k = 0; k < 3; ++k) {
        f->gyro_bias[k] = 0;
        f->acc_bias[k] = 0;
        f->acc_sum[k] = 0;
        f->mag_sum[k] = 0;
    }
    f->q[0] = f->q_out[0] = IMU_ONE_Q30;
    for (k = 1; k < 4; ++k) {
        f->q[k] = f->q_out[k] = 0;
    }
    f->ref_field = 0;
    f->ref_dip = 0;
    f->acc_weight = 0;
    f->mag_weight = 0;
    f->cov.n = 0;
    return IMU_OK;
}

/** Dip of a unit field in the earth frame (positive below the horizon), rad Q29, and its horizontal length. */
static imu_angle_t field_dip(const imu_q30_t earth[3], imu_q30_t *horizontal)
{
    *horizontal = imu_hypot(earth[0], earth[1]);
    return imu_atan2(-earth[2], *horizontal);
}

/** Attitude from a specific force and a field alone: tilt + tilt-compensated heading (seed 004 eq. 3-5, 14). */
static void align_to(imu_eskf_t *f, const imu_q16_t acc[3], const imu_q16_t mag[3])
{
    imu_angle_t euler[3] = {0, 0, 0};
    int k;
    (void)imu_tilt_from_acc(acc, &euler[0], &euler[1]);
    euler[2] = imu_heading_from_mag(mag, euler[0], euler[1]);
    imu_euler_to_quat(euler, f->q);
    for (k = 0; k < 4; ++k) {
        f->q_out[k] = f->q[k];
    }
}

/** Initial attitude (align_to), covariance and field reference. */
static void initialise(imu_eskf_t *f, const imu_sample_t *s)
{
    const imu_eskf_settings_t *st = &f->settings;
    imu_wide_t var[9];
    imu_q30_t unit[3], earth[3], horizontal;
    imu_real_t norm = 0;
    imu_q30_t acc_std_g;
    int k;
    align_to(f, s->acc, s->mag);
    if (imu_vec3_normalize(s->mag, unit, &norm)) {
        imu_quat_rotate(f->q, unit, earth);
        f->ref_field = norm;
        f->ref_dip = field_dip(earth, &horizontal);
    }
    /* Variances in Q56: attitude Q28^2 = Q56 (at most 3.2^2 * 2^56 < 2^60); gyro bias Q30^2 = Q60
     * and acc bias in g (Q24 * Q30 >> 24 -> Q30)^2 = Q60, both shifted down by 4. */
    acc_std_g = IMU_MUL(st->init_acc_bias_std, f->inv_gravity, 24);
    for (k = 0; k < 3; ++k) {
        var[ATT + k] = IMU_WMUL(st->init_attitude_std, st->init_attitude_std);
        var[GYRO_BIAS + k] = IMU_WSHR(IMU_WMUL(st->init_gyro_bias_std, st->init_gyro_bias_std), 4);
        var[ACC_BIAS + k] = IMU_WSHR(IMU_WMUL(acc_std_g, acc_std_g), 4);
    }
    imu_cov_init(&f->cov, imu_eskf_state_count(f), var, 56, &f->saturations);
    f->initialised = 1;
}

/** Three-sample rotation vector of eq. 15 from the buffered increments (Q30 rad, each below 0.1). */
static void rotation_vector(imu_q30_t t[3][3], imu_q30_t phi[3])
{
    imu_q30_t c13[3], diff[3], c2[3];
    int k;
    for (k = 0; k < 3; ++k) {
        diff[k] = IMU_SUB(t[2][k], t[0][k]);
    }
    imu_vec3_cross(t[0], t[2], c13);
    imu_vec3_cross(t[1], diff, c2);
    for (k = 0; k < 3; ++k) {
        phi[k] = IMU_ADD(IMU_ADD(IMU_ADD(t[0][k], t[1][k]), t[2][k]),
                         IMU_ADD(IMU_MUL(CONING_13, c13[k], 30), IMU_MUL(CONING_2, c2[k], 30)));
    }
}

/** Covariance time update over one filter period with rotation vector phi. */
static void predict_covariance(imu_eskf_t *f, const imu_q30_t phi[3])
{
    imu_q30_t m[IMU_COV_MAX][IMU_COV_MAX];
    const int n = imu_eskf_state_count(f);
    int i, j;
    for (i = 0; i < n; ++i) {
        for (j = 0; j < n; ++j) {
            m[i][j] = i == j ? IMU_ONE_Q30 : 0;
        }
    }
    /* Phi_att,att = I - [phi x] (w T = phi); Phi_att,bias = -T I. */
    m[0][1] = phi[2];
    m[0][2] = -phi[1];
    m[1][0] = -phi[2];
    m[1][2] = phi[0];
    m[2][0] = phi[1];
    m[2][1] = -phi[0];
    for (i = 0; i < 3; ++i) {
        m[ATT + i][GYRO_BIAS + i] = -f->period;
    }
    /* The angle variances are Q64 and the bias variances Q80: bringing the angle
     * ones to Q80 would overflow, so the whole vector is passed as Q64 with the bias
     * terms shifted down by 16 (seed 000's rrw still keeps 2^28 of resolution). */
    {
        imu_wide_t qvar[9];
        for (i = 0; i < 9; ++i) {
            qvar[i] = f->process_var[i];
        }
        for (i = 0; i < 3; ++i) {
            qvar[GYRO_BIAS + i] = IMU_WSHR(f->process_var[GYRO_BIAS + i], 16);
        }
        imu_cov_predict(&f->cov, m, qvar, 64, &f->saturations);
    }
}

/** x <- (u . x) u for a 3-vector x and a unit vector u (both Q30). */
static void project_onto(imu_q30_t x[3], const imu_q30_t u[3])
{
    const imu_q30_t along = IMU_ADD(IMU_ADD(IMU_MUL(x[0], u[0], 30), IMU_MUL(x[1], u[1], 30)), IMU_MUL(x[2], u[2], 30));
    int k;
    for (k = 0; k < 3; ++k) {
        x[k] = IMU_MUL(along, u[k], 30);
    }
}

/**
 * Sequential scalar update; the innovation is corrected for the corrections so
 * far. With `vertical_only` (the heading update) the attitude and gyro-bias
 * corrections keep only their component along `up`, so that cross-covariances
 * cannot let the magnetometer tilt roll and pitch.
 */
static void scalar_update(imu_eskf_t *f, const imu_q30_t h[9], imu_q30_t z, imu_wide_t r, int r_q, imu_q30_t w,
                          const imu_q30_t *vertical_only, imu_q30_t dx_total[9])
{
    imu_q30_t dx[9];
    const int n = imu_eskf_state_count(f);
    int i;
    for (i = 0; i < n; ++i) {
        z = IMU_SUB_SAT(z, IMU_MUL(h[i], dx_total[i], 30), &f->saturations);
    }
    if (imu_cov_update(&f->cov, h, r, r_q, z, w, dx, &f->saturations)) {
        if (vertical_only != 0) {
            project_onto(&dx[ATT], vertical_only);
            project_onto(&dx[GYRO_BIAS], vertical_only);
            for (i = ACC_BIAS; i < n; ++i) {
                dx[i] = 0;
            }
        }
        for (i = 0; i < n; ++i) {
            dx_total[i] = IMU_ADD_SAT(dx_total[i], dx[i], &f->saturations);
        }
    }
}

/** Gravity measurement: a / g = v + [v x] dtheta + ba (three scalar updates). */
static void gravity_update(imu_eskf_t *f, const imu_q16_t acc[3], const imu_q30_t up[3], imu_q30_t dx[9])
{
    const imu_eskf_settings_t *st = &f->settings;
    imu_q30_t unit[3];
    imu_real_t norm;
    imu_q30_t h[9];
    imu_q30_t noise_g;
    int k, i;
    if (!imu_vec3_normalize(acc, unit, &norm)) {
        f->acc_weight = 0;
        return;
    }
    /* |a| / g - 1: Q16 * Q30 >> 22 -> Q24. */
    f->acc_weight = imu_deviation_weight(IMU_SUB(IMU_MUL(norm, f->inv_gravity, 22), IMU_QCONST(1.0, 24)),
                                     IMU_SHR(st->acc_tolerance, 6), &f->saturations);
    if (f->acc_weight == 0) {
        return; /* far from 1 g (taps, free fall): no gravity information */
    }
    noise_g = IMU_MUL(st->acc_noise, f->inv_gravity, 24); /* Q24 * Q30 >> 24 -> Q30 (g) */
    for (k = 0; k < 3; ++k) {
        /* Row k of [[v x], 0, I]. */
        const imu_q30_t cross[3][3] = {{0, -up[2], up[1]}, {up[2], 0, -up[0]}, {-up[1], up[0], 0}};
        /* z = a_k / g - v_k - ba_k: Q16 * Q30 >> 16 -> Q30 (g). */
        const imu_q30_t z = IMU_SUB_SAT(IMU_SUB_SAT(IMU_MUL_SAT(acc[k], f->inv_gravity, 16, &f->saturations), up[k],
                                                    &f->saturations),
                                        f->acc_bias[k], &f->saturations);
        for (i = 0; i < 9; ++i) {
            h[i] = 0;
        }
        for (i = 0; i < 3; ++i) {
            h[ATT + i] = cross[k][i];
        }
        h[ACC_BIAS + k] = IMU_ONE_Q30;
        scalar_update(f, h, z, IMU_WMUL(noise_g, noise_g), 60, f->acc_weight, 0, dx);
    }
}

/** Heading measurement from the horizontal field; tracks the field reference while undisturbed. */
static void heading_update(imu_eskf_t *f, const imu_q16_t mag[3], const imu_q30_t up[3], imu_q30_t dx[9])
{
    const imu_eskf_settings_t *st = &f->settings;
    imu_q30_t unit[3], earth[3], horizontal;
    imu_real_t norm;
    imu_angle_t dip;
    imu_q30_t h[9], z, sigma, w_norm;
    int i;
    f->mag_weight = 0;
    if (!imu_vec3_normalize(mag, unit, &norm) || f->ref_field <= 0) {
        return;
    }
    imu_quat_rotate(f->q, unit, earth);
    dip = field_dip(earth, &horizontal);
    if (horizontal < MIN_HORIZONTAL_FIELD) {
        return;
    }
    /* Norm deviation |m| / ref - 1 (Q16 / Q16 -> Q24) and dip deviation (Q29 -> Q24). */
    w_norm = imu_deviation_weight(IMU_SUB(IMU_DIV_SAT(norm, f->ref_field, 24, &f->saturations), IMU_QCONST(1.0, 24)),
                              IMU_SHR(st->mag_tolerance, 6), &f->saturations);
    f->mag_weight = IMU_MUL(w_norm,
                            imu_deviation_weight(IMU_SHR(imu_angle_diff(dip, f->ref_dip), 5),
                                             IMU_SHR(st->dip_tolerance, 6), &f->saturations),
                            30);
    if (f->steps < f->learn_steps) {
        /* Learning: the first dip came from an unconverged attitude; follow the
         * measured dip quickly (time constant 1 s) and let only the norm gate. */
        const imu_q30_t rate = IMU_MUL(f->period, LEARN_RATE, 30);
        f->ref_dip = imu_angle_add(f->ref_dip, IMU_MUL(rate, imu_angle_diff(dip, f->ref_dip), 30));
        f->mag_weight = w_norm;
    } else if (f->mag_weight >= IMU_QCONST(0.5, 30)) {
        /* Undisturbed: follow slow changes of the reference (time constant 30 s). */
        const imu_q30_t rate = IMU_MUL(f->period, REF_RATE, 30);
        f->ref_field = IMU_ADD(f->ref_field, IMU_MUL(rate, IMU_SUB(norm, f->ref_field), 30));
        f->ref_dip = imu_angle_add(f->ref_dip, IMU_MUL(rate, imu_angle_diff(dip, f->ref_dip), 30));
    }
    if (f->mag_weight == 0) {
        return;
    }
    /* z = sin(heading error) = east share of the horizontal field; H = [v^T, 0, 0].
     * (The sine, rather than the angle, also softens large innovations.) */
    z = IMU_DIV_SAT(earth[0], horizontal, 30, &f->saturations);
    for (i = 0; i < 9; ++i) {
        h[i] = 0;
    }
    for (i = 0; i < 3; ++i) {
        h[ATT + i] = up[i];
    }
    /* sigma = mag_noise / (horizontal field in uT), Q16 / Q16 -> Q30 (clamped: a tiny horizontal field means no heading). */
    {
        const imu_q16_t horizontal_ut = IMU_MUL(horizontal, norm, 30);
        if (horizontal_ut <= 0) {
            return;
        }
        sigma = IMU_DIV_SAT(st->mag_noise, horizontal_ut, 30, &f->saturations);
    }
    scalar_update(f, h, z, IMU_WMUL(sigma, sigma), 60, f->mag_weight, up, dx);
}

/**
 * Low-pass the specific force in the estimated earth frame, where rotations do
 * not change gravity but a back-and-forth translation averages out (time
 * constant acc_lowpass), and return it in the sensor frame: acc <- R^T lp(R acc).
 */
static void lowpass_specific_force(imu_eskf_t *f, imu_q16_t acc[3])
{
    imu_q30_t rows[3][3];
    imu_q16_t earth[3];
    int r, k;
    for (r = 0; r < 3; ++r) {
        imu_quat_matrix_row(f->q, r, rows[r]);
        /* Q30 * Q16 >> 30 -> Q16; |R a| = |a|. */
        earth[r] = IMU_ADD(IMU_ADD(IMU_MUL(rows[r][0], acc[0], 30), IMU_MUL(rows[r][1], acc[1], 30)),
                           IMU_MUL(rows[r][2], acc[2], 30));
    }
    for (r = 0; r < 3; ++r) {
        f->acc_earth[r] = f->acc_earth_valid
                              ? IMU_ADD(f->acc_earth[r], IMU_MUL(f->acc_alpha, IMU_SUB(earth[r], f->acc_earth[r]), 30))
                              : earth[r];
    }
    f->acc_earth_valid = 1;
    for (k = 0; k < 3; ++k) {
        acc[k] = IMU_ADD(IMU_ADD(IMU_MUL(rows[0][k], f->acc_earth[0], 30), IMU_MUL(rows[1][k], f->acc_earth[1], 30)),
                         IMU_MUL(rows[2][k], f->acc_earth[2], 30));
    }
}

/** v <- v + (R dtheta) x v: an earth-frame vector (Q16) after the estimate turned by dtheta (sensor frame, Q30). */
static void turn_earth_vector(const imu_eskf_t *f, imu_q16_t v[3], const imu_q30_t dtheta[3])
{
    imu_q30_t u[3];
    imu_q16_t c[3];
    int k;
    imu_quat_rotate(f->q, dtheta, u);
    c[0] = IMU_SUB(IMU_MUL(u[1], v[2], 30), IMU_MUL(u[2], v[1], 30));
    c[1] = IMU_SUB(IMU_MUL(u[2], v[0], 30), IMU_MUL(u[0], v[2], 30));
    c[2] = IMU_SUB(IMU_MUL(u[0], v[1], 30), IMU_MUL(u[1], v[0], 30));
    for (k = 0; k < 3; ++k) {
        v[k] = IMU_ADD(v[k], c[k]);
    }
}

/** 1 when the specific force's norm is within acc_tolerance of gravity (Q16 m/s^2 in). */
static int near_gravity(const imu_eskf_t *f, const imu_q16_t acc[3])
{
    imu_q30_t unit[3];
    imu_real_t norm;
    imu_real_t deviation;
    if (!imu_vec3_normalize(acc, unit, &norm)) {
        return 0;
    }
    /* |a| / g - 1: Q16 * Q30 >> 22 -> Q24 (up to 128 g). */
    deviation = IMU_SUB(IMU_MUL(norm, f->inv_gravity, 22), IMU_QCONST(1.0, 24));
    return deviation < IMU_SHR(f->settings.acc_tolerance, 6) && deviation > -IMU_SHR(f->settings.acc_tolerance, 6);
}

/** Attitude error variance back to init_attitude_std^2, its correlations cleared. */
static void restart_attitude_uncertainty(imu_eskf_t *f)
{
    const imu_wide_t var = IMU_WMUL(f->settings.init_attitude_std, f->settings.init_attitude_std); /* Q56 */
    int k;
    for (k = 0; k < 3; ++k) {
        imu_cov_reset_state(&f->cov, ATT + k, var, 56, &f->saturations);
    }
    f->acc_earth_valid = 0; /* its earth frame was the lost one */
}

/** One filter step at the end of a group of three samples. */
static void filter_step(imu_eskf_t *f)
{
    imu_q30_t phi[3], up[3], dx[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    imu_q16_t acc[3], mag[3];
    int k;
    rotation_vector(f->increments, phi);
    imu_quat_integrate(f->q, phi);
    predict_covariance(f, phi);
    for (k = 0; k < 3; ++k) {
        acc[k] = f->acc_sum[k] / 3;
        mag[k] = f->mag_sum[k] / 3;
        f->acc_sum[k] = 0;
        f->mag_sum[k] = 0;
    }
    if ((f->clipped & IMU_CLIPPED_GYR) != 0) {
        /* A clipped gyroscope lost an unknown part of the rotation (any angle): the
         * attitude restarts from gravity and the field at the first calm step. */
        f->realign = 1;
    }
    if (f->realign && (f->clipped & (IMU_CLIPPED_GYR | IMU_CLIPPED_ACC)) == 0 && near_gravity(f, acc)) {
        align_to(f, acc, mag);
        restart_attitude_uncertainty(f);
        f->realign = 0;
    }
    imu_quat_matrix_row(f->q, 2, up);
    if ((f->clipped & IMU_CLIPPED_ACC) == 0) {
        lowpass_specific_force(f, acc);
        gravity_update(f, acc, up, dx);
    } else {
        f->acc_weight = 0;
    }
    if ((f->clipped & IMU_CLIPPED_MAG) == 0) {
        heading_update(f, mag, up, dx);
    } else {
        f->mag_weight = 0;
    }
    f->clipped = 0;
    /* Inject and reset the error state; the low-passed specific force follows the
     * estimated earth frame's correction (exp(R dtheta)). */
    turn_earth_vector(f, f->acc_earth, &dx[ATT]);
    imu_quat_integrate(f->q, &dx[ATT]);
    for (k = 0; k < 3; ++k) {
        f->gyro_bias[k] = IMU_ADD_SAT(f->gyro_bias[k], dx[GYRO_BIAS + k], &f->saturations);
        if (imu_eskf_state_count(f) == 9) {
            f->acc_bias[k] = IMU_ADD_SAT(f->acc_bias[k], dx[ACC_BIAS + k], &f->saturations);
        }
    }
    for (k = 0; k < 4; ++k) {
        f->q_out[k] = f->q[k];
    }
    if (f->steps < f->learn_steps) {
        ++f->steps;
    }
}

/** v <- v - theta x v: a sensor-frame vector (Q16) seen from the frame turned by theta (Q30 rad, small). */
static void rotate_back(imu_q16_t v[3], const imu_q30_t theta[3])
{
    const imu_q16_t c0 = IMU_SUB(IMU_MUL(theta[1], v[2], 30), IMU_MUL(theta[2], v[1], 30));
    const imu_q16_t c1 = IMU_SUB(IMU_MUL(theta[2], v[0], 30), IMU_MUL(theta[0], v[2], 30));
    const imu_q16_t c2 = IMU_SUB(IMU_MUL(theta[0], v[1], 30), IMU_MUL(theta[1], v[0], 30));
    v[0] = IMU_SUB(v[0], c0);
    v[1] = IMU_SUB(v[1], c1);
    v[2] = IMU_SUB(v[2], c2);
}

void imu_eskf_update(imu_eskf_t *f, const imu_sample_t *s)
{
    int k;
    if (!f->initialised) {
        initialise(f, s);
        return;
    }
    for (k = 0; k < 3; ++k) {
        /* Bias-corrected rate (Q24 - Q30 >> 6) times dt (Q30) >> 24 -> rad Q30. */
        const imu_rate_t w = IMU_SUB_SAT(s->gyr[k], IMU_SHR(f->gyro_bias[k], 6), &f->saturations);
        f->increments[f->in_group][k] = IMU_MUL_SAT(w, f->dt, 24, &f->saturations);
    }
    /* The group's sums are kept in the frame of the latest sample: rotate them by
     * this sample's increment (v <- v - theta x v) before adding the new values, so
     * the measurement matches the attitude at the end of the group. */
    rotate_back(f->acc_sum, f->increments[f->in_group]);
    rotate_back(f->mag_sum, f->increments[f->in_group]);
    for (k = 0; k < 3; ++k) {
        /* Three sensor values (each below 2^27 in Q16) sum without overflow. */
        f->acc_sum[k] = IMU_ADD(f->acc_sum[k], s->acc[k]);
        f->mag_sum[k] = IMU_ADD(f->mag_sum[k], s->mag[k]);
    }
    f->clipped |= s->clipped;
    imu_quat_integrate(f->q_out, f->increments[f->in_group]);
    if (++f->in_group == 3) {
        f->in_group = 0;
        filter_step(f);
    }
}

void imu_eskf_get(const imu_eskf_t *f, imu_output_t *out)
{
    int k;
    for (k = 0; k < 4; ++k) {
        out->quat[k] = f->q_out[k];
    }
    imu_quat_to_euler(f->q_out, out->euler);
    for (k = 0; k < 3; ++k) {
        out->gyro_bias[k] = IMU_SHR(f->gyro_bias[k], 6);
    }
}

void imu_eskf_get_acc_bias(const imu_eskf_t *f, imu_q16_t acc_bias_q24[3])
{
    int k;
    for (k = 0; k < 3; ++k) {
        /* g units Q30 * g (Q24) >> 30 -> m/s^2 Q24. */
        acc_bias_q24[k] = IMU_MUL(f->acc_bias[k], f->settings.gravity, 30);
    }
}

void imu_eskf_covariance(const imu_eskf_t *f, int i, int j, imu_real_t *mant, int32_t *exp)
{
    imu_cov_get(&f->cov, i, j, mant, exp);
}

void imu_eskf_get_weights(const imu_eskf_t *f, imu_q30_t *gravity, imu_q30_t *heading)
{
    *gravity = f->acc_weight;
    *heading = f->mag_weight;
}
