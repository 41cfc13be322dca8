/**
 * @file imu_navfilter.c
 * @brief The nav filter as the board runs it (see imu_navfilter.h).
 */
#include "imu_navfilter.h"

#include "imu_math.h"

const imu_navfilter_settings_t imu_navfilter_default_settings = {
    IMU_QCONST(100.0, 16), /* sample_rate, Hz */
    IMU_QCONST(0.0, 16),   /* lever_arm_x, m: the antenna at the sensor */
    IMU_QCONST(0.0, 16),   /* lever_arm_y, m */
    IMU_QCONST(0.0, 16),   /* lever_arm_z, m */
    IMU_QCONST(0.0, 16),   /* gnss_latency, s: what the receiver's fix says it is (u-blox NAV-PVT: its epoch) */
    IMU_NAVKF_DEFAULT_TUNING,
};

/* Each field with its Q format, unit and accepted range [lo, hi] in the unit. */
#define DESC(field, q, unit, lo, hi) \
    {#field, offsetof(imu_navfilter_settings_t, field), q, unit, IMU_QCONST(lo, q), IMU_QCONST(hi, q)}
#define TUNING(field, q, unit, lo, hi) \
    {#field, offsetof(imu_navfilter_settings_t, tuning.field), q, unit, IMU_QCONST(lo, q), IMU_QCONST(hi, q)}
const imu_setting_desc_t imu_navfilter_setting_descs[] = {
    DESC(sample_rate, 16, "Hz", 10.0, 1000.0),
    DESC(lever_arm_x, 16, "m", -10.0, 10.0),
    DESC(lever_arm_y, 16, "m", -10.0, 10.0),
    DESC(lever_arm_z, 16, "m", -10.0, 10.0),
    DESC(gnss_latency, 16, "s", 0.0, 1.0),
    TUNING(gyro_noise, 30, "rad/s^0.5", 1e-5, 1e-3),
    TUNING(acc_noise, 30, "m/s^1.5", 1e-4, 0.08),
    TUNING(gyro_bias_walk, 30, "rad/s^1.5", 1e-7, 1e-3),
    TUNING(acc_bias_walk, 30, "m/s^2.5", 1e-6, 1e-3),
    TUNING(gate, 16, "1", 7.81, 100.0),
    TUNING(reset_time, 16, "s", 1.0, 600.0),
    TUNING(rest_rate, 24, "rad/s", 0.005, 1.0),
    TUNING(rest_force, 16, "m/s^2", 0.02, 3.0),
    TUNING(acc_range, 16, "m/s^2", 19.6, 200.0),
};
#undef DESC
#undef TUNING
const int imu_navfilter_setting_count =
    (int)(sizeof imu_navfilter_setting_descs / sizeof imu_navfilter_setting_descs[0]);

/** A fix's accuracies when the receiver gives none (NMEA): a consumer receiver's, mm and mm/s. */
#define DEFAULT_H_ACC_MM 5000
#define DEFAULT_V_ACC_MM 10000
#define DEFAULT_S_ACC_MM_S 500
/** The largest accuracy the filter takes, mm (imu_navkf_fix_t). */
#define MAX_ACCURACY 0x40000000u

/** 1e-7 deg to rad, Q29: * (pi / 180e7) 2^60 >> 31 (the constant's integer, 2.01e9, below 2^31). */
#define DEG_1E7_TO_RAD IMU_QCONST(3.14159265358979323846 / 1.8e9, 60)

void imu_navfilter_init(imu_navfilter_t *f)
{
    f->settings = imu_navfilter_default_settings;
    f->started = 0;
    f->saturations = 0;
}

imu_status_t imu_navfilter_set_settings(imu_navfilter_t *f, const imu_navfilter_settings_t *settings)
{
    if (imu_settings_check(imu_navfilter_setting_descs, imu_navfilter_setting_count, settings) != IMU_OK) {
        return IMU_ERR_RANGE;
    }
    f->settings = *settings;
    f->started = 0;
    f->saturations = 0;
    return IMU_OK;
}

void imu_navfilter_update(imu_navfilter_t *f, const imu_sample_t *sample)
{
    if (f->started) {
        imu_navkf_step(&f->kf, sample->gyr, sample->acc, sample->mag);
        return;
    }
    {
        /* m, Q16 -> mm (* 1000 >> 16): within +-10 m */
        const imu_real_t arm_mm[3] = {IMU_MUL(f->settings.lever_arm_x, IMU_QCONST(1000.0, 0), 16),
                                      IMU_MUL(f->settings.lever_arm_y, IMU_QCONST(1000.0, 0), 16),
                                      IMU_MUL(f->settings.lever_arm_z, IMU_QCONST(1000.0, 0), 16)};
        f->started = imu_navkf_start(&f->kf, f->settings.sample_rate, sample->acc, sample->mag, 0, arm_mm) == IMU_OK &&
                     imu_navkf_tune(&f->kf, &f->settings.tuning) == IMU_OK;
    }
}

/** An accuracy in the filter's range: mm as given, `otherwise` when not given (0). */
static imu_real_t accuracy(uint32_t given, imu_real_t otherwise)
{
    if (given == 0) {
        return otherwise;
    }
    return given <= MAX_ACCURACY ? (imu_real_t)given : (imu_real_t)MAX_ACCURACY + 1; /* beyond: refused */
}

/** The fix's position in the filter's units; the rest of *out left alone. */
static void place(imu_navkf_fix_t *out, int32_t lat_1e7deg, int32_t lon_1e7deg, int32_t height_mm)
{
    out->lat = IMU_MUL(lat_1e7deg, DEG_1E7_TO_RAD, 31);
    out->lon = IMU_MUL(lon_1e7deg, DEG_1E7_TO_RAD, 31);
    out->height = height_mm;
}

int imu_navfilter_gnss(imu_navfilter_t *f, const imu_navfilter_gnss_t *fix)
{
    imu_navkf_fix_t g;
    int k;
    if (!f->started || !fix->usable) {
        return 0;
    }
    g.source = IMU_NAVKF_GNSS;
    place(&g, fix->lat_1e7deg, fix->lon_1e7deg, fix->height_mm);
    g.has_vel = fix->has_velocity != 0;
    for (k = 0; k < 3; ++k) {
        /* north, east, down -> east, north, up; mm/s * 2^40 / 1000 >> 20 -> m/s, Q20 */
        const int32_t ned = fix->vel_ned_mm_s[k == 0 ? 1 : (k == 1 ? 0 : 2)];
        const imu_real_t v = IMU_MUL_SAT(ned, IMU_QCONST(0.001, 40), 20, &f->saturations);
        g.vel[k] = g.has_vel ? (k == 2 ? IMU_NEG_SAT(v, &f->saturations) : v) : 0;
    }
    g.h_acc = accuracy(fix->h_acc_mm, DEFAULT_H_ACC_MM);
    g.v_acc = accuracy(fix->v_acc_mm, DEFAULT_V_ACC_MM);
    g.s_acc = accuracy(fix->s_acc_mm_s, DEFAULT_S_ACC_MM_S);
    g.age = IMU_SHL_SAT(f->settings.gnss_latency, 14, &f->saturations); /* s, Q16 -> Q30 (at most 1: no saturation) */
    return imu_navkf_fix(&f->kf, &g);
}

int imu_navfilter_marker(imu_navfilter_t *f, int32_t lat_1e7deg, int32_t lon_1e7deg, int32_t height_mm,
                         uint32_t h_acc_mm, uint32_t v_acc_mm)
{
    imu_navkf_fix_t m;
    int k;
    if (!f->started || h_acc_mm == 0 || v_acc_mm == 0) {
        return 0;
    }
    m.source = IMU_NAVKF_MARKER;
    place(&m, lat_1e7deg, lon_1e7deg, height_mm);
    m.has_vel = 0;
    for (k = 0; k < 3; ++k) {
        m.vel[k] = 0;
    }
    m.h_acc = accuracy(h_acc_mm, 0);
    m.v_acc = accuracy(v_acc_mm, 0);
    m.s_acc = 1; /* unused without a velocity */
    m.age = 0;
    return imu_navkf_fix(&f->kf, &m);
}

void imu_navfilter_baro(imu_navfilter_t *f, int32_t pressure_pa)
{
    if (f->started) {
        imu_navkf_baro(&f->kf, pressure_pa);
    }
}

void imu_navfilter_get(const imu_navfilter_t *f, imu_output_t *out)
{
    int k;
    for (k = 0; k < 4; ++k) {
        out->quat[k] = f->started ? f->kf.nav.q[k] : (k == 0 ? IMU_ONE_Q30 : 0);
    }
    for (k = 0; k < 3; ++k) {
        out->gyro_bias[k] = f->started ? f->kf.nav.gyro_bias[k] : 0;
    }
    imu_quat_to_euler(out->quat, out->euler);
}

uint32_t imu_navfilter_saturations(const imu_navfilter_t *f)
{
    return f->saturations + (f->started ? f->kf.nav.saturations : 0u);
}

const imu_navkf_t *imu_navfilter_state(const imu_navfilter_t *f)
{
    return f->started ? &f->kf : 0;
}
