/**
 * @file imu_sensor.c
 * @brief Conversion of raw counts (see imu_sensor.h).
 */
#include "imu_sensor.h"

const imu_sensor_settings_t imu_sensor_default_settings = {
    IMU_QCONST(3.14159265358979323846 / 180.0 / 16.4, 40), /* rad/s per LSB at 16.4 LSB/(deg/s) */
    IMU_QCONST(2.394201660156250e-3, 32),  /* 9.80665 / 4096 */
    IMU_QCONST(9.174311926605504e-2, 24),  /* 100 / 1090 */
    {-32768, 32767},                       /* MPU6050 gyroscope: the int16 range */
    {-32768, 32767},                       /* MPU6050 accelerometer */
    {-2048, 2047},                         /* HMC5883L */
};

#define IMU_CAL_ONE IMU_QCONST(1.0, 24)
#define IMU_CAL_IDENTITY_SENSOR {{0, 0, 0}, {IMU_CAL_ONE, 0, 0, 0, IMU_CAL_ONE, 0, 0, 0, IMU_CAL_ONE}}

const imu_calibration_t imu_calibration_identity = {
    IMU_CAL_IDENTITY_SENSOR,
    IMU_CAL_IDENTITY_SENSOR,
    IMU_CAL_IDENTITY_SENSOR,
};

static int offsets_in_range(const imu_sensor_cal_t *c)
{
    int i;
    for (i = 0; i < 3; ++i) {
        if (!(c->offset[i] <= IMU_CAL_MAX_OFFSET && c->offset[i] >= -IMU_CAL_MAX_OFFSET)) {
            return 0; /* written so that a NaN (float build) is refused too */
        }
    }
    return 1;
}

static int sensor_is_identity(const imu_sensor_cal_t *c, const imu_sensor_cal_t *identity)
{
    int i;
    for (i = 0; i < 3; ++i) {
        if (c->offset[i] != identity->offset[i]) {
            return 0;
        }
    }
    for (i = 0; i < 9; ++i) {
        if (c->matrix[i] != identity->matrix[i]) {
            return 0;
        }
    }
    return 1;
}

int imu_calibration_is_identity(const imu_calibration_t *cal)
{
    const imu_calibration_t *id = &imu_calibration_identity;
    return sensor_is_identity(&cal->gyr, &id->gyr) && sensor_is_identity(&cal->acc, &id->acc) &&
           sensor_is_identity(&cal->mag, &id->mag);
}

imu_status_t imu_calibration_check(const imu_calibration_t *cal)
{
    return offsets_in_range(&cal->gyr) && offsets_in_range(&cal->acc) && offsets_in_range(&cal->mag) ? IMU_OK
                                                                                                      : IMU_ERR_RANGE;
}

/** Corrected counts of one sensor, Q8: matrix (raw - offset); bounds in imu_sensor.h. */
static void correct(const imu_sensor_cal_t *c, const int16_t raw[3], imu_real_t out[3], uint32_t *sat)
{
    imu_real_t d[3];
    int i;
    for (i = 0; i < 3; ++i) {
        /* |raw 2^8| <= 2^23 and |offset| <= 2^24 (imu_calibration_check): no saturation */
        d[i] = IMU_SUB(IMU_FROM_INT_SAT(raw[i], IMU_CAL_OFFSET_Q, sat), c->offset[i]);
    }
    for (i = 0; i < 3; ++i) {
        const imu_wide_t sum = IMU_WMUL(c->matrix[3 * i], d[0]) + IMU_WMUL(c->matrix[3 * i + 1], d[1]) +
                               IMU_WMUL(c->matrix[3 * i + 2], d[2]); /* Q32, below 3 * 2^56 */
        out[i] = IMU_WIDE_SAT(IMU_WSHR(sum, IMU_CAL_MATRIX_Q), sat);
    }
}

unsigned imu_sample_clipped(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw)
{
    unsigned clipped = 0;
    int i;
    for (i = 0; i < 3; ++i) {
        if (raw->gyr[i] <= settings->gyro_limits[0] || raw->gyr[i] >= settings->gyro_limits[1]) {
            clipped |= IMU_CLIPPED_GYR;
        }
        if (raw->acc[i] <= settings->acc_limits[0] || raw->acc[i] >= settings->acc_limits[1]) {
            clipped |= IMU_CLIPPED_ACC;
        }
        if (raw->mag[i] <= settings->mag_limits[0] || raw->mag[i] >= settings->mag_limits[1]) {
            clipped |= IMU_CLIPPED_MAG;
        }
    }
    return clipped;
}

/** Axis i of the sample from counts with `frac_bits` fraction bits (0: raw counts; IMU_CAL_OFFSET_Q:
 *  corrected ones): the scalings of imu_sample_from_raw(), `frac_bits` longer. The float build
 *  keeps counts as they are. */
static inline void scale_axis(const imu_sensor_settings_t *settings, imu_real_t gyr, imu_real_t acc, imu_real_t mag,
                              int frac_bits, int i, imu_sample_t *out, uint32_t *sat)
{
    (void)frac_bits; /* (a change of Q format: the float build's macros leave it out) */
    out->gyr[i] = IMU_MUL_SAT(gyr, settings->gyro_scale, 16 + frac_bits, sat);
    out->acc[i] = IMU_MUL_SAT(acc, settings->acc_scale, 16 + frac_bits, sat);
    out->mag[i] = IMU_MUL_SAT(mag, settings->mag_scale, 8 + frac_bits, sat);
}

void imu_sample_from_raw_calibrated(const imu_sensor_settings_t *settings, const imu_calibration_t *cal,
                                    const imu_raw_sample_t *raw, imu_sample_t *out, uint32_t *sat)
{
    imu_real_t gyr[3], acc[3], mag[3]; /* corrected counts, Q8 */
    int i;
    correct(&cal->gyr, raw->gyr, gyr, sat);
    correct(&cal->acc, raw->acc, acc, sat);
    correct(&cal->mag, raw->mag, mag, sat);
    out->clipped = imu_sample_clipped(settings, raw);
    for (i = 0; i < 3; ++i) {
        scale_axis(settings, gyr[i], acc[i], mag[i], IMU_CAL_OFFSET_Q, i, out, sat);
    }
}

void imu_sample_from_raw(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw,
                         imu_sample_t *out, uint32_t *sat)
{
    /* What the identity calibration's correction and the Q8 scaling give, exactly: its
     * correction is the count in Q8, and (c 2^8 s + 2^(k + 7)) >> (k + 8) = (c s + 2^(k - 1)) >> k. */
    int i;
    out->clipped = imu_sample_clipped(settings, raw);
    for (i = 0; i < 3; ++i) {
        scale_axis(settings, raw->gyr[i], raw->acc[i], raw->mag[i], 0, i, out, sat);
    }
}
