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
};

#define DESC(field, q, unit) {#field, offsetof(imu_kf1d_settings_t, field), q, unit}
const imu_setting_desc_t imu_kf1d_setting_descs[] = {
    DESC(sample_rate, 16, "Hz"), DESC(q_angle, 40, "rad^2/s"), DESC(q_bias, 48, "rad^2/s^3"),
    DESC(r_angle, 35, "rad^2"),  DESC(r_heading, 35, "rad^2"),
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
    if (s->sample_rate < IMU_QCONST(10.0, 16) || s->q_angle < 0 || s->q_angle > IMU_QCONST(1e-3, 40) ||
        s->q_bias < 0 || s->q_bias > IMU_QCONST(5e-6, 48) || s->r_angle < IMU_QCONST(1e-6, 35) ||
        s->r_angle > IMU_QCONST(0.03, 35) || s->r_heading < IMU_QCONST(1e-6, 35) ||
        s->r_heading > IMU_QCONST(0.03, 35)) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations);
    f->initialised = 0;
    for (k = 0; k < 3; ++k) {
        f->axis[k].angle = 0;
        f->axis[k].bias = 0;
        f->axis[k].p00 = 0;
        f->axis[k].p01 = 0;
        f->axis[k].p11 = 0;
    }
    return IMU_OK;
}

/** Prediction of one axis: angle = predicted (the gyro-propagated angle), P = A P A^T + Q dt. */
static void predict(imu_kf1d_t *f, imu_kf1d_axis_t *a, imu_angle_t predicted, imu_real_t q_angle)
{
    uint32_t *sat = &f->saturations;
    const imu_q30_t dt = f->dt;
    /* t = dt P11 - 2 P01 + q_angle (rad^2/s, Q40): Q30 * Q42 >> 32 -> Q40. */
    imu_real_t t = IMU_MUL_SAT(dt, a->p11, 32, sat);
    t = IMU_SUB_SAT(t, IMU_ADD_SAT(a->p01, a->p01, sat), sat);
    t = IMU_ADD_SAT(t, q_angle, sat);
    a->angle = predicted;
    a->p00 = IMU_ADD_SAT(a->p00, IMU_MUL_SAT(dt, t, 35, sat), sat);          /* Q30*Q40>>35 -> Q35 */
    a->p01 = IMU_SUB_SAT(a->p01, IMU_MUL_SAT(dt, a->p11, 32, sat), sat);     /* Q30*Q42>>32 -> Q40 */
    a->p11 = IMU_ADD_SAT(a->p11, IMU_MUL_SAT(f->settings.q_bias, dt, 36, sat), sat); /* Q48*Q30>>36 -> Q42 */
}

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
    const imu_real_t s = IMU_ADD_SAT(wp00, r, sat);                 /* rad^2, Q35, > 0 */
    const imu_q30_t k0 = IMU_DIV_SAT(wp00, s, 30, sat);             /* Q35/Q35 -> Q30, in [0, 1] */
    const imu_q30_t k1 = IMU_DIV_SAT(wp01, s, 25, sat);             /* 1/s: Q40/Q35 -> Q30 */
    const imu_angle_t innovation = imu_angle_diff(measured, a->angle);
    const imu_real_t p00 = a->p00;
    const imu_real_t p01 = a->p01;
    a->angle = imu_angle_add(a->angle, IMU_MUL_SAT(k0, innovation, 30, sat));
    a->bias = IMU_ADD_SAT(a->bias, IMU_MUL_SAT(k1, innovation, 35, sat), sat); /* Q30*Q29>>35 -> Q24 */
    a->p00 = IMU_SUB_SAT(p00, IMU_MUL_SAT(k0, p00, 30, sat), sat);
    a->p01 = IMU_SUB_SAT(p01, IMU_MUL_SAT(k0, p01, 30, sat), sat);
    a->p11 = IMU_SUB_SAT(a->p11, IMU_MUL_SAT(k1, p01, 28, sat), sat);          /* Q30*Q40>>28 -> Q42 */
}

void imu_kf1d_update(imu_kf1d_t *f, const imu_sample_t *s)
{
    uint32_t *sat = &f->saturations;
    imu_angle_t roll_m = f->axis[ROLL].angle;
    imu_angle_t pitch_m = f->axis[PITCH].angle;
    const int have_tilt = imu_tilt_from_acc(s->acc, &roll_m, &pitch_m);
    const int have_mag = s->mag[0] != 0 || s->mag[1] != 0 || s->mag[2] != 0;
    int k;

    if (!f->initialised) {
        f->axis[ROLL].angle = roll_m;
        f->axis[PITCH].angle = pitch_m;
        f->axis[HEADING].angle = imu_heading_from_mag(s->mag, roll_m, pitch_m);
        for (k = 0; k < 3; ++k) {
            f->axis[k].bias = 0;
            f->axis[k].p00 = k == HEADING ? f->settings.r_heading : f->settings.r_angle;
            f->axis[k].p01 = 0;
            f->axis[k].p11 = INITIAL_BIAS_VARIANCE;
        }
        f->initialised = 1;
        return;
    }

    {
        /* Prediction: the attitude of the current angles is advanced by the
         * bias-corrected gyroscope (axis biases: roll ~ y, pitch ~ x, heading ~ -z)
         * and read back as Euler angles. This is the exact kinematics, also
         * through the gimbal lock where per-axis rate integration breaks down. */
        imu_q30_t q[4], theta[3];
        imu_angle_t predicted[3];
        const imu_rate_t w[3] = {IMU_SUB_SAT(s->gyr[0], f->axis[PITCH].bias, sat),
                                 IMU_SUB_SAT(s->gyr[1], f->axis[ROLL].bias, sat),
                                 IMU_ADD_SAT(s->gyr[2], f->axis[HEADING].bias, sat)};
        for (k = 0; k < 3; ++k) {
            theta[k] = IMU_MUL_SAT(w[k], f->dt, 24, sat); /* rad/s Q24 * s Q30 >> 24 -> rad Q30 */
            predicted[k] = f->axis[k].angle;
        }
        imu_euler_to_quat(predicted, q);
        imu_quat_integrate(q, theta);
        imu_quat_to_euler(q, predicted);
        for (k = 0; k < 3; ++k) {
            predict(f, &f->axis[k], predicted[k], f->settings.q_angle);
        }
    }

    /* Roll and heading are not separable near the gimbal lock: their
     * measurements are weighted by cos^2(pitch), which fades them out smoothly
     * (a hard threshold would let the fixed and float builds branch apart). */
    if (have_tilt) {
        imu_q30_t sp, cp, w;
        imu_sincos(pitch_m, &sp, &cp);
        w = IMU_MUL(cp, cp, 30);
        correct(f, &f->axis[ROLL], roll_m, f->settings.r_angle, w);
        correct(f, &f->axis[PITCH], pitch_m, f->settings.r_angle, IMU_ONE_Q30);
    }
    if (have_mag) {
        imu_q30_t sp, cp;
        imu_sincos(f->axis[PITCH].angle, &sp, &cp);
        const imu_angle_t heading_m = imu_heading_from_mag(s->mag, f->axis[ROLL].angle, f->axis[PITCH].angle);
        correct(f, &f->axis[HEADING], heading_m, f->settings.r_heading, IMU_MUL(cp, cp, 30));
    }
}

void imu_kf1d_get(const imu_kf1d_t *f, imu_output_t *out)
{
    int k;
    for (k = 0; k < 3; ++k) {
        out->euler[k] = f->axis[k].angle;
    }
    imu_euler_to_quat(out->euler, out->quat);
    out->gyro_bias[0] = f->axis[PITCH].bias;
    out->gyro_bias[1] = f->axis[ROLL].bias;
    {
        uint32_t unused = 0; /* a const filter counts nothing; the bias state is already saturated */
        out->gyro_bias[2] = IMU_NEG_SAT(f->axis[HEADING].bias, &unused);
    }
}
