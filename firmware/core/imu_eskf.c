/**
 * @file imu_eskf.c
 * @brief 9-state error-state Kalman filter (see imu_eskf.h).
 */
#include "imu_eskf.h"

#include "imu_math.h"


/* Error states. The 6-state filter keeps the low-pass's error (lowpass_error_states) where the
 * 9-state one keeps the accelerometer bias. */
enum { ATT = 0, GYRO_BIAS = 3, ACC_BIAS = 6, LOWPASS_ERROR = 6 };

/* Defaults: [seed 000]'s angle random walk (docs/filters.md, Bibliography); the rest
 * chosen on the BROAD trials (one set for all, docs/accuracy.md): a rate random walk below [seed 000]'s (its
 * 520 deg/h^1.5 makes the bias wander faster than MEMS parts of the GY-86 class
 * do), no accelerometer-bias states (without rotation they absorb translation
 * accelerations, docs/filters.md). */
const imu_eskf_settings_t imu_eskf_default_settings = {
    IMU_QCONST(100.0, 16),    /* sample_rate, Hz */
    IMU_QCONST(8.7e-4, 32),   /* gyro_arw, rad/sqrt(s) ([seed 000] table 1: 3 deg/sqrt(h)) */
    IMU_QCONST(1e-5, 40),     /* gyro_rrw, rad/s/sqrt(s) (124 deg/h^1.5) */
    IMU_QCONST(1e-4, 32),     /* acc_bias_rw, m/s^2/sqrt(s) */
    IMU_QCONST(0.2, 24),      /* acc_noise, m/s^2 */
    IMU_QCONST(1.0, 16),      /* mag_noise, uT */
    IMU_QCONST(0.1, 28),      /* init_attitude_std, rad */
    IMU_QCONST(0.01, 30),     /* init_gyro_bias_std, rad/s */
    IMU_QCONST(0.02, 24),     /* init_acc_bias_std, m/s^2: what `imulink calibrate accel` leaves */
    IMU_QCONST(0.0, 0),       /* estimate_acc_bias */
    IMU_QCONST(9.80665, 24),  /* gravity, m/s^2 */
    IMU_QCONST(0.25, 30),     /* acc_tolerance, fraction of g */
    IMU_QCONST(0.05, 30),     /* mag_tolerance, fraction of the reference field */
    IMU_QCONST(0.02, 30),     /* dip_tolerance, rad */
    IMU_QCONST(3.0, 16),      /* acc_lowpass, s */
    IMU_QCONST(0.003, 30),    /* gyro_scale_std, fraction (a calibrated gyroscope's residual) */
};

/* Each field with its Q format, unit and accepted range [lo, hi] in the unit. */
#define DESC(field, q, unit, lo, hi) \
    {#field, offsetof(imu_eskf_settings_t, field), q, unit, IMU_QCONST(lo, q), IMU_QCONST(hi, q)}
const imu_setting_desc_t imu_eskf_setting_descs[] = {
    DESC(sample_rate, 16, "Hz", 30.0, 32767.0),
    DESC(gyro_arw, 32, "rad/s^0.5", 0.0, 0.49),
    DESC(gyro_rrw, 40, "rad/s^1.5", 0.0, 1.9e-3),
    DESC(acc_bias_rw, 32, "m/s^2.5", 0.0, 0.49),
    DESC(acc_noise, 24, "m/s^2", 1e-3, 100.0),
    DESC(mag_noise, 16, "uT", 1e-3, 1000.0),
    DESC(init_attitude_std, 28, "rad", 1e-4, 3.2),
    DESC(init_gyro_bias_std, 30, "rad/s", 1e-5, 1.0),
    DESC(init_acc_bias_std, 24, "m/s^2", 1e-4, 10.0),
    DESC(estimate_acc_bias, 0, "1", 0.0, 1.0),
    DESC(gravity, 24, "m/s^2", 9.0, 10.5),
    DESC(acc_tolerance, 30, "1", 1e-3, 1.0),
    DESC(mag_tolerance, 30, "1", 1e-3, 1.0),
    DESC(dip_tolerance, 30, "rad", 1e-3, 1.5),
    DESC(acc_lowpass, 16, "s", 0.0, 60.0),
    DESC(gyro_scale_std, 30, "1", 0.0, 0.05),
};
#undef DESC
const int imu_eskf_setting_count = (int)(sizeof imu_eskf_setting_descs / sizeof imu_eskf_setting_descs[0]);

/** Magnetic reference (norm and dip) tracking: 1 / time constant, 1/s, Q30: 30 s in normal
 *  operation, 1 s while the dip is learnt (the first REF_LEARN_TIME seconds). */
#define REF_RATE IMU_QCONST(0.033333333333333333, 30)
#define LEARN_RATE IMU_QCONST(1.0, 30)
#define REF_LEARN_TIME IMU_QCONST(10.0, 16)
/** A field weight (Q30) from which the heading update may teach the gyro bias (heading_update):
 *  the norm and dip within about a quarter of their tolerances (w = 1 / (1 + d^2)^2 >= 0.9 for
 *  one deviation d <= 0.23). The HMC5883L's noise moves a group mean's norm by about 0.05 and
 *  its dip by about 0.1 of the default tolerances. */
#define BIAS_FIELD_WEIGHT IMU_QCONST(0.9, 30)
/** Below this horizontal share of the unit field (Q30) the heading is not observable. */
#define MIN_HORIZONTAL_FIELD IMU_QCONST(0.05, 30)
/** A field acceptable as the first reference, uT, Q16: the earth's is 22-67 uT everywhere;
 *  below 5 uT it is a magnetometer that has not converted yet (an HMC5883L reads zeros). */
#define MIN_REF_FIELD IMU_QCONST(5.0, 16)
#define MAX_REF_FIELD IMU_QCONST(500.0, 16)
/** A disturbed field that keeps one norm and dip in the earth frame while the board turns
 *  faster than NEW_FIELD_MIN_RATE (rad/s, Q30: 20 deg/s) is fixed to the earth, not to the
 *  board. It becomes the new reference by the rule the nav filter shares (imu_field_trust_t),
 *  counting only the turning steps: once it has held for longer than the reference was
 *  trusted (turning, undisturbed) and for at least IMU_FIELD_NEW_TIME; the trust counts up
 *  to IMU_FIELD_TRUST_LIMIT, so a lasting new field (the board moved into a vehicle) is
 *  taken after a minute of turning. */
#define NEW_FIELD_MIN_RATE IMU_QCONST(0.34906585, 30)
/** Largest specific force and field the filter takes, m/s^2 or uT, Q16 (beyond every range
 *  of the MPU6050 and HMC5883L): larger values come only from scale settings no real
 *  sensor has; they are clamped and the sensor counts as clipped, which leaves every sum,
 *  norm and rotation below with headroom. */
#define INPUT_LIMIT IMU_QCONST(1024.0, 16)
/** A specific force above this (m/s^2, Q16; 52 g, beyond 16 of the largest acc_tolerance)
 *  carries no gravity information, and |a| / g stays within Q24 below it. */
#define MAX_GRAVITY_NORM IMU_QCONST(512.0, 16)
/** lowpass_settled this close to 1 (within 2^-16) is taken as 1: the gravity updates' full weight. */
#define SETTLED IMU_QCONST(1.0 - 1.0 / 65536.0, 30)
/** A rest measurement of the gyro bias this many standard deviations from the prediction is
 *  a jump of the bias (check_bias_jump). With 5, Gaussian noise alone makes one in about
 *  580 000 rest steps (5 h of rest at 100 Hz), which then widens the variance to a few
 *  times the noise's: harmless. */
#define JUMP_SIGMAS 5
/** Turn (rad, Q30) of gravity or the field beyond which a bias jump is told from a rotation
 *  (check_bias_jump): 1.25 times the turn tests' limit, so that a real rotation fails those
 *  tests first (at 1.0 the two raced on equal terms and a 1 deg/s turn now and then won). */
#define JUMP_TURN (5 * IMU_REST_TURN / 4)

/* The 9-state filter has no states for the low-pass's error (lowpass_error_states): while the
 * board turns (faster than NEW_FIELD_MIN_RATE, `turning`) its gravity rows count that error as
 * white noise of this size besides acc_noise, m/s^2, Q24. With it they count 0.3 m/s^2 in
 * motion, what that filter was measured best with on BROAD before the 6-state filter took
 * these states and acc_noise 0.2 (docs/accuracy.md). At rest and in slow turns the error is
 * small, and counted there it made the tilt and bias look worse known than they are (NEES
 * 0.65-0.70 per degree of freedom in tools/eval_consistency.py's slow rotation). */
#define UNMODELLED_LOWPASS_ERROR IMU_QCONST(0.2236068, 24)


/* The group after one with a clipped accelerometer: a private bit of `clipped`, beside the
 * IMU_CLIPPED_* bits (see hold_specific_force). */
#define AFTER_ACC_CLIP 0x100u
/** Three-sample coning coefficients of eq. 15, Q30. */
#define CONING_13 IMU_QCONST(0.4125, 30) /* 33/80 */
#define CONING_2 IMU_QCONST(0.7125, 30)  /* 57/80 */

void imu_eskf_init(imu_eskf_t *f)
{
    (void)imu_eskf_set_settings(f, &imu_eskf_default_settings);
}

int imu_eskf_state_count(const imu_eskf_t *f)
{
    return f->settings.estimate_acc_bias != 0 ? 9 : 6;
}

/**
 * 1 when the covariance holds the low-pass's error L as three states (the 6-state filter).
 * The gravity rows read the low-passed specific force, whose direction errs by the attitude
 * error low-passed alike: L <- (1 - w) Phi L + w dtheta at each group the low-pass takes
 * with weight w, not dtheta itself. Each past group was projected with the attitude of its
 * time, and the drift of the gyroscope since then moved the estimate but not the group.
 * Taking L for dtheta, with that drift counted as white noise step after step (acc_noise),
 * kept the gain small and the tilt behind VQF's (docs/accuracy.md, BROAD inclination 0.820
 * deg against 0.752 deg). The 9-state filter has no room for them (IMU_COV_MAX): its gravity
 * rows count the drift as noise (UNMODELLED_LOWPASS_ERROR).
 */
static int lowpass_error_states(const imu_eskf_t *f)
{
    return f->settings.estimate_acc_bias == 0;
}

imu_status_t imu_eskf_set_settings(imu_eskf_t *f, const imu_eskf_settings_t *s)
{
    imu_q30_t t;
    int k;
    /* estimate_acc_bias is a switch: 0 or 1, nothing between (the float build could hold 0.5) */
    if (imu_settings_check(imu_eskf_setting_descs, imu_eskf_setting_count, s) != IMU_OK ||
        (s->estimate_acc_bias != 0 && s->estimate_acc_bias != IMU_QCONST(1.0, 0))) {
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
    /* rrw Q40 * T Q30 >> 30 -> Q40, * rrw Q40 -> Q80, >> 16 -> Q64: the angle variances are
     * Q64 and the bias variances Q80, and bringing the angle ones to Q80 would overflow, so
     * all are Q64 ([seed 000]'s rrw still keeps 2^28 of resolution). */
    t = IMU_MUL(s->gyro_rrw, f->period, 30);
    for (k = 0; k < 3; ++k) {
        f->process_var[GYRO_BIAS + k] = IMU_WSHR(IMU_WMUL(t, s->gyro_rrw), 16);
    }
    /* In g units: rw Q32 / g (Q32 * Q30 >> 30 -> Q32), then as the angle: Q64. */
    {
        const imu_real_t rw_g = IMU_MUL(s->acc_bias_rw, f->inv_gravity, 30);
        t = IMU_MUL(rw_g, f->period, 30);
        for (k = 0; k < 3; ++k) {
            /* the low-pass's error has no noise of its own: it is the attitude's, low-passed */
            f->process_var[ACC_BIAS + k] = lowpass_error_states(f) ? 0 : IMU_WMUL(t, rw_g);
        }
    }
    /* Low-pass weight T / (tau + T) in [0, 1]: T Q30 * 2^24 / (tau Q16 -> Q24 (60 s < 2^30) + T Q24)
     * -> Q30. T keeps all its bits in the numerator (at 5 kHz a Q16 T would be 0.8 % off the twin's). */
    f->acc_alpha = IMU_DIV_SAT(f->period,
                               IMU_ADD(IMU_SHL_SAT(s->acc_lowpass, 8, &f->saturations), IMU_SHR(f->period, 6)), 24,
                               &f->saturations);
    f->lowpass_settled = 0;
    f->acc_held_valid = 0;
    for (k = 0; k < 3; ++k) {
        f->jump_turn[k] = 0;
        f->acc_held[k] = 0;
        f->acc_earth[k] = 0;
        f->gyr_sum[k] = 0;
        f->lowpass_rotation[k][0] = f->lowpass_rotation[k][1] = f->lowpass_rotation[k][2] = 0;
    }
    imu_rest_init(&f->rest, &imu_rest_default_config, f->period, &f->saturations);
    /* arw^2 / T = arw (Q32) * (sample_rate / 3) (Q16): Q48 wide (below 2^62) -> Q24 (below 2^37),
     * times arw in Q24 (below 2^23) -> Q48, below 2^60. */
    f->rest_var = IMU_WMUL(IMU_WSHR(IMU_WMUL(s->gyro_arw, s->sample_rate) / 3, 24), IMU_SHR(s->gyro_arw, 8));
    f->at_rest = 0;
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
    f->q[0] = f->q_out[0] = f->injected[0] = IMU_ONE_Q30;
    for (k = 1; k < 4; ++k) {
        f->q[k] = f->q_out[k] = f->injected[k] = 0;
    }
    f->ref.norm = f->ref.dip = 0;
    f->cand.norm = f->cand.dip = 0;
    imu_field_trust_reset(&f->trust);
    f->turning = 0;
    /* IMU_FIELD_NEW_TIME and IMU_FIELD_TRUST_LIMIT * filter rate, as learn_steps. */
    f->new_field_steps = IMU_MUL_TO_INT(IMU_FIELD_NEW_TIME, s->sample_rate, 32) / 3;
    f->trust_limit_steps = IMU_MUL_TO_INT(IMU_FIELD_TRUST_LIMIT, s->sample_rate, 32) / 3;
    f->acc_weight = 0;
    f->mag_weight = 0;
    f->cov.n = 0;
    return IMU_OK;
}

/** Attitude from a specific force and a field alone: tilt + tilt-compensated heading ([seed 004] eq. 3-5, 14). */
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

/** 1 when the specific force's norm is within acc_tolerance of gravity (Q16 m/s^2 in). */
static int near_gravity(const imu_eskf_t *f, const imu_q16_t acc[3])
{
    imu_real_t norm;
    imu_real_t deviation;
    if (!imu_vec3_normalize(acc, NULL, &norm) || norm >= MAX_GRAVITY_NORM) {
        return 0;
    }
    /* |a| / g - 1: Q16 * Q30 >> 22 -> Q24 (below 512 m/s^2: 53 g). */
    deviation = IMU_SUB(IMU_MUL(norm, f->inv_gravity, 22), IMU_QCONST(1.0, 24));
    return deviation < IMU_SHR(f->settings.acc_tolerance, 6) && deviation > -IMU_SHR(f->settings.acc_tolerance, 6);
}

/** Norm and dip of a field (Q16) in the earth frame of the attitude of rotation `rot`;
 *  0 for a zero field. */
static int field_norm_dip(const imu_rotation_t *rot, const imu_q16_t mag[3], imu_q16_t *norm, imu_angle_t *dip,
                          imu_q30_t earth[3], imu_q30_t *horizontal)
{
    imu_q30_t unit[3];
    if (!imu_vec3_normalize(mag, unit, norm)) {
        return 0;
    }
    imu_rotation_apply(rot, unit, earth);
    *dip = imu_field_dip(earth, horizontal);
    return 1;
}

/** A field's norm (uT, Q16) and dip (rad, Q29) from their Q46 / Q59 form. */
static imu_q16_t reference_norm(const imu_eskf_field_t *field)
{
    return IMU_NARROW(IMU_WSHR(field->norm, 30)); /* at most the largest input norm, 1774 uT */
}

static imu_angle_t reference_dip(const imu_eskf_field_t *field)
{
    return IMU_NARROW(IMU_WSHR(field->dip, 30)); /* within +-pi/2 */
}

static void set_reference(imu_eskf_field_t *field, imu_q16_t norm, imu_angle_t dip)
{
    field->norm = IMU_WMUL(norm, IMU_ONE_Q30);
    field->dip = IMU_WMUL(dip, IMU_ONE_Q30);
}

/**
 * Take the field as the magnetic reference when it is plausible (an earth-sized norm
 * with a horizontal share the heading can be read from): the dip and norm are then
 * learnt anew. Returns 1 when taken.
 */
static int acquire_reference(imu_eskf_t *f, const imu_rotation_t *rot, const imu_q16_t mag[3])
{
    imu_q30_t earth[3], horizontal;
    imu_q16_t norm;
    imu_angle_t dip;
    if (!field_norm_dip(rot, mag, &norm, &dip, earth, &horizontal) || norm < MIN_REF_FIELD || norm > MAX_REF_FIELD ||
        horizontal < MIN_HORIZONTAL_FIELD) {
        return 0;
    }
    set_reference(&f->ref, norm, dip);
    f->steps = 0;
    f->cand.norm = 0;
    imu_field_trust_reset(&f->trust);
    return 1;
}

/** Initial attitude (align_to), covariance and, when the field is plausible, its reference. */
static void initialise(imu_eskf_t *f, const imu_sample_t *s)
{
    const imu_eskf_settings_t *st = &f->settings;
    imu_wide_t var[9];
    imu_q30_t acc_std_g;
    int k;
    align_to(f, s->acc, s->mag);
    f->ref.norm = 0;
    if ((s->clipped & IMU_CLIPPED_MAG) == 0) {
        imu_rotation_t rot;
        imu_quat_rotation(f->q, &rot);
        (void)acquire_reference(f, &rot, s->mag);
    }
    /* A first sample away from 1 g (a tap, free fall) gives no tilt: align again at the first calm step. */
    f->realign = (s->clipped & IMU_CLIPPED_ACC) != 0 || !near_gravity(f, s->acc);
    /* Variances in Q56: attitude Q28^2 = Q56 (at most 3.2^2 * 2^56 < 2^60); gyro bias Q30^2 = Q60
     * and acc bias in g (Q24 * Q30 >> 24 -> Q30)^2 = Q60, both shifted down by 4. */
    acc_std_g = IMU_MUL(st->init_acc_bias_std, f->inv_gravity, 24);
    for (k = 0; k < 3; ++k) {
        var[ATT + k] = IMU_WMUL(st->init_attitude_std, st->init_attitude_std);
        var[GYRO_BIAS + k] = IMU_WSHR(IMU_WMUL(st->init_gyro_bias_std, st->init_gyro_bias_std), 4);
        /* (L becomes dtheta when the low-pass takes its first group: any variance until then) */
        var[ACC_BIAS + k] = lowpass_error_states(f) ? var[ATT + k] : IMU_WSHR(IMU_WMUL(acc_std_g, acc_std_g), 4);
    }
    imu_cov_init(&f->cov, 9, var, 56, &f->saturations);
    f->initialised = 1;
}

/** Three-sample rotation vector of eq. 15 from the buffered increments (Q30 rad, each at most
 *  1 rad): t1 + t2 + t3 + 33/80 t1 x t3 + 57/80 (t2 x t3 - t2 x t1). Up to 5.3 rad, so the
 *  vector is wide (Q30 in int64); every cross product is of two vectors of at most 1 rad. */
static void rotation_vector(imu_q30_t t[3][3], imu_wide_t phi[3])
{
    imu_q30_t c13[3], c23[3], c21[3];
    int k;
    imu_vec3_cross(t[0], t[2], c13);
    imu_vec3_cross(t[1], t[2], c23);
    imu_vec3_cross(t[1], t[0], c21);
    for (k = 0; k < 3; ++k) {
        /* Q30 * Q30 -> Q60, each product below 2^60: the sum fits int64. */
        const imu_wide_t coning = IMU_WMUL(CONING_13, c13[k]) + IMU_WMUL(CONING_2, c23[k]) - IMU_WMUL(CONING_2, c21[k]);
        phi[k] = (imu_wide_t)t[0][k] + t[1][k] + t[2][k] + IMU_WSHR(coning, 30);
    }
}

/** dq = exp(phi / 2) for a wide rotation vector (Q30 rad, up to 5.3 rad): applied in equal
 *  parts of at most half a radian per component, within imu_quat_integrate's 1 rad limit. */
static void rotation_quaternion(const imu_wide_t phi[3], imu_q30_t dq[4])
{
    const imu_wide_t half_rad = IMU_WMUL(IMU_QCONST(0.5, 30), IMU_QCONST(1.0, 0)); /* Q30 */
    imu_wide_t largest = 0;
    imu_q30_t part[3];
    int parts = 1, k;
    for (k = 0; k < 3; ++k) {
        const imu_wide_t a = phi[k] < 0 ? -phi[k] : phi[k];
        largest = a > largest ? a : largest;
    }
    while (largest >= parts * half_rad) {
        ++parts;
    }
    for (k = 0; k < 3; ++k) {
        /* at most 0.5 rad: fits Q30 (one part, the usual case, needs no 64-bit division: a
         * library routine of some sixty instructions on the Cortex-M4) */
        part[k] = (imu_q30_t)(parts == 1 ? phi[k] : phi[k] / parts);
    }
    imu_quat_from_rotation(dq, part);
    for (k = 1; k < parts; ++k) {
        imu_quat_integrate(dq, part);
    }
}

/** Scale a Q30 rotation vector down to at most 1 rad, direction kept. */
static void limit_to_one_radian(imu_q30_t v[3])
{
    const imu_q30_t half_rad = IMU_QCONST(0.5, 30);
    imu_q30_t unit[3];
    imu_real_t norm;
    int k;
    if (v[0] < half_rad && v[0] > -half_rad && v[1] < half_rad && v[1] > -half_rad && v[2] < half_rad &&
        v[2] > -half_rad) {
        return; /* below 0.87 rad: nothing to do (and no square root) */
    }
    if (imu_vec3_normalize(v, unit, &norm) && norm > IMU_ONE_Q30) {
        for (k = 0; k < 3; ++k) {
            v[k] = unit[k];
        }
    }
}

/**
 * The tilt share of the gyroscope's scale and misalignment errors over a step that turned
 * by `phi` (rad, Q30, in the error state's frame): a scale error s_k of axis k turns the
 * estimate by s_k phi_k about that axis, variance (sigma phi_k)^2, sigma = gyro_scale_std.
 * Only its tilt part u_k = (I - v v^T) sigma phi_k e_k enters, v the vertical in the sensor
 * frame: gravity corrects the tilt within seconds, and a faster tilt loop while the board
 * turns is what these errors ask for; a heading share would let every magnetic disturbance
 * in while the board turns (docs/filters.md). block: sum_k u_k u_k^T, Q64 rad^2
 * (imu_cov_predict's upper triangle).
 */
static void scale_noise(const imu_eskf_t *f, const imu_wide_t phi[3], imu_wide_t block[IMU_COV_BLOCK_CELLS])
{
    imu_q30_t v[3];
    imu_real_t tilt[3][3]; /* column k: u_k, rad, Q32 */
    int a, b, k, cell = 0;
    imu_quat_matrix_row(f->q, 2, v); /* up, in the sensor frame */
    for (k = 0; k < 3; ++k) {
        /* sigma Q30 * phi Q30 >> 28 -> Q32: at most 0.05 * 5.3 rad, within int32 */
        const imu_real_t turned = (imu_real_t)IMU_WSHR(IMU_WMUL(f->settings.gyro_scale_std, phi[k]), 28);
        for (a = 0; a < 3; ++a) {
            const imu_q30_t projector = IMU_SUB(a == k ? IMU_ONE_Q30 : 0, IMU_MUL(v[a], v[k], 30)); /* |.| <= 1 */
            tilt[a][k] = IMU_MUL(projector, turned, 30);
        }
    }
    for (a = 0; a < 3; ++a) {
        for (b = a; b < 3; ++b) {
            /* three products of Q32 values below 0.27 rad: below 2^62 */
            block[cell++] = IMU_WMUL(tilt[a][0], tilt[b][0]) + IMU_WMUL(tilt[a][1], tilt[b][1]) +
                            IMU_WMUL(tilt[a][2], tilt[b][2]);
        }
    }
}

/**
 * Covariance time update over one filter period whose frame turned by dq (the last
 * correction and the step's rotation): Phi_att,att = R(dq)^T (the exact transition of
 * the attitude error; the first-order
 * I - [phi x] lets the variance grow without bound in fast rotation), Phi_att,bias = -T I.
 * The process noise adds the gyroscope scale errors' tilt share of the step's gyro rotation
 * `phi` (scale_noise). The attitude variances are then kept below 1 rad^2.
 */
static void predict_covariance(imu_eskf_t *f, const imu_q30_t dq[4], const imu_wide_t phi[3])
{
    static const int attitude_rows[3] = {ATT, ATT + 1, ATT + 2}; /* the biases' rows are the identity's */
    imu_q30_t m[3][IMU_COV_MAX];
    imu_q30_t row[3];
    imu_wide_t block[IMU_COV_BLOCK_CELLS];
    const imu_wide_t *scale_block = NULL; /* none without a scale uncertainty */
    int i, j;
    if (f->settings.gyro_scale_std != 0) {
        scale_noise(f, phi, block);
        scale_block = block;
    }
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < IMU_COV_MAX; ++j) {
            m[i][j] = 0;
        }
    }
    for (i = 0; i < 3; ++i) {
        imu_quat_matrix_row(dq, i, row);
        for (j = 0; j < 3; ++j) {
            m[j][ATT + i] = row[j]; /* transpose */
        }
        m[i][GYRO_BIAS + i] = -f->period;
    }
    imu_cov_predict(&f->cov, m, attitude_rows, 3, f->process_var, scale_block, 64, &f->saturations);
    for (i = 0; i < 3; ++i) {
        imu_cov_cap_unit_variance(&f->cov, ATT + i);
    }
}

/**
 * The low-pass's error (lowpass_error_states) before the attitude's own time update: the
 * low-pass took a group with weight `taken` (Q30; 0: none) whose error was the attitude's
 * before this step, and L turns with the frame by dq (predict_covariance):
 * L <- R(dq)^T ((1 - w) L + w dtheta), with no noise of its own. (One transition with the
 * attitude's would take six moving rows, and their stack.)
 */
static void predict_lowpass_error(imu_eskf_t *f, const imu_q30_t dq[4], imu_q30_t taken)
{
    static const int lowpass_rows[3] = {LOWPASS_ERROR, LOWPASS_ERROR + 1, LOWPASS_ERROR + 2};
    static const imu_wide_t no_noise[IMU_COV_MAX] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    const imu_q30_t keep = IMU_SUB(IMU_ONE_Q30, taken);
    imu_q30_t m[3][IMU_COV_MAX];
    imu_q30_t row[3];
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < IMU_COV_MAX; ++j) {
            m[i][j] = 0;
        }
    }
    for (i = 0; i < 3; ++i) {
        imu_quat_matrix_row(dq, i, row);
        for (j = 0; j < 3; ++j) { /* transpose */
            m[j][ATT + i] = IMU_MUL(taken, row[j], 30);
            m[j][LOWPASS_ERROR + i] = IMU_MUL(keep, row[j], 30);
        }
    }
    imu_cov_predict(&f->cov, m, lowpass_rows, 3, no_noise, NULL, 64, &f->saturations);
}

/**
 * Gain map (imu_cov_update) of a measurement that may correct the attitude, the gyro
 * bias and the accelerometer bias as the flags say; with `vertical`, the attitude and
 * the gyro bias only along that unit vector (Q30).
 */
static void set_gain_map(imu_cov_map_t *map, int attitude, int gyro_bias, int acc_bias, const imu_q30_t *vertical)
{
    const uint8_t some = vertical != 0 ? IMU_COV_BLOCK_ALONG : IMU_COV_BLOCK_ALL;
    int i;
    map->block[ATT / 3] = attitude ? some : IMU_COV_BLOCK_NONE;
    map->block[GYRO_BIAS / 3] = gyro_bias ? some : IMU_COV_BLOCK_NONE;
    map->block[ACC_BIAS / 3] = acc_bias ? IMU_COV_BLOCK_ALL : IMU_COV_BLOCK_NONE;
    for (i = 0; i < 3; ++i) {
        map->along[i] = vertical != 0 ? vertical[i] : 0;
    }
}

/**
 * Sequential scalar update; the innovation is corrected for the corrections so
 * far. A gain map (NULL: none) restricts the corrections; P then keeps the
 * uncertainty of what was not corrected (imu_cov_update).
 */
static void scalar_update(imu_eskf_t *f, const imu_q30_t h[9], imu_q30_t z, imu_wide_t r, int r_q, imu_q30_t w,
                          const imu_cov_map_t *gain_map, imu_q30_t dx_total[9])
{
    const int n = f->cov.n;
    int i;
    for (i = 0; i < n; ++i) {
        if (h[i] != 0 && dx_total[i] != 0) { /* (most of a row is zero) */
            z = IMU_SUB_SAT(z, IMU_MUL_SAT(h[i], dx_total[i], 30, &f->saturations), &f->saturations);
        }
    }
    (void)imu_cov_update(&f->cov, h, r, r_q, z, w, gain_map, dx_total, &f->saturations);
}

/**
 * The norm row's second-order part. |v_true + dba| - 1 = v . dba + q, dba the
 * accelerometer-bias error, q = (v x dtheta) . dba + |dba across v|^2 / 2 + ...: at rest the
 * tilt and the horizontal bias trade against each other (the pair is not observable), and
 * q, about the variance of that horizontal bias, does not average out: left in the
 * innovation it became a vertical bias. Out: E[q] (g, Q30, into the innovation); the
 * return value is 1 while the vertical bias's variance v' P v is above var(q) (about
 * E[|dba across v|^2 / 2]^2, exact for two equal variances): below it the norm holds no
 * information a linear update could use.
 */
static int norm_second_order(imu_eskf_t *f, const imu_q30_t up[3], imu_q30_t *mean)
{
    imu_wide_t coupling = 0; /* E[(v x dtheta) . dba], Q60 */
    imu_wide_t trace = 0;    /* tr P_ba, Q60 */
    imu_wide_t vertical = 0; /* v' P_ba v, Q60 */
    imu_q30_t across;        /* E|dba across v|^2 / 2, Q30 */
    imu_q30_t p_ba[3][3];    /* P_ba, Q30 (each element read once: P is symmetric) */
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = i; j < 3; ++j) {
            p_ba[i][j] = p_ba[j][i] = imu_cov_element_q30(&f->cov, ACC_BIAS + i, ACC_BIAS + j, &f->saturations);
        }
    }
    for (i = 0; i < 3; ++i) {
        /* row i of [v x] is v_{i+1} e_{i+2} - v_{i+2} e_{i+1} (indices mod 3) */
        const int next = (i + 1) % 3, after = (i + 2) % 3;
        imu_wide_t p_up = 0; /* (P_ba v)_i, Q60 */
        coupling += IMU_WMUL(up[next], imu_cov_element_q30(&f->cov, ACC_BIAS + i, ATT + after, &f->saturations)) -
                    IMU_WMUL(up[after], imu_cov_element_q30(&f->cov, ACC_BIAS + i, ATT + next, &f->saturations));
        for (j = 0; j < 3; ++j) {
            p_up += IMU_WMUL(p_ba[i][j], up[j]);
        }
        trace += IMU_WMUL(p_ba[i][i], IMU_ONE_Q30);
        vertical += IMU_WMUL(IMU_NARROW(IMU_WSHR(p_up, 30)), up[i]);
    }
    across = IMU_HALF(IMU_WIDE_SAT(IMU_WSHR(trace - vertical, 30), &f->saturations));
    *mean = IMU_WIDE_SAT(IMU_WSHR(coupling, 30) + across, &f->saturations);
    return vertical > IMU_WMUL(across, across);
}

/** Component k of the low-passed specific force, m/s^2, Q16. */
static imu_q16_t acc_earth_q16(const imu_eskf_t *f, int k)
{
    return IMU_NARROW(IMU_WSHR(f->acc_earth[k], 30)); /* kept within +-INPUT_LIMIT */
}

/** Element (r, k) of the low-passed rotation, Q30 (about 1 at most: a mean of rotations). */
static imu_q30_t lowpass_rotation_q30(const imu_eskf_t *f, int r, int k)
{
    return IMU_NARROW(IMU_WSHR(f->lowpass_rotation[r][k], 29));
}

/**
 * The accelerometer bias ba as the low-passed specific force holds it (g, Q30; 9 states):
 * the low-pass ran in the earth frame, so it holds lowpass(R) ba, in the sensor frame
 * R^T lowpass(R) ba. At rest that is ba; just after a turn it is still partly the bias of
 * the former orientation, and taken for ba it made the turn look like information about
 * the bias (tests/test_eskf.py, two positions).
 */
static void lowpassed_bias(imu_eskf_t *f, const imu_rotation_t *rot, imu_q30_t bias[3])
{
    imu_q30_t earth[3]; /* lowpass(R) ba, g, Q30 */
    int r, k;
    for (r = 0; r < 3; ++r) {
        /* Q30 * Q30 -> Q60; |ba| below 2 g */
        earth[r] = IMU_WIDE_SAT(IMU_WSHR(IMU_WMUL(lowpass_rotation_q30(f, r, 0), f->acc_bias[0]) +
                                             IMU_WMUL(lowpass_rotation_q30(f, r, 1), f->acc_bias[1]) +
                                             IMU_WMUL(lowpass_rotation_q30(f, r, 2), f->acc_bias[2]),
                                         30),
                                &f->saturations);
    }
    for (k = 0; k < 3; ++k) {
        bias[k] = IMU_WIDE_SAT(IMU_WSHR(IMU_WMUL(rot->row[0][k], earth[0]) + IMU_WMUL(rot->row[1][k], earth[1]) +
                                            IMU_WMUL(rot->row[2][k], earth[2]),
                                        30),
                               &f->saturations);
    }
}

/**
 * Weight (Q30) of a gravity update from the low-passed force: `weight` times
 * lowpass_settled, the low-pass's steady noise variance (what acc_noise describes) over its
 * present one. At the start it holds few values and their linear acceleration almost
 * whole; counted with acc_noise they made the attitude look known to a degree while it
 * was tens of degrees off. The heading update, which reads the field through that tilt,
 * takes the same weight.
 */
static imu_q30_t start_weight(const imu_eskf_t *f, imu_q30_t weight)
{
    return f->lowpass_settled >= IMU_ONE_Q30 ? weight : IMU_MUL(weight, f->lowpass_settled, 30);
}

/**
 * Gravity measurement: c = a / g - B ba_est = v + [v x] dtheta + B (ba - ba_est), a the
 * low-passed specific force, v the estimated up in the sensor frame, B = R^T lowpass(R)
 * (lowpassed_bias; I at rest), taken apart along the estimated earth axes:
 * - east and north (two rows, e . c with H = [e x v, 0, e^T B], e^T B a row of
 *   lowpass(R)): the tilt and the horizontal accelerometer bias;
 * - up (9 states only, at rest): the norm, |c| - 1 = v . (ba - ba_est), which does not
 *   depend on the attitude. The linear row v . c - 1 would read the tilt error's
 *   second-order term (1 - cos e, e the tilt that the horizontal bias makes unobservable
 *   at rest) as vertical bias, and the filter became overconfident in it
 *   (docs/accuracy.md). Its H is taken along v (the up row of lowpass(R), v at rest), not
 *   along c: a direction that moved with the noise would make the tilt / horizontal-bias
 *   trade look observable.
 * Without accelerometer bias states the rows read the low-pass's error L instead of dtheta
 * (H = [0, 0, e x v]; lowpass_error_states).
 * The acceleration noise is isotropic, so the rows keep independent noise.
 *
 * The accelerometer bias is corrected at rest only. In motion a also holds what the
 * low-pass left of the linear acceleration, an error correlated over the low-pass's time
 * constant (seconds); counted as white noise step after step, it made a translation look
 * like a well-known bias (BROAD trial 16: 0.65 m/s^2). In motion the update leaves the bias
 * alone (a Schmidt update: P keeps its uncertainty and correlations), and a rest in a new
 * orientation, where a is gravity and the bias, tells tilt and bias apart.
 */
static void gravity_update(imu_eskf_t *f, const imu_q16_t acc[3], const imu_rotation_t *rot, imu_q30_t dx[9])
{
    const imu_eskf_settings_t *st = &f->settings;
    const imu_q30_t *up = rot->row[2];
    imu_q30_t c[3];         /* a / g - B ba, g, Q30 */
    imu_q30_t lowpassed[3]; /* the accelerometer bias in the low-passed a, g, Q30 (9 states) */
    const imu_q30_t *bias = f->acc_bias; /* (zero with six states) */
    const int nine = imu_eskf_state_count(f) == 9;
    imu_real_t norm;        /* |a|, m/s^2, Q16 */
    imu_q30_t h[9];
    imu_real_t noise_g; /* specific-force noise in g, Q26 (up to 100 m/s^2 over 9 m/s^2: 11 g) */
    imu_wide_t r;       /* its square, Q52 g^2 */
    imu_cov_map_t gain_map;
    const imu_cov_map_t *map = NULL;
    int k, i;
    if (!imu_vec3_normalize(acc, NULL, &norm)) {
        f->acc_weight = 0;
        return;
    }
    if (norm >= MAX_GRAVITY_NORM) {
        f->acc_weight = 0; /* beyond 16 tolerances of any setting: no gravity information */
        return;
    }
    /* |a| / g - 1: Q16 * Q30 >> 22 -> Q24 (below 512 m/s^2: 53 g). */
    f->acc_weight = imu_deviation_weight(IMU_SUB(IMU_MUL(norm, f->inv_gravity, 22), IMU_QCONST(1.0, 24)),
                                         IMU_SHR(st->acc_tolerance, 6), &f->saturations);
    if (f->acc_weight == 0) {
        return; /* far from 1 g (taps, free fall): no gravity information */
    }
    f->acc_weight = start_weight(f, f->acc_weight);
    noise_g = IMU_MUL(st->acc_noise, f->inv_gravity, 28); /* Q24 * Q30 >> 28 -> Q26 (g) */
    r = IMU_WMUL(noise_g, noise_g);
    if (!lowpass_error_states(f) && f->turning) {
        const imu_real_t unmodelled_g = IMU_MUL(UNMODELLED_LOWPASS_ERROR, f->inv_gravity, 28); /* Q26 */
        r += IMU_WMUL(unmodelled_g, unmodelled_g); /* two squares below 2^62 each: (11 g)^2 in Q52 */
    }
    if (f->at_rest) {
        set_gain_map(&gain_map, 1, 0, 1, NULL); /* the gyro bias is the rest measurement's */
        map = &gain_map;
    } else if (nine) {
        set_gain_map(&gain_map, 1, 1, 0, NULL); /* the accelerometer bias is learnt at rest */
        map = &gain_map;
    }
    if (nine) {
        lowpassed_bias(f, rot, lowpassed);
        bias = lowpassed;
    }
    for (k = 0; k < 3; ++k) {
        /* Q16 * Q30 >> 16 -> Q30 (g): below 16 acc_tolerance of 1 g, at most 17 g, saturated
         * beyond 2 g where the weight makes the update negligible. */
        c[k] = IMU_SUB_SAT(IMU_MUL_SAT(acc[k], f->inv_gravity, 16, &f->saturations), bias[k], &f->saturations);
    }
    for (k = 0; k < 2; ++k) {
        const imu_q30_t *e = rot->row[k]; /* east, north */
        /* e . c: each |c_k| <= 2 g, the sum up to 2 sqrt(3) g: saturated to Q30 */
        const imu_q30_t z = IMU_WIDE_SAT(
            IMU_WSHR(IMU_WMUL(e[0], c[0]) + IMU_WMUL(e[1], c[1]) + IMU_WMUL(e[2], c[2]), 30), &f->saturations);
        imu_vec3_cross(e, up, &h[ATT]);
        for (i = 0; i < 3; ++i) {
            h[GYRO_BIAS + i] = 0;
            if (nine) {
                h[ACC_BIAS + i] = lowpass_rotation_q30(f, k, i);
            } else { /* the rows read the low-pass's error, not the attitude's */
                h[LOWPASS_ERROR + i] = h[ATT + i];
                h[ATT + i] = 0;
            }
        }
        scalar_update(f, h, z, r, 52, f->acc_weight, map, dx);
    }
    if (nine && f->at_rest) { /* (in motion it would correct nothing) */
        imu_real_t c_norm; /* |c|, g, Q30 */
        imu_q30_t second_order;
        if (imu_vec3_normalize(c, NULL, &c_norm) && norm_second_order(f, up, &second_order)) {
            const imu_q30_t z = IMU_SUB_SAT(IMU_SUB_SAT(c_norm, IMU_ONE_Q30, &f->saturations), second_order,
                                            &f->saturations);
            for (i = 0; i < 6; ++i) {
                h[i] = 0;
            }
            for (i = 0; i < 3; ++i) {
                h[ACC_BIAS + i] = lowpass_rotation_q30(f, 2, i);
            }
            scalar_update(f, h, z, r, 52, f->acc_weight, map, dx);
        }
    }
}

/** Attitude error variance back to init_attitude_std^2, its correlations cleared. */
static void restart_attitude_uncertainty(imu_eskf_t *f)
{
    const imu_wide_t var = IMU_WMUL(f->settings.init_attitude_std, f->settings.init_attitude_std); /* Q56 */
    int k;
    for (k = 0; k < 3; ++k) {
        imu_cov_reset_state(&f->cov, ATT + k, var, 56, &f->saturations);
    }
    f->lowpass_settled = 0; /* its earth frame was the lost one */
    f->acc_held_valid = 0;
}

/**
 * Weight (Q30) of a field of norm `norm` (uT, Q16) and dip `dip` against a reference
 * field: the product of the norm and dip deviation weights; *w_norm gets the first.
 */
static imu_q30_t field_weight(imu_eskf_t *f, imu_q16_t norm, imu_angle_t dip, const imu_eskf_field_t *ref,
                              imu_q30_t *w_norm)
{
    const imu_eskf_settings_t *st = &f->settings;
    return imu_field_weight(norm, reference_norm(ref), dip, reference_dip(ref), IMU_SHR(st->mag_tolerance, 6),
                            IMU_SHR(st->dip_tolerance, 6), w_norm, &f->saturations);
}

/** field <- field + rate (target - field) for the norm (Q16) and dip (Q29, within +-pi/2);
 *  rate Q30 in [0, 1]. */
static void follow_field(imu_eskf_field_t *field, imu_q16_t norm, imu_angle_t dip, imu_q30_t rate)
{
    field->norm += IMU_WMUL(rate, IMU_SUB(norm, reference_norm(field))); /* both below 2^28 */
    field->dip += IMU_WMUL(rate, IMU_SUB(dip, reference_dip(field)));
}

/**
 * A disturbed field: track it as a candidate reference; it becomes the reference as
 * NEW_FIELD_MIN_RATE's comment says. (Aligning the heading to the new field at once, so that
 * its turn is not learnt as gyro bias, was tried: in the 24 h soak the earth's own field,
 * taken back after an hour's accelerations had moved the reference's dip, then turned the
 * heading by up to 19 deg, from one mean of three samples in motion.)
 */
static void track_candidate(imu_eskf_t *f, imu_q16_t norm, imu_angle_t dip)
{
    imu_q30_t w_norm;
    if (f->cand.norm > 0 && field_weight(f, norm, dip, &f->cand, &w_norm) >= IMU_QCONST(0.5, 30)) {
        follow_field(&f->cand, norm, dip, IMU_MUL(f->period, LEARN_RATE, 30));
        if (imu_field_trust_hold(&f->trust, f->turning, f->new_field_steps)) {
            f->ref = f->cand;
            f->cand.norm = 0;
        }
    } else if (norm >= MIN_REF_FIELD && norm <= MAX_REF_FIELD) {
        set_reference(&f->cand, norm, dip);
        imu_field_trust_drop(&f->trust);
    }
}

/** The heading (roll and pitch kept) from the field: the reference was just acquired. */
static void align_heading(imu_eskf_t *f, const imu_q16_t mag[3])
{
    imu_angle_t euler[3];
    imu_quat_to_euler(f->q, euler);
    euler[2] = imu_heading_from_mag(mag, euler[0], euler[1]);
    imu_euler_to_quat(euler, f->q);
}

/** Heading measurement from the horizontal field; learns and tracks the field reference. */
static void heading_update(imu_eskf_t *f, const imu_q16_t mag[3], const imu_rotation_t *rot, imu_q30_t dx[9])
{
    const imu_eskf_settings_t *st = &f->settings;
    const imu_q30_t *north = rot->row[1], *up = rot->row[2];
    imu_q30_t earth[3], horizontal;
    imu_q16_t norm;
    imu_angle_t dip;
    imu_q30_t h[9], z, sigma, w_norm;
    imu_cov_map_t gain_map;
    int i;
    f->mag_weight = 0;
    if (f->ref.norm <= 0) {
        /* No reference yet (a magnetometer that read zeros or nonsense so far). */
        if (acquire_reference(f, rot, mag)) {
            align_heading(f, mag);
            restart_attitude_uncertainty(f);
        }
        return;
    }
    if (!field_norm_dip(rot, mag, &norm, &dip, earth, &horizontal) || horizontal < MIN_HORIZONTAL_FIELD) {
        return;
    }
    f->mag_weight = field_weight(f, norm, dip, &f->ref, &w_norm);
    if (f->steps < f->learn_steps) {
        /* Learning: the first norm and dip came from one sample and an unconverged
         * attitude; follow the measured ones quickly (time constant 1 s) and let only
         * the norm gate. */
        follow_field(&f->ref, norm, dip, IMU_MUL(f->period, LEARN_RATE, 30));
        f->mag_weight = w_norm;
    } else if (f->mag_weight >= IMU_QCONST(0.5, 30)) {
        /* Undisturbed: follow slow changes of the reference (time constant 30 s). */
        follow_field(&f->ref, norm, dip, IMU_MUL(f->period, REF_RATE, 30));
        f->cand.norm = 0;
        imu_field_trust_confirm(&f->trust, f->turning, f->trust_limit_steps);
    } else {
        track_candidate(f, norm, dip);
    }
    if (f->mag_weight == 0) {
        return;
    }
    /* sigma = mag_noise / |m|, Q16 / Q16 -> Q24: the noise of the unit field's east share.
     * A horizontal field below 1/64 of the noise carries no heading information (and
     * sigma stays below 64). */
    if (IMU_MUL(horizontal, norm, 30) <= IMU_MUL(st->mag_noise, IMU_QCONST(1.0 / 64.0, 30), 30)) {
        return;
    }
    sigma = IMU_DIV_SAT(st->mag_noise, norm, 24, &f->saturations);
    /* z = m_H psi: the unit field's horizontal share m_H times the heading error psi, the
     * angle of the horizontal field from the estimate's north (up to 1 rad: beyond it the
     * steps that follow do the rest). Near zero it is the east share m_E = m_H sin(psi);
     * unlike m_E it grows with psi up to a half turn (the east share's sine, linearised with
     * the measured north share m_N = m_H cos(psi), made a heading error beyond 90 deg turn
     * on to 180 deg). An attitude error dtheta (sensor frame) moves z by
     * (m_H up - m_U north) . dtheta: the heading error and, through the field's vertical
     * part, the tilt error, which H must include (left out, a constant tilt error would
     * pass for heading information: tan(dip) times it). The gain map lets the update
     * correct only the vertical components of the attitude and the gyro bias, so that
     * the magnetometer cannot tilt the estimate, and P keeps the tilt's uncertainty.
     *
     * The gyro bias only from a field that matches the reference (BIAS_FIELD_WEIGHT), and
     * not at rest (the rest update's): a field a little off in norm or dip is disturbed,
     * and a disturbance whose direction changes with the orientation (a magnet on the
     * board, steel nearby) is no white noise: taught to the vertical bias, it tilted the
     * estimate once the board turned that axis away from the vertical (tools/eval_rough.py
     * `attached-magnet`: inclination 0.32 deg with the bias from every field, 0.23 deg with
     * this rule; VQF 0.15 deg). A down-weighted field still corrects the heading. */
    for (i = 0; i < 9; ++i) {
        h[i] = 0;
    }
    for (i = 0; i < 3; ++i) {
        h[ATT + i] = IMU_SUB(IMU_MUL(horizontal, up[i], 30), IMU_MUL(earth[2], north[i], 30)); /* |h| <= |m| = 1 */
    }
    set_gain_map(&gain_map, 1, !f->at_rest && f->mag_weight >= BIAS_FIELD_WEIGHT, 0, up);
    {
        const imu_angle_t one_rad = IMU_QCONST(1.0, 29);
        imu_angle_t psi = imu_atan2(earth[0], earth[1]); /* Q29 rad */
        psi = psi > one_rad ? one_rad : (psi < -one_rad ? -one_rad : psi);
        z = IMU_MUL(horizontal, psi, 29); /* Q30 * Q29 >> 29 -> Q30, at most 1 */
    }
    /* The innovation is the field seen through the estimated tilt, and while the earth-frame
     * low-pass is starting the tilt is known no better than its start noise, which P does
     * not hold (a start while shaken: the first sample's tilt error times tan(dip) as
     * heading): the heading update takes the gravity updates' start weight too. */
    scalar_update(f, h, z, IMU_WMUL(sigma, sigma), 48, start_weight(f, f->mag_weight), &gain_map, dx);
}

/**
 * Weight of the newest value in the earth-frame low-pass (Q30), and lowpass_settled moved
 * on past it. While the mean of the values so far weighs the newest one more than the
 * exponential low-pass's alpha, the low-pass is that mean: started from one value it
 * would keep e^(-t/acc_lowpass) of it, and a start in motion kept its first linear
 * acceleration as a tilt for seconds (72 % of it after 1 s at 3 s), long enough for the
 * gravity updates to teach it to the gyro bias (tests/test_eskf.py, start in motion).
 * With s = alpha / (2 - alpha) and u = lowpass_settled: the mean of n values has noise
 * 1 / n (u = n s) and weighs the next s / (u + s) = 1 / (n + 1); then u <- u + s. The
 * exponential low-pass's noise v <- (1 - alpha)^2 v + alpha^2 makes u <- u / (q + (1 - q) u),
 * q = (1 - alpha)^2, which rises to 1 (kept in this form: u near 1 has all its bits).
 */
static imu_q30_t lowpass_weight(imu_eskf_t *f)
{
    const imu_q30_t u = f->lowpass_settled;
    imu_q30_t steady, mean_weight;
    if (u >= IMU_ONE_Q30) {
        return f->acc_alpha; /* settled: the usual case, no division */
    }
    if (f->acc_alpha >= IMU_ONE_Q30) {
        f->lowpass_settled = IMU_ONE_Q30; /* no low-pass (acc_lowpass 0): each value is whole */
        return f->acc_alpha;
    }
    steady = imu_lowpass_noise_share(f->acc_alpha, &f->saturations);
    mean_weight = IMU_DIV_SAT(steady, IMU_ADD_SAT(u, steady, &f->saturations), 30, &f->saturations);
    if (mean_weight > f->acc_alpha) {
        f->lowpass_settled = IMU_ADD_SAT(u, steady, &f->saturations);
        return mean_weight;
    }
    {
        const imu_q30_t keep = IMU_SUB(IMU_ONE_Q30, f->acc_alpha);
        const imu_q30_t q = IMU_MUL(keep, keep, 30);
        const imu_q30_t den = IMU_ADD(q, IMU_MUL(IMU_SUB(IMU_ONE_Q30, q), u, 30)); /* in [u, 1] */
        const imu_q30_t next = IMU_DIV_SAT(u, den, 30, &f->saturations);
        /* u approaches 1 only asymptotically: within 2^-16 it is 1 */
        f->lowpass_settled = next >= SETTLED ? IMU_ONE_Q30 : next;
    }
    return f->acc_alpha;
}

/**
 * Low-pass a group's specific force in the estimated earth frame (`earth`, m/s^2, Q16), where
 * rotations do not change gravity but a back-and-forth translation averages out (time
 * constant acc_lowpass; at its start the mean: lowpass_weight). With 9 states the rotation R
 * is low-passed alike (lowpassed_bias; rot, the estimate of the group's time: NULL with 6 states).
 * Returns the weight the group took, Q30.
 */
static imu_q30_t lowpass_take(imu_eskf_t *f, const imu_rotation_t *rot, const imu_q16_t earth[3])
{
    const int first = f->lowpass_settled == 0;
    const imu_q30_t weight = lowpass_weight(f);
    int r, k;
    for (r = 0; r < 3; ++r) {
        /* weight (Q30) * (earth - smooth) (Q16, both within 1774 m/s^2) -> Q46. */
        f->acc_earth[r] = first ? IMU_WMUL(earth[r], IMU_ONE_Q30)
                                : f->acc_earth[r] + IMU_WMUL(weight, IMU_SUB(earth[r], acc_earth_q16(f, r)));
    }
    if (imu_eskf_state_count(f) == 9) {
        /* The same low-pass of R: Q30 * Q29 -> Q59 (halved: a difference of rotations reaches 2). */
        for (r = 0; r < 3; ++r) {
            for (k = 0; k < 3; ++k) {
                f->lowpass_rotation[r][k] =
                    first ? IMU_WMUL(rot->row[r][k], IMU_QCONST(1.0, 29))
                          : f->lowpass_rotation[r][k] + IMU_WMUL(weight, IMU_SUB(IMU_SHR(rot->row[r][k], 1),
                                                                                 IMU_SHR(lowpass_rotation_q30(f, r, k), 1)));
            }
        }
    }
    return first ? IMU_ONE_Q30 : weight;
}

/**
 * A knock that clips the accelerometer holds no gravity information in its clipped samples,
 * and none in the rest of it either: its pulse rings on both sides of the clipped samples (side
 * lobes, the sensor's own low-pass), and with the clipped part missing, what the low-pass took
 * of it no longer averaged out; an unbalanced force that read as a tilt (tools/eval_rough.py,
 * `shocks`). So a group is held (hold_specific_force) and enters the low-pass one filter step
 * late, once the next group showed no clipping; the group after a clipped one does not enter.
 * At the start of a filter step, before the estimate moves on: the held group enters unless
 * this step's group clipped. Returns the weight it took (Q30; 0: none).
 */
static imu_q30_t take_held_specific_force(imu_eskf_t *f)
{
    imu_rotation_t rot; /* the estimate of the held group's time (with its correction) */
    const imu_rotation_t *rotation = NULL; /* only the low-pass of R reads it (9 states) */
    if ((f->clipped & IMU_CLIPPED_ACC) != 0) {
        f->acc_held_valid = 0; /* its neighbour clipped: dropped */
        return 0;
    }
    if (!f->acc_held_valid) {
        return 0;
    }
    if (imu_eskf_state_count(f) == 9) {
        imu_quat_rotation(f->q, &rot);
        rotation = &rot;
    }
    return lowpass_take(f, rotation, f->acc_held);
}

/** Hold the step's group (sensor frame, m/s^2, Q16) in the estimated earth frame of its time,
 *  rot (take_held_specific_force). */
static void hold_specific_force(imu_eskf_t *f, const imu_rotation_t *rot, const imu_q16_t acc[3])
{
    if ((f->clipped & IMU_CLIPPED_ACC) != 0) {
        return;
    }
    imu_rotation_apply(rot, acc, f->acc_held); /* Q30 * Q16 >> 30 -> Q16; |R a| = |a| */
    f->acc_held_valid = (f->clipped & AFTER_ACC_CLIP) == 0;
}

/** The low-passed specific force in the sensor frame: R^T lp, m/s^2, Q16. */
static void lowpassed_specific_force(const imu_eskf_t *f, const imu_rotation_t *rot, imu_q16_t acc[3])
{
    imu_q16_t smooth[3];
    int k;
    for (k = 0; k < 3; ++k) {
        smooth[k] = acc_earth_q16(f, k);
    }
    for (k = 0; k < 3; ++k) {
        acc[k] = IMU_ADD(IMU_ADD(IMU_MUL(rot->row[0][k], smooth[0], 30), IMU_MUL(rot->row[1][k], smooth[1], 30)),
                         IMU_MUL(rot->row[2][k], smooth[2], 30));
    }
}

/**
 * The group held for the low-pass (hold_specific_force) after the estimate turned by dtheta
 * (sensor frame, Q30, at most 1 rad): it turns with the estimated earth frame, v <- v +
 * (R dtheta) x v, so that its error stays the attitude's, which the low-pass's error takes
 * with it (lowpass_error_states). Q30 * Q16 >> 30 -> Q16: a held group (at most 1774 m/s^2)
 * lengthened by up to sqrt(2), once.
 */
static void turn_held(imu_eskf_t *f, const imu_rotation_t *rot, const imu_q30_t dtheta[3])
{
    imu_q30_t u[3];
    imu_q16_t v[3];
    int k;
    if (!f->acc_held_valid) {
        return;
    }
    imu_rotation_apply(rot, dtheta, u);
    for (k = 0; k < 3; ++k) {
        v[k] = f->acc_held[k];
    }
    f->acc_held[0] += IMU_SUB(IMU_MUL(u[1], v[2], 30), IMU_MUL(u[2], v[1], 30));
    f->acc_held[1] += IMU_SUB(IMU_MUL(u[2], v[0], 30), IMU_MUL(u[0], v[2], 30));
    f->acc_held[2] += IMU_SUB(IMU_MUL(u[0], v[1], 30), IMU_MUL(u[1], v[0], 30));
}

/**
 * The low-passed specific force after a turn by dtheta (sensor frame, Q30, at most 1 rad):
 * v <- v + (R dtheta) x v; the estimate's correction with 9 states, the low-pass's own error's
 * correction with 6 (lowpass_error_states). The first-order turn lengthens v by up to sqrt(2)
 * per call: kept within the inputs' limit, which a low-passed specific force cannot leave
 * (and so that R^T v fits Q16 in lowpassed_specific_force).
 */
static void turn_acc_earth(imu_eskf_t *f, const imu_rotation_t *rot, const imu_q30_t dtheta[3])
{
    const imu_wide_t limit = IMU_WMUL(INPUT_LIMIT, IMU_ONE_Q30);
    imu_q30_t u[3];
    imu_q16_t v[3];
    int k;
    if (f->lowpass_settled == 0) {
        return; /* nothing to turn: the next low-pass starts afresh (and rot may be of an older attitude) */
    }
    imu_rotation_apply(rot, dtheta, u);
    for (k = 0; k < 3; ++k) {
        v[k] = acc_earth_q16(f, k);
    }
    /* Q30 * Q16 -> Q46, each product below 2^57. */
    f->acc_earth[0] += IMU_WMUL(u[1], v[2]) - IMU_WMUL(u[2], v[1]);
    f->acc_earth[1] += IMU_WMUL(u[2], v[0]) - IMU_WMUL(u[0], v[2]);
    f->acc_earth[2] += IMU_WMUL(u[0], v[1]) - IMU_WMUL(u[1], v[0]);
    for (k = 0; k < 3; ++k) {
        f->acc_earth[k] = f->acc_earth[k] > limit ? limit : (f->acc_earth[k] < -limit ? -limit : f->acc_earth[k]);
    }
    if (imu_eskf_state_count(f) != 9) {
        return;
    }
    for (k = 0; k < 3; ++k) {
        /* column k of the low-passed rotation, an earth vector, turns alike: Q30 * Q30 -> Q60 >> 1 -> Q59 */
        const imu_wide_t one = IMU_WMUL(IMU_ONE_Q30, IMU_QCONST(1.0, 29)); /* 1 in Q59 */
        imu_q30_t m[3];
        int r;
        for (r = 0; r < 3; ++r) {
            m[r] = lowpass_rotation_q30(f, r, k);
        }
        f->lowpass_rotation[0][k] += IMU_WSHR(IMU_WMUL(u[1], m[2]) - IMU_WMUL(u[2], m[1]), 1);
        f->lowpass_rotation[1][k] += IMU_WSHR(IMU_WMUL(u[2], m[0]) - IMU_WMUL(u[0], m[2]), 1);
        f->lowpass_rotation[2][k] += IMU_WSHR(IMU_WMUL(u[0], m[1]) - IMU_WMUL(u[1], m[0]), 1);
        for (r = 0; r < 3; ++r) { /* a mean of rotations' elements is within +-1; the first-order turn is not */
            imu_wide_t *const e = &f->lowpass_rotation[r][k];
            *e = *e > one ? one : (*e < -one ? -one : *e);
        }
    }
}

/** A turn (rad, wide Q30) within +-0.5 rad, beyond JUMP_TURN's reach. */
static imu_q30_t limit_turn(imu_wide_t turn)
{
    const imu_wide_t half = IMU_ONE_Q30 / 2;
    return (imu_q30_t)(turn > half ? half : (turn < -half ? -half : turn));
}

/**
 * 1 when the rotation `turn` (rad, Q30) would have turned gravity or the field in the sensor
 * frame (their low-passes) by more than JUMP_TURN: a rotation the rest detector's turn
 * tests would have seen. Without a field, a rotation about gravity is seen by nothing, so
 * its length counts.
 */
static int turn_seen_by_rest(const imu_eskf_t *f, const imu_q30_t turn[3])
{
    const imu_wide_t limit = IMU_WMUL(JUMP_TURN, JUMP_TURN); /* Q60 */
    imu_q30_t unit[3], across[3];
    imu_real_t norm;
    int pass, k;
    for (pass = 0; pass < 2; ++pass) {
        imu_wide_t sum = 0; /* Q60 */
        if (imu_vec3_normalize(pass == 0 ? imu_rest_acc(&f->rest) : imu_rest_field(&f->rest), unit, &norm)) {
            imu_vec3_cross(turn, unit, across);
        } else if (pass == 1) {
            for (k = 0; k < 3; ++k) {
                across[k] = turn[k];
            }
        } else {
            continue;
        }
        for (k = 0; k < 3; ++k) {
            sum += IMU_WMUL(across[k], across[k]);
        }
        if (sum > limit) {
            return 1;
        }
    }
    return 0;
}

/** The low-passed rate's deviation from the bias estimate, rad/s, Q30: at rest, what the
 *  gyroscope reads of the bias error (the rest detector's rate test keeps it below 2 deg/s). */
static void rest_rate_deviation(imu_eskf_t *f, imu_q30_t z[3])
{
    const imu_rate_t *rate = imu_rest_rate(&f->rest);
    int k;
    for (k = 0; k < 3; ++k) { /* Q24 -> Q30 minus the bias, Q30 */
        z[k] = IMU_SUB_SAT(IMU_SHL_SAT(rate[k], 6, &f->saturations), f->gyro_bias[k], &f->saturations);
    }
}

/**
 * At rest, a bias that jumped (a knock, a mount that shifted, a temperature step): a
 * random walk, the bias model, makes no jumps, and the bias variance it leaves (0.005 deg/s
 * after a minute of rest with the default gyro_rrw) made the rest measurement learn a
 * 0.5 deg/s jump with a time constant of 90 s while the tilt drifted (tools/eval_rough.py,
 * `gyro-bias-step`). A deviation z of the low-passed rate from the bias estimate, in
 * component k beyond JUMP_SIGMAS standard deviations of what the model predicts (P_kk plus
 * the noise of the low-passed rate, imu_rest_rate_noise_share), is such a jump: each
 * component's standard deviation is doubled (its correlations kept, imu_cov_scale_up) until
 * it reaches |z_k| / 2 (a jump's other components may be just short of the limit: the
 * low-passed rate's noise), and the rest update that follows learns it within a few steps.
 *
 * The onset of a slow steady rotation looks the same for the second or so its turn takes
 * to fail the rest detector's turn tests (a 1 deg/s turn about the vertical turns the
 * field by 0.4 deg/s): learnt as a jump, it left 0.7 deg/s of bias. A jump turns neither
 * gravity nor the field, a rotation does. So the rotation z reads from the step it first
 * shows a jump, while the turn tests hold their references (jump_turn), is a jump only once
 * it would have turned one of them by more than the tests let pass (turn_seen_by_rest), and
 * then the attitude takes that rotation back, with the low-pass's lag: the board did not
 * turn.
 */
static void check_bias_jump(imu_eskf_t *f, imu_q30_t dx[9])
{
    int doublings[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    imu_wide_t noise;
    imu_q30_t z[3];
    int k, jumped = 0;
    if (!imu_rest_unturned(&f->rest)) {
        f->jump_turn[0] = f->jump_turn[1] = f->jump_turn[2] = 0;
        return;
    }
    /* rest_var (Q48, below 2^60) in Q33 times the share in Q15 (in (0, 1]) -> Q48 */
    noise = IMU_WSHR(f->rest_var, 15) * IMU_SHR(imu_rest_rate_noise_share(&f->rest, &f->saturations), 15);
    rest_rate_deviation(f, z);
    for (k = 0; k < 3; ++k) {
        const imu_wide_t zz = IMU_WSHR(IMU_WMUL(z[k], z[k]), 12); /* Q60 -> Q48, below 2^50 */
        imu_wide_t var = imu_cov_element_wide(&f->cov, GYRO_BIAS + k, GYRO_BIAS + k, 48, &f->saturations);
        if (zz / (JUMP_SIGMAS * JUMP_SIGMAS) - noise > var) { /* (no sum to overflow) */
            jumped = 1;
        }
        while (doublings[GYRO_BIAS + k] < 16 && var < zz / 4) {
            var *= 4;
            ++doublings[GYRO_BIAS + k];
        }
    }
    for (k = 0; k < 3; ++k) { /* rad/s Q30 * s Q30 >> 30 -> rad Q30 */
        f->jump_turn[k] = jumped ? limit_turn(f->jump_turn[k] + IMU_WSHR(IMU_WMUL(z[k], f->period), 30)) : 0;
    }
    if (f->at_rest && jumped && turn_seen_by_rest(f, f->jump_turn)) {
        /* The low-pass's time constant plus the period, s, Q24: the rate's integral exceeds its
         * low-pass's (lp += alpha (rate - lp)) by that times the low-pass's change, here z. */
        const imu_rate_t lag = IMU_ADD(imu_rest_default_config.tau, IMU_SHR(f->period, 6));
        imu_cov_scale_up(&f->cov, doublings);
        for (k = 0; k < 3; ++k) { /* the board did not turn: the attitude takes that rotation back */
            const imu_q30_t turned = IMU_ADD_SAT(f->jump_turn[k], IMU_MUL(z[k], lag, 24), &f->saturations);
            dx[ATT + k] = IMU_SUB_SAT(dx[ATT + k], turned, &f->saturations);
            f->jump_turn[k] = 0;
        }
    }
}

/**
 * At rest the gyroscope reads its bias: z = low-passed rate - bias estimate, H = I on the
 * gyro-bias states, variance arw^2 / T: the noise of one filter period's mean rate (the
 * low-passed rate has less, arw^2 / (2 tau), but consecutive steps share it: counted once
 * per step it would make the bias look known far better than it is). A jump of the bias
 * first widens its variance (check_bias_jump).
 *
 * The same gyroscope noise also drives the propagated attitude, which gravity and the
 * field observe: were both measurements let correct the bias, its noise would count
 * twice and the bias would look known better than it is (gyro-bias NEES 1.4-1.5 per
 * degree of freedom at rest). So at rest the bias is this measurement's alone, and this
 * measurement corrects the bias alone (gain maps: P stays that of the corrections made).
 */
static void rest_update(imu_eskf_t *f, imu_q30_t dx[9])
{
    imu_q30_t z[3];
    imu_q30_t h[9];
    imu_cov_map_t gain_map;
    int k, i;
    rest_rate_deviation(f, z);
    set_gain_map(&gain_map, 0, 1, 0, NULL);
    for (k = 0; k < 3; ++k) {
        for (i = 0; i < 9; ++i) {
            h[i] = 0;
        }
        h[GYRO_BIAS + k] = IMU_ONE_Q30;
        scalar_update(f, h, z[k], f->rest_var, 48, IMU_ONE_Q30, &gain_map, dx);
    }
}

/** 1 when a rotation vector (wide Q30) is longer than `angle` (Q30 rad). */
static int longer_than(const imu_wide_t phi[3], imu_q30_t angle)
{
    imu_wide_t sum = 0; /* Q60: three squares below 2^60 each */
    int k;
    for (k = 0; k < 3; ++k) {
        if (phi[k] >= IMU_ONE_Q30 || phi[k] <= -IMU_ONE_Q30) {
            return 1;
        }
        sum += IMU_WMUL((imu_q30_t)phi[k], (imu_q30_t)phi[k]);
    }
    return sum > IMU_WMUL(angle, angle);
}

/**
 * A group's mean from its sum (same Q format, |sum| < 2^31 - 1), rounded to nearest: a
 * truncating division pulls every mean towards zero by a third of an LSB on average, an
 * error the slow states (the low-passed specific force, the field reference) keep
 * instead of averaging it out.
 */
static imu_real_t mean_of_three(imu_real_t sum)
{
#ifdef IMU_FIXED
    return (sum >= 0 ? sum + 1 : sum - 1) / 3;
#else
    return sum / 3;
#endif
}

/** One filter step at the end of a group of three samples. */
static void filter_step(imu_eskf_t *f)
{
    imu_rotation_t rot; /* R(q) of the updates: q changes only when they are injected */
    imu_q30_t dx[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    imu_q16_t acc[3], mag[3];
    const imu_q30_t taken = take_held_specific_force(f); /* its weight in the low-pass, Q30 */
    int k;
    { /* (block scopes: their arrays share stack with the updates') */
        imu_wide_t phi[3];
        imu_q30_t dq[4], q_prev[4], turn[4];
        rotation_vector(f->increments, phi);
        rotation_quaternion(phi, dq);
        for (k = 0; k < 4; ++k) {
            q_prev[k] = f->q[k];
        }
        imu_quat_mul(q_prev, dq, f->q);
        imu_quat_normalize(f->q);
        /* The error state lives in the estimate's frame, which turned by the last correction
         * and by this step's rotation: P turns with both. (Turned by the step alone, P's
         * unobservable heading direction lags the estimated vertical after every tilt
         * correction, and the gravity updates then shrink the heading variance although
         * they carry no heading information: without a magnetometer the filter becomes
         * overconfident in heading. The first-order reset I - [dtheta/2 x] halves that.) */
        imu_quat_mul(f->injected, dq, turn);
        if (lowpass_error_states(f)) {
            predict_lowpass_error(f, turn, taken);
        }
        predict_covariance(f, turn, phi);
        f->turning = longer_than(phi, IMU_MUL(NEW_FIELD_MIN_RATE, f->period, 30));
    }
    {
        imu_rate_t gyr[3], bias[3];
        for (k = 0; k < 3; ++k) {
            acc[k] = mean_of_three(f->acc_sum[k]);
            mag[k] = mean_of_three(f->mag_sum[k]);
            f->acc_sum[k] = 0;
            f->mag_sum[k] = 0;
            gyr[k] = IMU_SHL_SAT(mean_of_three(f->gyr_sum[k]), 2, &f->saturations); /* Q22 -> Q24 */
            f->gyr_sum[k] = 0;
            bias[k] = IMU_SHR(f->gyro_bias[k], 6);
        }
        /* Rest: still, and the specific force is gravity (not free fall). */
        f->at_rest = imu_rest_update(&f->rest, gyr, bias, acc, mag, &f->saturations) &&
                     (f->clipped & (IMU_CLIPPED_GYR | IMU_CLIPPED_ACC)) == 0 && near_gravity(f, acc);
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
    imu_quat_rotation(f->q, &rot);
    hold_specific_force(f, &rot, acc);
    if ((f->clipped & IMU_CLIPPED_ACC) == 0 && f->lowpass_settled != 0) {
        lowpassed_specific_force(f, &rot, acc);
        gravity_update(f, acc, &rot, dx);
    } else {
        f->acc_weight = 0;
    }
    if ((f->clipped & IMU_CLIPPED_MAG) == 0) {
        heading_update(f, mag, &rot, dx);
    } else {
        f->mag_weight = 0;
    }
    check_bias_jump(f, dx);
    if (f->at_rest) {
        rest_update(f, dx);
    }
    f->clipped = (f->clipped & IMU_CLIPPED_ACC) != 0 ? AFTER_ACC_CLIP : 0;
    /* Inject and reset the error state; the low-passed specific force follows the
     * estimated earth frame's correction (exp(R dtheta)). A correction beyond a radian
     * is no small error: it is limited to one radian (the next steps do the rest). */
    limit_to_one_radian(&dx[ATT]);
    turn_held(f, &rot, &dx[ATT]);
    if (lowpass_error_states(f)) {
        /* the low-pass itself is corrected by L's correction, which leaves L's error at zero */
        limit_to_one_radian(&dx[LOWPASS_ERROR]);
        turn_acc_earth(f, &rot, &dx[LOWPASS_ERROR]);
    } else {
        turn_acc_earth(f, &rot, &dx[ATT]);
    }
    imu_quat_integrate(f->q, &dx[ATT]);
    imu_quat_from_rotation(f->injected, &dx[ATT]);
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

/** A specific force or field clamped to +-INPUT_LIMIT; `bit` is set in *clipped when it was beyond. */
static void clamp_input(const imu_q16_t in[3], imu_q16_t out[3], unsigned bit, unsigned *clipped)
{
    int k;
    for (k = 0; k < 3; ++k) {
        out[k] = in[k] > INPUT_LIMIT ? INPUT_LIMIT : (in[k] < -INPUT_LIMIT ? -INPUT_LIMIT : in[k]);
        if (out[k] != in[k]) {
            *clipped |= bit;
        }
    }
}

/** This sample's bias-corrected gyro increment, rad, Q30, at most 1 rad. */
static void gyro_increment(imu_eskf_t *f, const imu_rate_t gyr[3], imu_q30_t theta[3])
{
    imu_wide_t wide[3]; /* Q30 rad: |rate| < 130 rad/s times dt < 1/30 s */
    int big = 0, k;
    for (k = 0; k < 3; ++k) {
        /* Bias-corrected rate (Q24 - Q30 >> 6) times dt (Q30) >> 24 -> rad Q30. */
        const imu_rate_t w = IMU_SUB_SAT(gyr[k], IMU_SHR(f->gyro_bias[k], 6), &f->saturations);
        wide[k] = IMU_WSHR(IMU_WMUL(w, f->dt), 24);
        big = big || wide[k] >= IMU_ONE_Q30 || wide[k] <= -IMU_ONE_Q30;
    }
    for (k = 0; k < 3; ++k) {
        /* Beyond 1 rad per sample a quarter keeps the direction and fits Q30 (below 1.1 rad). */
        theta[k] = (imu_q30_t)(big ? wide[k] / 4 : wide[k]);
    }
    limit_to_one_radian(theta);
}

void imu_eskf_update(imu_eskf_t *f, const imu_sample_t *s)
{
    imu_q16_t acc[3], mag[3];
    imu_q30_t *theta;
    int k;
    unsigned clipped = s->clipped;
    clamp_input(s->acc, acc, IMU_CLIPPED_ACC, &clipped);
    clamp_input(s->mag, mag, IMU_CLIPPED_MAG, &clipped);
    if (!f->initialised) {
        imu_sample_t first = *s;
        for (k = 0; k < 3; ++k) {
            first.acc[k] = acc[k];
            first.mag[k] = mag[k];
        }
        first.clipped = clipped;
        initialise(f, &first);
        return;
    }
    theta = f->increments[f->in_group];
    gyro_increment(f, s->gyr, theta);
    /* The group's sums are kept in the frame of the latest sample: rotate them by
     * this sample's increment (v <- v - theta x v) before adding the new values, so
     * the measurement matches the attitude at the end of the group. */
    imu_vec3_turn_back(f->acc_sum, theta); /* Q16, below 2^29; theta at most 1 rad */
    imu_vec3_turn_back(f->mag_sum, theta);
    for (k = 0; k < 3; ++k) {
        f->acc_sum[k] = IMU_ADD_SAT(f->acc_sum[k], acc[k], &f->saturations);
        f->mag_sum[k] = IMU_ADD_SAT(f->mag_sum[k], mag[k], &f->saturations);
        f->gyr_sum[k] = IMU_ADD(f->gyr_sum[k], IMU_SHR(s->gyr[k], 2)); /* three below 2^29 each */
    }
    f->clipped |= clipped;
    if (++f->in_group == 3) {
        f->in_group = 0;
        filter_step(f); /* the output becomes the step's estimate */
    } else {
        imu_quat_integrate(f->q_out, theta); /* the output follows the gyroscope until the step */
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

void imu_eskf_get_acc_bias(const imu_eskf_t *f, imu_real_t acc_bias[3])
{
    int k;
    for (k = 0; k < 3; ++k) {
        /* g units Q30 * g (Q24) >> 30 -> m/s^2 Q24. */
        acc_bias[k] = IMU_MUL(f->acc_bias[k], f->settings.gravity, 30);
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
