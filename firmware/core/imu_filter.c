/**
 * @file imu_filter.c
 * @brief Dispatch to the selected filter (see imu_filter.h).
 */
#include "imu_filter.h"

imu_status_t imu_filter_init(imu_filter_t *f, int id)
{
    f->sensor = imu_sensor_default_settings;
    f->calibration = imu_calibration_identity;
    f->calibrated = 0;
    switch (id) {
    case IMU_FILTER_EECF:
        imu_eecf_init(&f->u.eecf);
        break;
    case IMU_FILTER_KF1D:
        imu_kf1d_init(&f->u.kf1d);
        break;
    case IMU_FILTER_ESKF:
        imu_eskf_init(&f->u.eskf);
        break;
    case IMU_FILTER_NAV:
        imu_navfilter_init(&f->u.nav);
        break;
    default:
        return IMU_ERR_UNKNOWN;
    }
    f->id = (imu_filter_id_t)id;
    return IMU_OK;
}

imu_status_t imu_filter_set_settings(imu_filter_t *f, const void *settings)
{
    switch (f->id) {
    case IMU_FILTER_EECF:
        return imu_eecf_set_settings(&f->u.eecf, (const imu_eecf_settings_t *)settings);
    case IMU_FILTER_KF1D:
        return imu_kf1d_set_settings(&f->u.kf1d, (const imu_kf1d_settings_t *)settings);
    case IMU_FILTER_ESKF:
        return imu_eskf_set_settings(&f->u.eskf, (const imu_eskf_settings_t *)settings);
    case IMU_FILTER_NAV:
        return imu_navfilter_set_settings(&f->u.nav, (const imu_navfilter_settings_t *)settings);
    }
    return IMU_ERR_UNKNOWN;
}

void imu_filter_set_sensor(imu_filter_t *f, const imu_sensor_settings_t *sensor)
{
    f->sensor = *sensor;
}

imu_status_t imu_filter_set_calibration(imu_filter_t *f, const imu_calibration_t *cal)
{
    if (imu_calibration_check(cal) != IMU_OK) {
        return IMU_ERR_RANGE;
    }
    f->calibration = *cal;
    f->calibrated = !imu_calibration_is_identity(cal);
    return IMU_OK;
}

static uint32_t *saturation_counter(imu_filter_t *f)
{
    switch (f->id) {
    case IMU_FILTER_EECF:
        return &f->u.eecf.saturations;
    case IMU_FILTER_KF1D:
        return &f->u.kf1d.saturations;
    case IMU_FILTER_ESKF:
        return &f->u.eskf.saturations;
    case IMU_FILTER_NAV:
        return &f->u.nav.saturations;
    }
    return &f->u.eecf.saturations; /* unreachable: the id is checked at initialisation */
}

void imu_filter_update_raw(imu_filter_t *f, const imu_raw_sample_t *raw)
{
    imu_sample_t sample;
    /* the identity's correction is exact (imu_sensor.h): without a calibration it is skipped */
    if (f->calibrated) {
        imu_sample_from_raw_calibrated(&f->sensor, &f->calibration, raw, &sample, saturation_counter(f));
    } else {
        imu_sample_from_raw(&f->sensor, raw, &sample, saturation_counter(f));
    }
    switch (f->id) {
    case IMU_FILTER_EECF:
        imu_eecf_update(&f->u.eecf, &sample);
        break;
    case IMU_FILTER_KF1D:
        imu_kf1d_update(&f->u.kf1d, &sample);
        break;
    case IMU_FILTER_ESKF:
        imu_eskf_update(&f->u.eskf, &sample);
        break;
    case IMU_FILTER_NAV:
        imu_navfilter_update(&f->u.nav, &sample);
        break;
    }
}

void imu_filter_get(const imu_filter_t *f, imu_output_t *out)
{
    switch (f->id) {
    case IMU_FILTER_EECF:
        imu_eecf_get(&f->u.eecf, out);
        break;
    case IMU_FILTER_KF1D:
        imu_kf1d_get(&f->u.kf1d, out);
        break;
    case IMU_FILTER_ESKF:
        imu_eskf_get(&f->u.eskf, out);
        break;
    case IMU_FILTER_NAV:
        imu_navfilter_get(&f->u.nav, out);
        break;
    }
}

uint32_t imu_filter_saturations(const imu_filter_t *f)
{
    if (f->id == IMU_FILTER_NAV) {
        return imu_navfilter_saturations(&f->u.nav); /* the conversions' and the filter's */
    }
    return *saturation_counter((imu_filter_t *)f);
}

void imu_filter_run(imu_filter_t *f, const int16_t *gyr, const int16_t *acc, const int16_t *mag, size_t n,
                    imu_q30_t *quat, imu_angle_t *euler, imu_rate_t *gyro_bias)
{
    size_t i, k;
    for (i = 0; i < n; ++i) {
        imu_raw_sample_t raw;
        imu_output_t out;
        for (k = 0; k < 3; ++k) {
            raw.gyr[k] = gyr[3 * i + k];
            raw.acc[k] = acc[3 * i + k];
            raw.mag[k] = mag[3 * i + k];
        }
        imu_filter_update_raw(f, &raw);
        imu_filter_get(f, &out);
        for (k = 0; k < 4 && quat != 0; ++k) {
            quat[4 * i + k] = out.quat[k];
        }
        for (k = 0; k < 3; ++k) {
            if (euler != 0) {
                euler[3 * i + k] = out.euler[k];
            }
            if (gyro_bias != 0) {
                gyro_bias[3 * i + k] = out.gyro_bias[k];
            }
        }
    }
}

const imu_eskf_t *imu_filter_eskf(const imu_filter_t *f)
{
    return f->id == IMU_FILTER_ESKF ? &f->u.eskf : 0;
}

imu_navfilter_t *imu_filter_nav(imu_filter_t *f)
{
    return f->id == IMU_FILTER_NAV ? &f->u.nav : 0;
}
