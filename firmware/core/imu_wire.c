/**
 * @file imu_wire.c
 * @brief The core's types as the protocol's messages (see imu_wire.h).
 */
#include "imu_wire.h"

/** NAV-PVT's fixType of a 3-D fix, and of one combined with dead reckoning. */
#define FIX_TYPE_3D 3
#define FIX_TYPE_GNSS_DEAD_RECKONING 4

void imu_wire_gnss_fix(const imu_proto_gnss_t *msg, imu_navfilter_gnss_t *fix)
{
    int k;
    fix->usable = msg->fix_ok != 0 && (msg->fix_type == FIX_TYPE_3D || msg->fix_type == FIX_TYPE_GNSS_DEAD_RECKONING);
    fix->lat_1e7deg = msg->lat_1e7deg;
    fix->lon_1e7deg = msg->lon_1e7deg;
    fix->height_mm = msg->height_mm;
    fix->has_velocity = msg->has_velocity != 0;
    for (k = 0; k < 3; ++k) {
        fix->vel_ned_mm_s[k] = msg->vel_ned_mm_s[k];
    }
    fix->h_acc_mm = msg->h_acc_mm;
    fix->v_acc_mm = msg->v_acc_mm;
    fix->s_acc_mm_s = msg->s_acc_mm_s;
}

#ifdef IMU_FIXED
void imu_wire_estimate(const imu_filter_t *f, const imu_output_t *out, uint32_t index, imu_proto_estimate_t *msg)
{
    const imu_eskf_t *eskf = imu_filter_eskf(f);
    int i;
    msg->index = index;
    msg->filter_id = (uint8_t)f->id;
    for (i = 0; i < 4; ++i) {
        msg->quat[i] = out->quat[i];
    }
    for (i = 0; i < 3; ++i) {
        msg->gyro_bias[i] = out->gyro_bias[i];
        msg->euler[i] = out->euler[i];
    }
    for (i = 0; i < 9; ++i) {
        msg->cov_mantissa[i] = 0;
        msg->cov_exponent[i] = 0;
    }
    msg->weights[0] = msg->weights[1] = 0;
    if (eskf != 0) {
        const int states = imu_eskf_state_count(eskf);
        imu_eskf_get_weights(eskf, &msg->weights[0], &msg->weights[1]);
        for (i = 0; i < states; ++i) {
            int32_t exponent;
            imu_eskf_covariance(eskf, i, i, &msg->cov_mantissa[i], &exponent);
            msg->cov_exponent[i] = (int8_t)exponent; /* the block-floating exponents stay within +-64 */
        }
    }
    msg->saturations = imu_filter_saturations(f);
}

void imu_wire_nav_state(const imu_navfilter_t *f, uint32_t index, imu_proto_nav_state_t *msg)
{
    const imu_navkf_t *kf = imu_navfilter_state(f);
    int k;
    msg->index = index;
    msg->mode = (uint8_t)(kf == 0 ? 0 : (kf->anchored ? 2 : 1));
    msg->lat = msg->lon = msg->height_mm = msg->baro_bias_mm = 0;
    msg->since_fix = msg->rejected = msg->zero_velocity = msg->resets = msg->fades = 0;
    for (k = 0; k < 3; ++k) {
        msg->vel[k] = kf != 0 ? kf->nav.vel[k] : 0;
        msg->acc_bias[k] = kf != 0 ? kf->nav.acc_bias[k] : 0;
    }
    for (k = 0; k < IMU_NAVKF_STATES; ++k) {
        int32_t exponent = 0;
        msg->var_mantissa[k] = 0;
        if (kf != 0) {
            imu_navkf_variance(kf, k, &msg->var_mantissa[k], &exponent);
        }
        /* the block-floating exponents stay far inside int8 (a variance of 2^-98 .. 2^97) */
        msg->var_exponent[k] = (int8_t)(exponent < -128 ? -128 : (exponent > 127 ? 127 : exponent));
    }
    if (kf != 0) {
        imu_navkf_position(kf, &msg->lat, &msg->lon, &msg->height_mm);
        msg->baro_bias_mm = kf->baro_bias;
        msg->since_fix = (uint32_t)kf->since_fix;
        msg->rejected = kf->rejected;
        msg->zero_velocity = kf->zero_velocity;
        msg->resets = kf->resets;
        msg->fades = kf->fades;
    }
}
#endif
