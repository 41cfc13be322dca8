/**
 * @file imu_filter.c
 * @brief The table of filter kinds and the dispatch through it (see imu_filter.h).
 */
#include "imu_filter.h"

/* Each kind's functions with the table's void * signatures: calling a function through a
 * pointer of another type is undefined behaviour, so every kind gets these small adapters. */
#define KIND_ADAPTERS(kind, state_t, settings_t)                                                  \
    static void kind##_init(void *f)                                                              \
    {                                                                                             \
        imu_##kind##_init((state_t *)f);                                                          \
    }                                                                                             \
    static imu_status_t kind##_set_settings(void *f, const void *settings)                        \
    {                                                                                             \
        return imu_##kind##_set_settings((state_t *)f, (const settings_t *)settings);             \
    }                                                                                             \
    static void kind##_update(void *f, const imu_sample_t *sample)                                \
    {                                                                                             \
        imu_##kind##_update((state_t *)f, sample);                                                \
    }                                                                                             \
    static void kind##_get(const void *f, imu_output_t *out)                                      \
    {                                                                                             \
        imu_##kind##_get((const state_t *)f, out);                                                \
    }

KIND_ADAPTERS(eecf, imu_eecf_t, imu_eecf_settings_t)
KIND_ADAPTERS(kf1d, imu_kf1d_t, imu_kf1d_settings_t)
KIND_ADAPTERS(eskf, imu_eskf_t, imu_eskf_settings_t)
KIND_ADAPTERS(navfilter, imu_navfilter_t, imu_navfilter_settings_t)
#undef KIND_ADAPTERS

/* The attitude filters count every saturation in one counter; the nav filter keeps its
 * navigation filter's apart (imu_navfilter_saturations adds them). */
static uint32_t eecf_saturations(const void *f)
{
    return ((const imu_eecf_t *)f)->saturations;
}

static uint32_t kf1d_saturations(const void *f)
{
    return ((const imu_kf1d_t *)f)->saturations;
}

static uint32_t eskf_saturations(const void *f)
{
    return ((const imu_eskf_t *)f)->saturations;
}

static uint32_t navfilter_saturations(const void *f)
{
    return imu_navfilter_saturations((const imu_navfilter_t *)f);
}

const imu_filter_kind_t imu_filter_kinds[IMU_FILTER_KIND_COUNT] = {
    {IMU_FILTER_EECF, "eecf", imu_eecf_setting_descs, &imu_eecf_setting_count, &imu_eecf_default_settings,
     sizeof(imu_eecf_settings_t), offsetof(imu_eecf_t, saturations), sizeof(imu_eecf_t), eecf_init,
     eecf_set_settings, eecf_update, eecf_get, eecf_saturations},
    {IMU_FILTER_KF1D, "kf1d", imu_kf1d_setting_descs, &imu_kf1d_setting_count, &imu_kf1d_default_settings,
     sizeof(imu_kf1d_settings_t), offsetof(imu_kf1d_t, saturations), sizeof(imu_kf1d_t), kf1d_init,
     kf1d_set_settings, kf1d_update, kf1d_get, kf1d_saturations},
    {IMU_FILTER_ESKF, "eskf", imu_eskf_setting_descs, &imu_eskf_setting_count, &imu_eskf_default_settings,
     sizeof(imu_eskf_settings_t), offsetof(imu_eskf_t, saturations), sizeof(imu_eskf_t), eskf_init,
     eskf_set_settings, eskf_update, eskf_get, eskf_saturations},
    {IMU_FILTER_NAV, "nav", imu_navfilter_setting_descs, &imu_navfilter_setting_count,
     &imu_navfilter_default_settings, sizeof(imu_navfilter_settings_t), offsetof(imu_navfilter_t, saturations),
     sizeof(imu_navfilter_t), navfilter_init, navfilter_set_settings, navfilter_update, navfilter_get,
     navfilter_saturations},
};

const imu_filter_kind_t *imu_filter_kind(int id)
{
    int i;
    for (i = 0; i < IMU_FILTER_KIND_COUNT; ++i) {
        if ((int)imu_filter_kinds[i].id == id) {
            return &imu_filter_kinds[i];
        }
    }
    return 0;
}

imu_status_t imu_filter_init(imu_filter_t *f, int id)
{
    const imu_filter_kind_t *kind = imu_filter_kind(id);
    uint8_t *state = (uint8_t *)&f->u;
    size_t i;
    if (kind == 0) {
        return IMU_ERR_UNKNOWN;
    }
    for (i = 0; i < kind->state_size; ++i) {
        state[i] = 0; /* every byte of a checkpoint defined, the explicit padding too */
    }
    f->sensor = imu_sensor_default_settings;
    f->calibration = imu_calibration_identity;
    f->calibrated = 0;
    kind->init(&f->u);
    f->id = kind->id;
    f->kind = kind;
    return IMU_OK;
}

imu_status_t imu_filter_set_settings(imu_filter_t *f, const void *settings)
{
    return f->kind->set_settings(&f->u, settings);
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

void imu_filter_update_raw(imu_filter_t *f, const imu_raw_sample_t *raw)
{
    imu_sample_t sample;
    uint32_t *sat = (uint32_t *)((unsigned char *)&f->u + f->kind->conversion_saturations);
    /* the identity's correction is exact (imu_sensor.h): without a calibration it is skipped */
    if (f->calibrated) {
        imu_sample_from_raw_calibrated(&f->sensor, &f->calibration, raw, &sample, sat);
    } else {
        imu_sample_from_raw(&f->sensor, raw, &sample, sat);
    }
    f->kind->update(&f->u, &sample);
}

void imu_filter_get(const imu_filter_t *f, imu_output_t *out)
{
    f->kind->get(&f->u, out);
}

uint32_t imu_filter_saturations(const imu_filter_t *f)
{
    return f->kind->saturations(&f->u);
}

const uint8_t *imu_filter_state(const imu_filter_t *f)
{
    return (const uint8_t *)&f->u;
}

size_t imu_filter_state_size(const imu_filter_t *f)
{
    return f->kind->state_size;
}

imu_status_t imu_filter_restore(imu_filter_t *f, const uint8_t *state, size_t size)
{
    uint8_t *to = (uint8_t *)&f->u;
    size_t i;
    if (size != f->kind->state_size) {
        return IMU_ERR_RANGE;
    }
    for (i = 0; i < size; ++i) {
        to[i] = state[i];
    }
    return IMU_OK;
}

void imu_filter_update_counts(imu_filter_t *f, const int16_t gyr[3], const int16_t acc[3], const int16_t mag[3])
{
    imu_raw_sample_t raw;
    int k;
    for (k = 0; k < 3; ++k) {
        raw.gyr[k] = gyr[k];
        raw.acc[k] = acc[k];
        raw.mag[k] = mag[k];
    }
    imu_filter_update_raw(f, &raw);
}

void imu_filter_run(imu_filter_t *f, const int16_t *gyr, const int16_t *acc, const int16_t *mag, size_t n,
                    imu_q30_t *quat, imu_angle_t *euler, imu_rate_t *gyro_bias)
{
    size_t i, k;
    for (i = 0; i < n; ++i) {
        imu_output_t out;
        imu_filter_update_counts(f, gyr + 3 * i, acc + 3 * i, mag + 3 * i);
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
