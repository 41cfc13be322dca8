/**
 * @file imu_kf1d.c
 * @brief Per-axis angle/bias Kalman filter (see imu_kf1d.h).
 */
#include "imu_kf1d.h"

#include "imu_math.h"

enum { ROLL = 0, PITCH = 1, HEADING = 2 };

const imu_kf1d_settings_t imu_kf1d_default_settings = {
    IMU_QCONST(100.0, 16), /* sample_rate, Hz */
    IMU_QCONST(2e-4, 40),  /* q_angle, rad^2/s (tuned on BROAD under the fixed-vs-float bound) */
    IMU_QCONST(3e-8, 48),  /* q_bias, rad^2/s^3 (tuned, docs/accuracy.md) */
    IMU_QCONST(0.03, 35),  /* r_angle, rad^2 (tuned) */
    IMU_QCONST(0.03, 35),  /* r_heading, rad^2 (tuned) */
    IMU_QCONST(0.2, 24),   /* acc_tolerance, m/s^2: 10 sigma of the accelerometer noise, as the EECF's */
};

/* Each field with its Q format, unit and accepted range [lo, hi] in the unit. */
#define DESC(field, q, unit, lo, hi) \
    {#field, offsetof(imu_kf1d_settings_t, field), q, unit, IMU_QCONST(lo, q), IMU_QCONST(hi, q)}
const imu_setting_desc_t imu_kf1d_setting_descs[] = {
    DESC(sample_rate, 16, "Hz", 10.0, IMU_Q16_LARGEST),
    DESC(q_angle, 40, "rad^2/s", 0.0, 1e-3),
    DESC(q_bias, 48, "rad^2/s^3", 0.0, 5e-6),
    DESC(r_angle, 35, "rad^2", 1e-6, 0.03),
    DESC(r_heading, 35, "rad^2", 1e-6, 0.03),
    DESC(acc_tolerance, 24, "m/s^2", IMU_Q24_SMALLEST, 1.9),
};
#undef DESC
const int imu_kf1d_setting_count = (int)(sizeof imu_kf1d_setting_descs / sizeof imu_kf1d_setting_descs[0]);

/** Initial bias variance: (0.5 deg/s)^2 in rad^2/s^2, Q42. */
#define INITIAL_BIAS_VARIANCE IMU_QCONST(7.6e-5, 42)

void imu_kf1d_init(imu_kf1d_t *f)
{
    (void)imu_kf1d_set_settings(f, &imu_kf1d_default_settings);
}

imu_status_t imu_kf1d_set_settings(imu_kf1d_t *f, const imu_kf1d_settings_t *s)
{
    int k;
    if (imu_settings_check(imu_kf1d_setting_descs, imu_kf1d_setting_count, s) != IMU_OK) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations);
    f->initialised = 0;
    f->quat[0] = IMU_ONE_Q30;
    f->quat[1] = f->quat[2] = f->quat[3] = 0;
    f->bias_noise_residual = 0;
    for (k = 0; k < 3; ++k) {
        f->axis[k].angle = 0;
        f->axis[k].bias = 0;
        f->axis[k].p00 = 0;
        f->axis[k].p01 = 0;
        f->axis[k].p11 = 0;
    }
    return IMU_OK;
}

/**
 * Prediction of one axis: angle = predicted (read from the propagated attitude),
 * P = A P A^T + Q dt with A = [[1, -c dt], [0, 1]]; c (`coupling`, Q30, in [-1, 1])
 * is how much of the paired gyro axis' bias reaches this angle's rate at the
 * current attitude; bias_noise is this sample's q_bias dt (rad^2/s^2, Q42).
 */
static void predict(imu_kf1d_t *f, imu_kf1d_axis_t *a, imu_angle_t predicted, imu_real_t q_angle,
                    imu_real_t bias_noise, imu_q30_t coupling)
{
    uint32_t *sat = &f->saturations;
    const imu_q30_t dt = f->dt;
    const imu_q30_t cdt = IMU_MUL(dt, coupling, 30); /* s, Q30 */
    /* t = c dt P11 - 2 P01 (rad^2/s, Q40): Q30 * Q42 >> 32 -> Q40. */
    imu_real_t t = IMU_MUL_SAT(cdt, a->p11, 32, sat);
    t = IMU_SUB_SAT(t, IMU_ADD_SAT(a->p01, a->p01, sat), sat);
    a->angle = predicted;
    a->p00 = IMU_ADD_SAT(a->p00, IMU_ADD_SAT(IMU_MUL_SAT(cdt, t, 35, sat), IMU_MUL_SAT(dt, q_angle, 35, sat), sat),
                         sat);                                               /* Q30*Q40>>35 -> Q35 */
    a->p01 = IMU_SUB_SAT(a->p01, IMU_MUL_SAT(cdt, a->p11, 32, sat), sat);    /* Q30*Q42>>32 -> Q40 */
    a->p11 = IMU_ADD_SAT(a->p11, bias_noise, sat);
}

/** A Kalman gain num / s as a mantissa and an exponent, num / s = mant 2^-exp: computed
 *  once per measurement and multiplied into each quantity it corrects (one 32 x 32-bit
 *  product and a rounding shift each instead of a 64-by-32-bit division). It keeps 30
 *  significant bits whatever its size: the bias gain rounded to a fixed Q30 would keep
 *  some 15 at 1 kHz, and its truncation would bias the estimate against the float
 *  build's. Float build: mant = num / s, exp = 0. */
typedef struct {
    imu_real_t mant; /* |mant| in [2^29, 2^31), or 0 */
    int exp;         /* -1 ... 61: |num| at most 2^31, s at least 1 */
} gain_t;

/** 1 / s of a measurement's innovation variance s, shared by its two gains (one division). */
typedef struct {
    imu_real_t inv; /* fixed: floor((2^62 - 1) / (s 2^shift)), in [2^30, 2^31); float: 1 / s */
    int shift;      /* fixed: s 2^shift in [2^31, 2^32); float: 0 */
} reciprocal_t;

#ifdef IMU_FIXED

/** 1 / s for s > 0: a 64-by-32-bit division of 2^62 - 1 by s normalised to 32 bits. */
static reciprocal_t reciprocal(imu_real_t s)
{
    reciprocal_t r;
    uint32_t sn;
    r.shift = imu_clz32((uint32_t)s);
    sn = (uint32_t)s << r.shift;
    r.inv = (imu_real_t)imu_udiv64_32(((uint64_t)1 << 62) - 1, sn);
    return r;
}

/** num / s (any int32 num): |num| 2^za in [2^31, 2^32) times the reciprocal's mantissa
 *  is (num / s) 2^(62 + za - shift) within 2^-30 relative; its top 32 bits, rounded,
 *  lie in [2^29, 2^31): one 32 x 32-bit product. */
static gain_t gain(imu_real_t num, reciprocal_t r)
{
    gain_t g = {0, 0};
    if (num != 0) {
        const uint32_t a = num < 0 ? (uint32_t)(-(int64_t)num) : (uint32_t)num;
        const int za = imu_clz32(a);
        const imu_real_t mant = (imu_real_t)(((uint64_t)(a << za) * (uint32_t)r.inv + ((uint64_t)1 << 31)) >> 32);
        g.mant = num < 0 ? -mant : mant;
        g.exp = 30 + za - r.shift;
    }
    return g;
}

/** x g 2^-extra, rounded and saturated (|x g.mant| < 2^62; the shift is at least -1). */
static inline imu_real_t times(imu_real_t x, gain_t g, int extra, uint32_t *sat)
{
    const imu_wide_t v = IMU_WMUL(x, g.mant);
    const int shift = g.exp + extra;
    if (shift > 62) {
        return 0; /* below one half */
    }
    if (shift >= 33) {
        /* the usual case (gains below 2^-3): the same rounding, (v 2^(1 - shift) + 1) / 2
         * floored, as a shift of v's high word (a 64-bit shift by a variable count costs
         * a dozen instructions on a 32-bit core); |result| < 2^29 */
        const int32_t t = (int32_t)(v >> 32) >> (shift - 33);
        return (t >> 1) + (t & 1);
    }
    return IMU_WIDE_SAT(shift > 0 ? imu_rshift_round64(v, shift) : v * ((int64_t)1 << -shift), sat);
}

#else /* IMU_FLOAT */

static reciprocal_t reciprocal(imu_real_t s)
{
    reciprocal_t r;
    r.inv = 1.0 / s;
    r.shift = 0;
    return r;
}

static gain_t gain(imu_real_t num, reciprocal_t r)
{
    gain_t g;
    g.mant = num * r.inv;
    g.exp = 0;
    return g;
}

static inline imu_real_t times(imu_real_t x, gain_t g, int extra, uint32_t *sat)
{
    (void)extra; /* a change of Q format */
    (void)sat;
    return x * g.mant;
}

#endif

/**
 * Measurement update of one axis with a measured angle (Q29) of variance r / w
 * (r: rad^2 Q35; w: weight in [0, 1], Q30). The weight enters as
 * K = w P H^T / (w P00 + r), which equals the update with variance r / w without
 * ever forming r / w (no overflow as w goes to 0, where the update fades out).
 */
static void correct(imu_kf1d_t *f, imu_kf1d_axis_t *a, imu_angle_t measured, imu_real_t r, imu_q30_t w)
{
    uint32_t *sat = &f->saturations;
    const imu_real_t wp00 = IMU_MUL(w, a->p00, 30);                 /* rad^2, Q35 */
    const imu_real_t wp01 = IMU_MUL(w, a->p01, 30);                 /* rad^2/s, Q40 */
    const reciprocal_t inv_s = reciprocal(IMU_ADD_SAT(wp00, r, sat)); /* of s: rad^2, Q35, > 0 */
    const gain_t k_angle = gain(wp00, inv_s);                           /* Q35 / Q35: dimensionless */
    const gain_t k_bias = gain(wp01, inv_s);                            /* Q40 / Q35: 1/s, 2^5 */
    const imu_angle_t innovation = imu_angle_diff(measured, a->angle);
    const imu_real_t p01 = a->p01;
    a->angle = imu_angle_add(a->angle, times(innovation, k_angle, 0, sat));         /* Q29 */
    a->bias = IMU_ADD_SAT(a->bias, times(innovation, k_bias, 4, sat), sat);         /* Q29 * 2^5 / 2^4 -> Q30 */
    a->p00 = IMU_SUB_SAT(a->p00, times(a->p00, k_angle, 0, sat), sat);              /* Q35 */
    a->p01 = IMU_SUB_SAT(p01, times(p01, k_angle, 0, sat), sat);                    /* Q40 */
    a->p11 = IMU_SUB_SAT(a->p11, times(p01, k_bias, 3, sat), sat);                  /* Q40 * 2^5 / 2^3 -> Q42 */
}

/**
 * Turns the attitude by this sample's Euler-angle corrections `delta` (Q29 rad) as
 * one body-frame rotation: roll about the sensor y axis, pitch about the
 * intermediate x axis (cos r, 0, sin r) and heading about the earth vertical (-up
 * in the sensor frame: heading is clockwise), which equals adding them to the
 * angles to second order. Written back through Euler angles instead, every sample
 * would round the attitude through a conversion whose error is a fixed function of
 * the attitude, which adds up in slow motion: it about doubled the fixed-vs-float
 * difference in an hour of random motion at 5 kHz (tools/agreement.py --rates 5000
 * --filters kf1d).
 *
 * `up` is the earth's vertical in the sensor frame (Q30) of the predicted attitude, which
 * the corrections turn. The pitch axis takes the measured roll `roll_m` (Q29 rad), equal to the
 * estimated roll when the accelerometer agrees with the estimate: near the gimbal
 * lock the estimated roll is ill-conditioned (a rounding-level attitude difference
 * becomes degrees of roll), and pitch corrections about an axis taken from it
 * part two builds within a few samples; the measurement is the same in both.
 */
static void turn_by_corrections(imu_kf1d_t *f, const imu_q30_t up[3], imu_angle_t roll_m, const imu_angle_t delta[3])
{
    uint32_t *sat = &f->saturations;
    imu_q30_t sr, cr, theta[3];
    imu_sincos(roll_m, &sr, &cr);
    /* rad Q29 * Q30 >> 29 -> rad Q30 */
    theta[0] = IMU_SUB_SAT(IMU_MUL_SAT(delta[PITCH], cr, 29, sat), IMU_MUL_SAT(delta[HEADING], up[0], 29, sat), sat);
    theta[1] = IMU_SUB_SAT(IMU_SHL_SAT(delta[ROLL], 1, sat), IMU_MUL_SAT(delta[HEADING], up[1], 29, sat), sat);
    theta[2] = IMU_SUB_SAT(IMU_MUL_SAT(delta[PITCH], sr, 29, sat), IMU_MUL_SAT(delta[HEADING], up[2], 29, sat), sat);
    imu_quat_turn(f->quat, theta);
}

/** cos r of the attitude whose axes these are (Q30): up_z / cos p (up_z = cos r cos p), within
 *  [-1, 1]; 1 where cos p is 0 (the roll is undefined there, as atan2(0, 0) = 0 makes it). */
static imu_q30_t cos_roll(const imu_euler_axes_t *axes, uint32_t *sat)
{
    const imu_q30_t up_z = axes->up[2], cp = axes->cos_pitch;
    if (cp == 0) {
        return IMU_ONE_Q30;
    }
    if (up_z >= cp || up_z <= -cp) {
        return up_z > 0 ? IMU_ONE_Q30 : -IMU_ONE_Q30; /* (a rounding beyond 1) */
    }
    return IMU_DIV_SAT(up_z, cp, 30, sat); /* below 1 in magnitude */
}

void imu_kf1d_update(imu_kf1d_t *f, const imu_sample_t *s)
{
    uint32_t *sat = &f->saturations;
    /* The specific force's part in the sensor's x-z plane and its magnitude, m/s^2 Q16
     * (saturated beyond 2^15 m/s^2, where the tilt measurements' weight is zero). The
     * magnitude is rounded: floored, it would bias the tilt weights against the float
     * build's (docs/performance-log.md, KF1D's tilt measurement). */
    const imu_real_t acc_xz = imu_hypot(s->acc[0], s->acc[2]);
    const imu_real_t acc_norm = imu_vec3_norm(s->acc);
    const int have_tilt = acc_norm != 0;
    imu_angle_t roll_m = f->axis[ROLL].angle;
    imu_angle_t pitch_m = f->axis[PITCH].angle;
    const int have_mag = s->mag[0] != 0 || s->mag[1] != 0 || s->mag[2] != 0;
    imu_angle_t predicted[3];
    imu_euler_axes_t axes; /* what the predicted angles are read from (Q30) */
    int k;

    if (have_tilt) {
        /* imu_tilt_from_acc's angles, with the magnitudes already at hand */
        roll_m = imu_atan2(IMU_NEG_SAT(s->acc[0], sat), s->acc[2]);
        pitch_m = imu_atan2(s->acc[1], acc_xz);
    }
    if (!f->initialised) {
        f->axis[ROLL].angle = roll_m;
        f->axis[PITCH].angle = pitch_m;
        f->axis[HEADING].angle = imu_heading_from_mag(s->mag, roll_m, pitch_m);
        for (k = 0; k < 3; ++k) {
            predicted[k] = f->axis[k].angle;
            f->axis[k].bias = 0;
            f->axis[k].p00 = k == HEADING ? f->settings.r_heading : f->settings.r_angle;
            f->axis[k].p01 = 0;
            f->axis[k].p11 = INITIAL_BIAS_VARIANCE;
        }
        imu_euler_to_quat(predicted, f->quat);
        f->initialised = 1;
        return;
    }

    {
        /* Prediction: the attitude quaternion is advanced by the bias-corrected
         * gyroscope (axis biases: roll ~ y, pitch ~ x, heading ~ -z) and the Euler
         * angles are read from it. This is the exact kinematics, also through the
         * gimbal lock where per-axis rate integration breaks down. */
        imu_q30_t theta[3];
        /* Bias steps: rad/s Q30 * s Q30 >> 30 -> rad Q30, rounded once from the full-precision bias. */
        const imu_q30_t bias_step[3] = {IMU_MUL_SAT(f->axis[PITCH].bias, f->dt, 30, sat),
                                        IMU_MUL_SAT(f->axis[ROLL].bias, f->dt, 30, sat),
                                        IMU_NEG_SAT(IMU_MUL_SAT(f->axis[HEADING].bias, f->dt, 30, sat), sat)};
        imu_real_t bias_noise;
        for (k = 0; k < 3; ++k) {
            /* rad/s Q24 * s Q30 >> 24 -> rad Q30 */
            theta[k] = IMU_SUB_SAT(IMU_MUL_SAT(s->gyr[k], f->dt, 24, sat), bias_step[k], sat);
        }
        /* q_bias dt is some hundred Q42 steps at 1 kHz (26 at 5 kHz): rounded alone it
         * would be the same error each sample, a q_bias 0.05 % (1.5 %) off the float
         * build's, which this filter's gains in random motion are sensitive to. */
        bias_noise = IMU_WSHR_FEEDBACK_SAT(IMU_WMUL(f->settings.q_bias, f->dt), 36, &f->bias_noise_residual,
                                           sat); /* Q48*Q30 = Q78 >> 36 -> Q42 */
        imu_quat_integrate(f->quat, theta);
        imu_quat_to_euler_axes(f->quat, predicted, &axes);
        {
            /* The biases' reach (Euler kinematics): pitch rate = w_x cos r + w_z sin r,
             * heading rate = (w_x sin r - w_z cos r) / cos p, roll rate = w_y + ...: an
             * x-gyro bias moves pitch by cos r, a z-gyro bias the heading by cos r / cos p,
             * taken as cos r cos p (bounded; the sign is what matters). Upside down they
             * act backwards: with A's fixed -dt the bias estimates then ran away (tenths of
             * a rad/s in tumbling random motion), and the fixed and float builds with them.
             * Both are read from the axes the angles come from, without a sine or cosine. */
            imu_q30_t coupling[3];
            coupling[ROLL] = IMU_ONE_Q30;
            coupling[PITCH] = cos_roll(&axes, sat);
            coupling[HEADING] = axes.up[2];
            for (k = 0; k < 3; ++k) {
                predict(f, &f->axis[k], predicted[k], f->settings.q_angle, bias_noise, coupling[k]);
            }
        }
    }

    /* The tilt measurements count in full only while the accelerometer reads
     * gravity alone: their weight falls smoothly as |acc| departs from g by more
     * than acc_tolerance (an accelerating board's tilt is wrong, and taken as
     * measured it drives the bias estimates away). Roll and heading are not
     * separable near the gimbal lock: their measurements are also weighted by
     * cos^2(pitch), which fades them out smoothly (a hard threshold would let the
     * fixed and float builds branch apart). The roll measurement fades with both
     * pitches, the measured one (roll from the accelerometer is ill-conditioned
     * there) and the estimated one (so is the roll read from the attitude, even
     * while an accelerating board measures a pitch far from it). */
    if (have_tilt) {
        const imu_q30_t cp_m = IMU_DIV_SAT(acc_xz, acc_norm, 30, sat); /* cos of the measured pitch, Q30 */
        const imu_q30_t w_acc =
            imu_deviation_weight(IMU_SHL_SAT(IMU_SUB_SAT(acc_norm, IMU_STANDARD_GRAVITY, sat), 8, sat),
                                 f->settings.acc_tolerance, sat); /* deviation Q16 -> Q24 */
        const imu_q30_t cp2 =
            IMU_MUL(IMU_MUL(cp_m, cp_m, 30), IMU_MUL(axes.cos_pitch, axes.cos_pitch, 30), 30);
        const imu_q30_t w_roll = IMU_MUL(cp2, w_acc, 30);
        correct(f, &f->axis[ROLL], roll_m, f->settings.r_angle, w_roll);
        correct(f, &f->axis[PITCH], pitch_m, f->settings.r_angle, w_acc);
    }
    if (have_mag) {
        /* Tilt compensation by the corrected roll and pitch, whose sines and cosines also
         * give the weight. (The predicted ones, which the prediction has at hand, are
         * slightly less accurate: docs/performance-log.md, KF1D's heading measurement.) */
        imu_q30_t sr, cr, sp, cp;
        imu_sincos(f->axis[ROLL].angle, &sr, &cr);
        imu_sincos(f->axis[PITCH].angle, &sp, &cp);
        correct(f, &f->axis[HEADING], imu_heading_from_mag_tilt(s->mag, sr, cr, sp, cp), f->settings.r_heading,
                IMU_MUL(cp, cp, 30));
    }
    if (have_tilt || have_mag) {
        imu_angle_t delta[3];
        for (k = 0; k < 3; ++k) {
            delta[k] = imu_angle_diff(f->axis[k].angle, predicted[k]);
        }
        turn_by_corrections(f, axes.up, roll_m, delta);
    }
}

void imu_kf1d_get(const imu_kf1d_t *f, imu_output_t *out)
{
    int k;
    for (k = 0; k < 3; ++k) {
        out->euler[k] = f->axis[k].angle;
    }
    for (k = 0; k < 4; ++k) {
        out->quat[k] = f->quat[k];
    }
    /* Q30 -> Q24 (rad/s); |bias| <= 2 rad/s, so the negation and the shift cannot overflow. */
    out->gyro_bias[0] = IMU_SHR(f->axis[PITCH].bias, 6);
    out->gyro_bias[1] = IMU_SHR(f->axis[ROLL].bias, 6);
    out->gyro_bias[2] = IMU_SHR(-(imu_wide_t)f->axis[HEADING].bias, 6);
}
