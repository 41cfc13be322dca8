/**
 * @file imu_kf1d.c
 * @brief Per-axis angle/bias Kalman filter (see imu_kf1d.h).
 */
#include "imu_kf1d.h"

#include "imu_math.h"

enum { ROLL = 0, PITCH = 1, HEADING = 2 };

const imu_kf1d_settings_t imu_kf1d_default_settings = {
    IMU_QCONST(100.0, 16), /* sample_rate, Hz */
    IMU_QCONST(1e-5, 40),  /* q_angle, rad^2/s */
    IMU_QCONST(1e-8, 48),  /* q_bias, rad^2/s^3 */
    IMU_QCONST(0.01, 35),  /* r_angle, rad^2 */
    IMU_QCONST(0.01, 35),  /* r_heading, rad^2 */
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
/** Smallest |cos(pitch)| used in the heading rate (Q30), near the gimbal lock. */
#define MIN_COS_PITCH IMU_QCONST(0.02, 30)

void imu_kf1d_init(imu_kf1d_t *f)
{
    (void)imu_kf1d_set_settings(f, &imu_kf1d_default_settings);
}

imu_status_t imu_kf1d_set_settings(imu_kf1d_t *f, const imu_kf1d_settings_t *s)
{
    if (!(s->sample_rate > IMU_QCONST(0.5, 16)) || s->q_angle < 0 || s->q_angle > IMU_QCONST(1e-3, 40) ||
        s->q_bias < 0 || s->q_bias > IMU_QCONST(5e-6, 48) || s->r_angle < IMU_QCONST(1e-6, 35) ||
        s->r_angle > IMU_QCONST(0.03, 35) || s->r_heading < IMU_QCONST(1e-6, 35) ||
        s->r_heading > IMU_QCONST(0.03, 35)) {
        return IMU_ERR_RANGE;
    }
    f->settings = *s;
    f->saturations = 0;
    f->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), s->sample_rate, 30, &f->saturations);
    f->initialised = 0;
    return IMU_OK;
}

/** Prediction of one axis: angle += rate dt, P = A P A^T + Q dt. */
static void predict(imu_kf1d_t *f, imu_kf1d_axis_t *a, imu_rate_t rate, imu_real_t q_angle)
{
    uint32_t *sat = &f->saturations;
    const imu_q30_t dt = f->dt;
    /* t = dt P11 - 2 P01 + q_angle (rad^2/s, Q40): Q30 * Q42 >> 32 -> Q40. */
    imu_real_t t = IMU_MUL_SAT(dt, a->p11, 32, sat);
    t = IMU_SUB_SAT(t, IMU_ADD_SAT(a->p01, a->p01, sat), sat);
    t = IMU_ADD_SAT(t, q_angle, sat);
    /* rad/s Q24 * s Q30 >> 25 -> rad Q29. */
    a->angle = imu_wrap_angle(IMU_ADD_SAT(a->angle, IMU_MUL_SAT(rate, dt, 25, sat), sat));
    a->p00 = IMU_ADD_SAT(a->p00, IMU_MUL_SAT(dt, t, 35, sat), sat);          /* Q30*Q40>>35 -> Q35 */
    a->p01 = IMU_SUB_SAT(a->p01, IMU_MUL_SAT(dt, a->p11, 32, sat), sat);     /* Q30*Q42>>32 -> Q40 */
    a->p11 = IMU_ADD_SAT(a->p11, IMU_MUL_SAT(f->settings.q_bias, dt, 36, sat), sat); /* Q48*Q30>>36 -> Q42 */
}

/** Measurement update of one axis with a measured angle (Q29) of variance r (Q35). */
static void correct(imu_kf1d_t *f, imu_kf1d_axis_t *a, imu_angle_t measured, imu_real_t r)
{
    uint32_t *sat = &f->saturations;
    const imu_real_t s = IMU_ADD_SAT(a->p00, r, sat);               /* rad^2, Q35, > 0 */
    const imu_q30_t k0 = IMU_DIV_SAT(a->p00, s, 30, sat);           /* Q35/Q35 -> Q30, in [0, 1] */
    const imu_q30_t k1 = IMU_DIV_SAT(a->p01, s, 25, sat);           /* 1/s: Q40/Q35 -> Q30 */
    const imu_angle_t innovation = imu_wrap_angle(IMU_SUB(measured, a->angle));
    const imu_real_t p00 = a->p00;
    const imu_real_t p01 = a->p01;
    a->angle = imu_wrap_angle(IMU_ADD_SAT(a->angle, IMU_MUL_SAT(k0, innovation, 30, sat), sat));
    a->bias = IMU_ADD_SAT(a->bias, IMU_MUL_SAT(k1, innovation, 35, sat), sat); /* Q30*Q29>>35 -> Q24 */
    a->p00 = IMU_SUB_SAT(p00, IMU_MUL_SAT(k0, p00, 30, sat), sat);
    a->p01 = IMU_SUB_SAT(p01, IMU_MUL_SAT(k0, p01, 30, sat), sat);
    a->p11 = IMU_SUB_SAT(a->p11, IMU_MUL_SAT(k1, p01, 28, sat), sat);          /* Q30*Q40>>28 -> Q42 */
}

/** Keep pitch in [-pi/2, pi/2]: past the vertical the same attitude is
 *  (roll + pi, pi - pitch, heading + pi). */
static void fold_pitch(imu_kf1d_t *f)
{
    imu_angle_t *pitch = &f->axis[PITCH].angle;
    if (*pitch > IMU_HALF_PI_ANGLE || *pitch < -IMU_HALF_PI_ANGLE) {
        *pitch = imu_wrap_angle(IMU_SUB(*pitch > 0 ? IMU_PI_ANGLE : -IMU_PI_ANGLE, *pitch));
        f->axis[ROLL].angle = imu_wrap_angle(IMU_ADD(f->axis[ROLL].angle, IMU_PI_ANGLE));
        f->axis[HEADING].angle = imu_wrap_angle(IMU_ADD(f->axis[HEADING].angle, IMU_PI_ANGLE));
    }
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
        /* Bias-corrected body rates (axis biases: roll ~ y, pitch ~ x, heading ~ -z). */
        const imu_rate_t wx = IMU_SUB_SAT(s->gyr[0], f->axis[PITCH].bias, sat);
        const imu_rate_t wy = IMU_SUB_SAT(s->gyr[1], f->axis[ROLL].bias, sat);
        const imu_rate_t wz = IMU_ADD_SAT(s->gyr[2], f->axis[HEADING].bias, sat);
        imu_q30_t sr, cr, sp, cp;
        imu_rate_t u, heading_rate, pitch_rate, roll_rate;
        imu_sincos(f->axis[ROLL].angle, &sr, &cr);
        imu_sincos(f->axis[PITCH].angle, &sp, &cp);
        if (cp < MIN_COS_PITCH) {
            cp = MIN_COS_PITCH; /* pitch is folded into [-pi/2, pi/2]: cos >= 0 */
        }
        /* Euler kinematics of R = Rz(-heading) Rx(pitch) Ry(roll):
         * pitch' = wx cr + wz sr; heading' = (wx sr - wz cr) / cp; roll' = wy + heading' sp.
         * The biases are already removed from the rates, so predict() adds rate dt
         * while its A = [[1, -dt], [0, 1]] carries the bias uncertainty. */
        pitch_rate = IMU_ADD_SAT(IMU_MUL_SAT(wx, cr, 30, sat), IMU_MUL_SAT(wz, sr, 30, sat), sat);
        u = IMU_SUB_SAT(IMU_MUL_SAT(wx, sr, 30, sat), IMU_MUL_SAT(wz, cr, 30, sat), sat);
        heading_rate = IMU_DIV_SAT(u, cp, 30, sat);
        roll_rate = IMU_ADD_SAT(wy, IMU_MUL_SAT(heading_rate, sp, 30, sat), sat);
        predict(f, &f->axis[ROLL], roll_rate, f->settings.q_angle);
        predict(f, &f->axis[PITCH], pitch_rate, f->settings.q_angle);
        predict(f, &f->axis[HEADING], heading_rate, f->settings.q_angle);
        fold_pitch(f);
    }

    if (have_tilt) {
        correct(f, &f->axis[ROLL], roll_m, f->settings.r_angle);
        correct(f, &f->axis[PITCH], pitch_m, f->settings.r_angle);
        fold_pitch(f);
    }
    if (have_mag) {
        const imu_angle_t heading_m = imu_heading_from_mag(s->mag, f->axis[ROLL].angle, f->axis[PITCH].angle);
        correct(f, &f->axis[HEADING], heading_m, f->settings.r_heading);
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
    out->gyro_bias[2] = -f->axis[HEADING].bias;
}
