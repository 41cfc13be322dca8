/**
 * @file options.c
 * @brief Start-up options of the emulated boards (see options.h).
 */
#include "options.h"

#include "gy86.h"
#include "text.h"

const char options_usage[] =
    "  --profile NAME   sensor ranges of the fed counts: gy86-default (+-2000 deg/s, +-8 g) or\n"
    "                   gy86-broad (+-2000 deg/s, +-16 g); default gy86-default\n"
    "  --rate HZ        sample rate, Hz (decimal); default 100\n"
    "  --filter NAME    filter active after start-up: eecf, kf1d, eskf or nav; default eecf\n";

/** The sensor profiles of host/imulink/core/counts.py: the reference board's GY-86 configuration
 *  (+-2000 deg/s, 1090 LSB/gauss) with one accelerometer range or the other. */
typedef struct {
    const char *name;
    mpu6050_acc_range_t acc_range;
} profile_t;

static const profile_t profiles[] = {{"gy86-default", MPU6050_ACC_8G}, {"gy86-broad", MPU6050_ACC_16G}};

static void apply_profile(app_config_t *config, const profile_t *profile)
{
    gy86_config_t gy86 = gy86_default_config;
    gy86.mpu.acc_range = profile->acc_range;
    gy86_sensor_settings(&gy86, &config->sensor);
}

static const struct {
    const char *name;
    uint8_t id;
} filter_names[] = {{"eecf", IMU_FILTER_EECF}, {"kf1d", IMU_FILTER_KF1D}, {"eskf", IMU_FILTER_ESKF},
                    {"nav", IMU_FILTER_NAV}};

/** Decimal "123.456" to Q16, rounded to nearest; 0 when it is not a positive number below 32768. */
static imu_real_t parse_rate_q16(const char *s)
{
    uint64_t whole = 0, fraction = 0, scale = 1;
    int digits = 0;
    for (; *s >= '0' && *s <= '9'; ++s, ++digits) {
        whole = whole * 10u + (uint64_t)(*s - '0');
        if (whole >= 32768u) {
            return 0;
        }
    }
    if (*s == '.') {
        for (++s; *s >= '0' && *s <= '9'; ++s, ++digits) {
            if (scale < 1000000000000ULL) { /* further digits are below the Q16 resolution */
                fraction = fraction * 10u + (uint64_t)(*s - '0');
                scale *= 10u;
            }
        }
    }
    if (*s != '\0' || digits == 0) {
        return 0;
    }
    whole = (whole << 16) + (fraction * 65536u + scale / 2u) / scale;
    return whole > 0 && whole < ((uint64_t)32768u << 16) ? (imu_real_t)whole : 0;
}

void options_defaults(app_config_t *config, const char *board_name)
{
    config->board_name = board_name;
    config->sample_rate = (imu_real_t)(100 * 65536);
    config->initial_filter = IMU_FILTER_EECF;
    apply_profile(config, &profiles[0]);
}

int options_apply(app_config_t *config, const char *name, const char *value, const char **error)
{
    size_t i;
    if (text_equal(name, "--profile")) {
        for (i = 0; value != 0 && i < sizeof profiles / sizeof profiles[0]; ++i) {
            if (text_equal(value, profiles[i].name)) {
                apply_profile(config, &profiles[i]);
                return 1;
            }
        }
        *error = "--profile must be gy86-default or gy86-broad";
        return -1;
    }
    if (text_equal(name, "--rate")) {
        const imu_real_t rate = value != 0 ? parse_rate_q16(value) : 0;
        if (rate == 0) {
            *error = "--rate must be a number of Hz above 0 and below 32768";
            return -1;
        }
        config->sample_rate = rate;
        return 1;
    }
    if (text_equal(name, "--filter")) {
        for (i = 0; value != 0 && i < sizeof filter_names / sizeof filter_names[0]; ++i) {
            if (text_equal(value, filter_names[i].name)) {
                config->initial_filter = filter_names[i].id;
                return 1;
            }
        }
        *error = "--filter must be eecf, kf1d, eskf or nav";
        return -1;
    }
    return 0;
}
