/**
 * @file campaign_driver.c
 * @brief Adversarial campaign of the fixed-point core: every setting of every filter
 *        at its minimum and maximum, times hostile input streams, at 30 Hz and 5 kHz (or the
 *        filter's largest rate).
 *
 * Built by tests/test_campaign.py twice: with gcc, -DIMU_FIXED -DIMU_CHECK_NARROWING
 * and -fsanitize=undefined,address (every unsaturated int64 -> int32 narrowing of the
 * arithmetic layer is checked, see imu_arith.h), and with clang's
 * -fsanitize=undefined,integer on the filter sources. By hand:
 *
 *     gcc -std=c99 -DIMU_FIXED -DIMU_CHECK_NARROWING -fsanitize=undefined,address \
 *         -fno-sanitize-recover=all -g -Ifirmware/core tests/c/campaign_driver.c \
 *         $(ls firmware/core/imu_*.c | grep -v imu_proto) -lm -o campaign
 *     ./campaign --ranges                  # the settings' true ranges, found by bisection
 *     ./campaign --list [--filter eskf]    # the case names
 *     ./campaign [--filter F] [--from I] [--to J]   # run cases I..J-1 (indices of --list)
 *     ./campaign --case 'eskf/acc_noise=max/sensor=default/still/30Hz'
 *
 * Settings come from the descriptor tables (imu_*_setting_descs: name, offset, Q
 * format). The range of every setting is not copied from the sources: it is found
 * by bisection on the answer of the filter's set_settings (IMU_OK / IMU_ERR_RANGE),
 * starting from the default, so the campaign follows the checks as they are edited.
 * The settings variants of a filter are: the defaults; each setting alone at its
 * minimum and at its maximum; all settings at their minimum together and all at
 * their maximum together. Each runs at 30 Hz and 5 kHz (or the filter's largest rate; the sample_rate setting
 * overridden), except the variants that set sample_rate themselves. The sensor
 * scales (imu_sensor_settings_t, no range check: any int32) are varied at their
 * extremes (INT32_MAX, INT32_MIN, 0) with the default settings, and all at INT32_MAX or
 * INT32_MIN with the all-minimum and all-maximum settings. So is the calibration
 * (imu_calibration_t): every offset at +-IMU_CAL_MAX_OFFSET and every matrix element at
 * INT32_MAX or INT32_MIN, with the default settings.
 *
 * Before each case the driver prints "CASE <index> <name>" on stdout (flushed). A
 * narrowing that does not fit int32 prints "NARROWING <file>:<line>: ..." with the
 * case, the sample and the non-default settings on stderr, a stack trace when the
 * sanitizer runtime is linked, and aborts (with --keep-going: abandons the case and
 * goes on with the next one, for speed when many cases fail); a sanitizer error
 * aborts by itself (the harness restarts after the failing case). Output checks that
 * do not abort (quaternion norm, Euler angles outside (-pi, pi], settings rejected at
 * their own extremes) print "OUTPUT ..." lines on stdout and the campaign goes on. Exit status 0 when
 * every case ran without such a line, 1 otherwise.
 */
#include <math.h>
#include <setjmp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "imu_filter.h"

#define MAX_SETTINGS 32
#define MAX_CASES 8192
#define NAME_LEN 160
#define PI 3.14159265358979323846

/* ------------------------------------------------------------------ filters and their settings */

typedef union {
    imu_eecf_settings_t eecf;
    imu_kf1d_settings_t kf1d;
    imu_eskf_settings_t eskf;
    imu_navfilter_settings_t nav;
} settings_t;

typedef struct {
    const char *name;
    int id;
    const imu_setting_desc_t *descs;
    int count;
    settings_t defaults;
    int rate_index;            /**< index of the sample_rate descriptor */
    int32_t min[MAX_SETTINGS]; /**< true minimum of each setting (bisection) */
    int32_t max[MAX_SETTINGS]; /**< true maximum of each setting (bisection) */
} filter_info_t;

enum { F_EECF, F_KF1D, F_ESKF, F_NAV, N_FILTERS };
static filter_info_t filters[N_FILTERS];

static int32_t get_raw(const settings_t *s, const imu_setting_desc_t *d)
{
    int32_t v;
    memcpy(&v, (const char *)s + d->offset, sizeof v);
    return v;
}

static void set_raw(settings_t *s, const imu_setting_desc_t *d, int32_t v)
{
    memcpy((char *)s + d->offset, &v, sizeof v);
}

/* ------------------------------------------------------------------ narrowing reports */

/** While 1 (bisection), narrowing failures are counted and not reported: set_settings is
 *  called with many values there; the extremes are then run as cases of their own. */
static int quiet;
static long quiet_failures;
static char current_case[NAME_LEN] = "(none)";
static long current_sample = -1;
static char current_settings[2048] = "";
/** --keep-going: a narrowing failure abandons its case (longjmp back to the case loop)
 *  instead of aborting the process; the next case starts from a fresh filter. */
static int keep_going;
static int in_case;
static jmp_buf case_escape;

extern void __sanitizer_print_stack_trace(void) __attribute__((weak));

void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value)
{
    if (quiet) {
        ++quiet_failures;
        return;
    }
    fflush(stdout);
    fprintf(stderr, "NARROWING %s:%d: %s value %lld does not fit int32 | case %s | sample %ld | settings %s\n", file,
            line, what, (long long)value, current_case, current_sample, current_settings);
    if (__sanitizer_print_stack_trace) {
        __sanitizer_print_stack_trace();
    }
    fflush(stderr);
    if (keep_going && in_case) {
        longjmp(case_escape, 1);
    }
    abort();
}

static int accepted(const filter_info_t *fi, const settings_t *s)
{
    imu_filter_t f;
    memset(&f, 0, sizeof f);
    if (imu_filter_init(&f, fi->id) != IMU_OK) {
        return 0;
    }
    return imu_filter_set_settings(&f, s) == IMU_OK;
}

/** Extreme of setting k accepted by set_settings, from the default toward `dir` (+1 max, -1 min). */
static int32_t bisect(const filter_info_t *fi, int k, int dir)
{
    settings_t s = fi->defaults;
    const imu_setting_desc_t *d = &fi->descs[k];
    int64_t good = get_raw(&s, d);
    int64_t bad = dir > 0 ? (int64_t)INT32_MAX : (int64_t)INT32_MIN;
    set_raw(&s, d, (int32_t)bad);
    if (accepted(fi, &s)) {
        return (int32_t)bad;
    }
    while (bad - good > 1 || good - bad > 1) {
        const int64_t mid = good + (bad - good) / 2;
        set_raw(&s, d, (int32_t)mid);
        if (accepted(fi, &s)) {
            good = mid;
        } else {
            bad = mid;
        }
    }
    return (int32_t)good;
}

/** Fill filters[]: descriptors, defaults, true ranges. Returns the number of problems printed. */
static int setup_filters(int print_ranges)
{
    int problems = 0;
    int i, k;
    filters[F_EECF].name = "eecf";
    filters[F_EECF].id = IMU_FILTER_EECF;
    filters[F_EECF].descs = imu_eecf_setting_descs;
    filters[F_EECF].count = imu_eecf_setting_count;
    filters[F_EECF].defaults.eecf = imu_eecf_default_settings;
    filters[F_KF1D].name = "kf1d";
    filters[F_KF1D].id = IMU_FILTER_KF1D;
    filters[F_KF1D].descs = imu_kf1d_setting_descs;
    filters[F_KF1D].count = imu_kf1d_setting_count;
    filters[F_KF1D].defaults.kf1d = imu_kf1d_default_settings;
    filters[F_ESKF].name = "eskf";
    filters[F_ESKF].id = IMU_FILTER_ESKF;
    filters[F_ESKF].descs = imu_eskf_setting_descs;
    filters[F_ESKF].count = imu_eskf_setting_count;
    filters[F_ESKF].defaults.eskf = imu_eskf_default_settings;
    filters[F_NAV].name = "nav";
    filters[F_NAV].id = IMU_FILTER_NAV;
    filters[F_NAV].descs = imu_navfilter_setting_descs;
    filters[F_NAV].count = imu_navfilter_setting_count;
    filters[F_NAV].defaults.nav = imu_navfilter_default_settings;
    quiet = 1;
    for (i = 0; i < N_FILTERS; ++i) {
        filter_info_t *fi = &filters[i];
        fi->rate_index = -1;
        if (fi->count > MAX_SETTINGS) {
            fprintf(stderr, "campaign: %s has more than %d settings\n", fi->name, MAX_SETTINGS);
            exit(2);
        }
        if (!accepted(fi, &fi->defaults)) {
            printf("OUTPUT %s: the default settings are rejected by set_settings\n", fi->name);
            ++problems;
        }
        for (k = 0; k < fi->count; ++k) {
            const imu_setting_desc_t *d = &fi->descs[k];
            if (strcmp(d->name, "sample_rate") == 0) {
                fi->rate_index = k;
            }
            quiet_failures = 0;
            fi->min[k] = bisect(fi, k, -1);
            fi->max[k] = bisect(fi, k, +1);
            if (print_ranges) {
                printf("RANGE %s %s %d %ld %ld %s\n", fi->name, d->name, d->frac_bits, (long)fi->min[k],
                       (long)fi->max[k], d->unit);
            }
            {
                /* The accepted set must be the interval [min, max]: probe 65 points inside. */
                settings_t s = fi->defaults;
                int p;
                for (p = 0; p <= 64; ++p) {
                    const int64_t v = fi->min[k] + ((int64_t)fi->max[k] - fi->min[k]) * p / 64;
                    set_raw(&s, d, (int32_t)v);
                    if (!accepted(fi, &s)) {
                        if (print_ranges) {
                            printf("OUTPUT %s.%s: %ld inside [%ld, %ld] is rejected (the range is not an interval)\n",
                                   fi->name, d->name, (long)v, (long)fi->min[k], (long)fi->max[k]);
                        }
                        ++problems;
                        break;
                    }
                }
            }
            if (print_ranges && quiet_failures > 0) {
                printf("OUTPUT %s.%s: set_settings overflowed int32 %ld times during the bisection of its range\n",
                       fi->name, d->name, quiet_failures);
                ++problems;
            }
        }
        if (fi->rate_index < 0) {
            fprintf(stderr, "campaign: %s has no sample_rate setting\n", fi->name);
            exit(2);
        }
    }
    quiet = 0;
    return problems;
}

/* ------------------------------------------------------------------ sensor variants */

enum {
    SENSOR_DEFAULT,
    SENSOR_GYRO_MAX,
    SENSOR_GYRO_MIN,
    SENSOR_ACC_MAX,
    SENSOR_ACC_MIN,
    SENSOR_MAG_MAX,
    SENSOR_MAG_MIN,
    SENSOR_ALL_MAX,
    SENSOR_ALL_MIN,
    SENSOR_ALL_ZERO,
    SENSOR_CAL_MAX,
    SENSOR_CAL_MIN,
    N_SENSORS
};
static const char *const SENSOR_NAMES[N_SENSORS] = {
    "sensor=default",   "gyro_scale=max", "gyro_scale=min", "acc_scale=max",  "acc_scale=min",
    "mag_scale=max",    "mag_scale=min",  "sensor_all=max", "sensor_all=min", "sensor_all=zero",
    "calibration=max",  "calibration=min"};

static imu_sensor_settings_t sensor_variant(int v)
{
    imu_sensor_settings_t s = imu_sensor_default_settings;
    switch (v) {
    case SENSOR_GYRO_MAX: s.gyro_scale = INT32_MAX; break;
    case SENSOR_GYRO_MIN: s.gyro_scale = INT32_MIN; break;
    case SENSOR_ACC_MAX: s.acc_scale = INT32_MAX; break;
    case SENSOR_ACC_MIN: s.acc_scale = INT32_MIN; break;
    case SENSOR_MAG_MAX: s.mag_scale = INT32_MAX; break;
    case SENSOR_MAG_MIN: s.mag_scale = INT32_MIN; break;
    case SENSOR_ALL_MAX: s.gyro_scale = s.acc_scale = s.mag_scale = INT32_MAX; break;
    case SENSOR_ALL_MIN: s.gyro_scale = s.acc_scale = s.mag_scale = INT32_MIN; break;
    case SENSOR_ALL_ZERO: s.gyro_scale = s.acc_scale = s.mag_scale = 0; break;
    default: break;
    }
    return s;
}

/** The calibration of a sensor variant: the identity, or every offset at the largest magnitude
 *  imu_calibration_check() accepts and every matrix element at an int32 extreme (the bound of
 *  the corrected sums in imu_sensor.h, then saturation). */
static imu_calibration_t calibration_variant(int v)
{
    imu_calibration_t cal = imu_calibration_identity;
    imu_sensor_cal_t *sensors[3];
    int i, k;
    if (v != SENSOR_CAL_MAX && v != SENSOR_CAL_MIN) {
        return cal;
    }
    sensors[0] = &cal.gyr;
    sensors[1] = &cal.acc;
    sensors[2] = &cal.mag;
    for (i = 0; i < 3; ++i) {
        for (k = 0; k < 3; ++k) {
            sensors[i]->offset[k] = v == SENSOR_CAL_MAX ? IMU_CAL_MAX_OFFSET : -IMU_CAL_MAX_OFFSET;
        }
        for (k = 0; k < 9; ++k) {
            sensors[i]->matrix[k] = v == SENSOR_CAL_MAX ? INT32_MAX : INT32_MIN;
        }
    }
    return cal;
}

/* ------------------------------------------------------------------ input streams (int16 counts) */

enum {
    S_STILL,
    S_ZEROS,
    S_INT16_MAX,
    S_INT16_MIN,
    S_INT16_MIXED,
    S_ALT_SATURATION,
    S_ALT_SAT_STILL,
    S_RANDOM,
    S_RANDOM_UNCLIPPED,
    S_SPIN_Z,
    S_SPIN_X,
    S_SPIN_XYZ,
    S_SPIN_NOISY,
    S_FREEFALL,
    S_FREEFALL_SPIN,
    S_DROP,
    N_STREAMS
};
static const char *const STREAM_NAMES[N_STREAMS] = {
    "still",     "zeros",  "int16_max", "int16_min", "int16_mixed",   "alt_saturation", "alt_sat_still", "random",
    "random_unclipped", "spin_z", "spin_x", "spin_xyz", "spin_noisy", "freefall", "freefall_spin", "drop"};

/** Counts of the default profile: 1 g (+-8 g: 4096 LSB/g), a 49 uT field with 63 deg dip
 *  (HMC5883L at 1090 LSB/G: 218 counts north, 436 down), the gyroscope's 16.4 LSB/(deg/s). */
#define G_COUNTS 4096.0
static const double EARTH_ACC[3] = {0.0, 0.0, G_COUNTS};
static const double EARTH_MAG[3] = {0.0, 218.0, -436.0};
#define GYRO_RAD_PER_COUNT (PI / 180.0 / 16.4)
/** Near full scale but below the clipping limit (imu_sensor.h flags >= 32767). */
#define NEAR_FS 32766

static uint64_t rng_state;

static uint64_t rng_next(void)
{
    /* splitmix64 */
    uint64_t z = (rng_state += UINT64_C(0x9E3779B97F4A7C15));
    z = (z ^ (z >> 30)) * UINT64_C(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)) * UINT64_C(0x94D049BB133111EB);
    return z ^ (z >> 31);
}

/** Uniform integer in [lo, hi]. */
static int32_t rng_int(int32_t lo, int32_t hi)
{
    return (int32_t)(lo + (int64_t)(rng_next() % (uint64_t)((int64_t)hi - lo + 1)));
}

static int16_t count_of(double v)
{
    const double r = floor(v + 0.5);
    return (int16_t)(r > 32767.0 ? 32767 : (r < -32768.0 ? -32768 : r));
}

/** v rotated by -angle about the unit axis: an earth vector seen from a sensor turned by angle. */
static void sensor_view(const double axis[3], double angle, const double v[3], double out[3])
{
    const double c = cos(-angle), s = sin(-angle);
    const double dot = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2];
    const double cross[3] = {axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2],
                             axis[0] * v[1] - axis[1] * v[0]};
    int k;
    for (k = 0; k < 3; ++k) {
        out[k] = v[k] * c + cross[k] * s + axis[k] * dot * (1.0 - c);
    }
}

static void fill_all(imu_raw_sample_t *raw, int16_t v)
{
    int k;
    for (k = 0; k < 3; ++k) {
        raw->gyr[k] = raw->acc[k] = raw->mag[k] = v;
    }
}

static void still_sample(imu_raw_sample_t *raw)
{
    int k;
    for (k = 0; k < 3; ++k) {
        raw->gyr[k] = (int16_t)rng_int(-3, 3);
        raw->acc[k] = count_of(EARTH_ACC[k] + rng_int(-20, 20));
        raw->mag[k] = count_of(EARTH_MAG[k] + rng_int(-3, 3));
    }
}

/** Rotation about a fixed sensor axis at gyro counts `gyr` (the counts' direction is the axis),
 *  gravity and field consistent with it. */
static void spin_sample(imu_raw_sample_t *raw, const int16_t gyr[3], long n, double rate_hz)
{
    const double w[3] = {gyr[0] * GYRO_RAD_PER_COUNT, gyr[1] * GYRO_RAD_PER_COUNT, gyr[2] * GYRO_RAD_PER_COUNT};
    const double len = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    const double axis[3] = {w[0] / len, w[1] / len, w[2] / len};
    const double angle = len * (double)(n + 1) / rate_hz; /* sample n closes the interval ending at (n+1)/rate */
    double acc[3], mag[3];
    int k;
    sensor_view(axis, angle, EARTH_ACC, acc);
    sensor_view(axis, angle, EARTH_MAG, mag);
    for (k = 0; k < 3; ++k) {
        raw->gyr[k] = gyr[k];
        raw->acc[k] = count_of(acc[k]);
        raw->mag[k] = count_of(mag[k]);
    }
}

static void stream_sample(int stream, long n, long length, double rate_hz, imu_raw_sample_t *raw)
{
    int k;
    switch (stream) {
    case S_STILL:
        still_sample(raw);
        break;
    case S_ZEROS:
        fill_all(raw, 0);
        break;
    case S_INT16_MAX:
        fill_all(raw, INT16_MAX);
        break;
    case S_INT16_MIN:
        fill_all(raw, INT16_MIN);
        break;
    case S_INT16_MIXED:
        for (k = 0; k < 3; ++k) {
            raw->gyr[k] = (k % 2 == 0) ? INT16_MAX : INT16_MIN;
            raw->acc[k] = (k % 2 == 0) ? INT16_MIN : INT16_MAX;
            raw->mag[k] = (k % 2 == 0) ? INT16_MAX : INT16_MIN;
        }
        break;
    case S_ALT_SATURATION:
        fill_all(raw, n % 2 == 0 ? INT16_MAX : INT16_MIN);
        break;
    case S_ALT_SAT_STILL:
        if (n % 2 == 0) {
            still_sample(raw);
        } else {
            fill_all(raw, (n / 2) % 2 == 0 ? INT16_MAX : INT16_MIN);
        }
        break;
    case S_RANDOM:
        for (k = 0; k < 3; ++k) {
            raw->gyr[k] = (int16_t)rng_int(INT16_MIN, INT16_MAX);
            raw->acc[k] = (int16_t)rng_int(INT16_MIN, INT16_MAX);
            raw->mag[k] = (int16_t)rng_int(INT16_MIN, INT16_MAX);
        }
        break;
    case S_RANDOM_UNCLIPPED:
        for (k = 0; k < 3; ++k) {
            raw->gyr[k] = (int16_t)rng_int(-NEAR_FS, NEAR_FS);
            raw->acc[k] = (int16_t)rng_int(-NEAR_FS, NEAR_FS);
            raw->mag[k] = (int16_t)rng_int(imu_sensor_default_settings.mag_limits[0] + 1, imu_sensor_default_settings.mag_limits[1] - 1);
        }
        break;
    case S_SPIN_Z: {
        const int16_t gyr[3] = {0, 0, NEAR_FS};
        spin_sample(raw, gyr, n, rate_hz);
        break;
    }
    case S_SPIN_X: {
        const int16_t gyr[3] = {-NEAR_FS, 0, 0};
        spin_sample(raw, gyr, n, rate_hz);
        break;
    }
    case S_SPIN_XYZ: {
        const int16_t gyr[3] = {NEAR_FS, -NEAR_FS, NEAR_FS};
        spin_sample(raw, gyr, n, rate_hz);
        break;
    }
    case S_SPIN_NOISY:
        still_sample(raw);
        for (k = 0; k < 3; ++k) {
            const int32_t v = rng_int(29000, INT16_MAX); /* clips now and then */
            raw->gyr[k] = (int16_t)((n / 64 + k) % 2 == 0 ? v : -v);
        }
        break;
    case S_FREEFALL:
        still_sample(raw);
        for (k = 0; k < 3; ++k) {
            raw->acc[k] = 0;
        }
        break;
    case S_FREEFALL_SPIN:
        still_sample(raw);
        raw->gyr[0] = 20000;
        raw->gyr[1] = 0;
        raw->gyr[2] = -20000;
        for (k = 0; k < 3; ++k) {
            raw->acc[k] = 0;
        }
        break;
    default: /* S_DROP: still, free fall, impact (clipped), ringing, still */
        still_sample(raw);
        if (n >= length / 3 && n < length / 2) {
            for (k = 0; k < 3; ++k) {
                raw->acc[k] = 0;
            }
        } else if (n >= length / 2 && n < length / 2 + 4) {
            raw->acc[2] = INT16_MAX;
            raw->acc[0] = INT16_MIN;
            raw->gyr[1] = (int16_t)rng_int(INT16_MIN, INT16_MAX);
        } else if (n >= length / 2 + 4 && n < length / 2 + 40) {
            raw->acc[2] = (int16_t)rng_int(-20000, 30000);
            raw->gyr[0] = (int16_t)rng_int(-20000, 20000);
        }
        break;
    }
}

/* ------------------------------------------------------------------ cases */

/** Settings variant: VAR_DEFAULT, a setting k at its minimum (VAR_MIN + k) or maximum
 *  (VAR_MAX + k), all settings at their minimum or maximum. */
enum { VAR_DEFAULT = 0, VAR_ALL_MIN = 1, VAR_ALL_MAX = 2, VAR_MIN = 100, VAR_MAX = 200 };
/** Sample rate: the variant's own sample_rate, or overridden to 30 Hz / 5 kHz (at most the filter's largest). */
enum { RATE_OWN = 0, RATE_30 = 1, RATE_5K = 2 };

typedef struct {
    int filter;
    int variant;
    int rate;
    int sensor;
    int stream;
} case_t;

static case_t cases[MAX_CASES];
static int n_cases;

static void add(int filter, int variant, int rate, int sensor)
{
    int s;
    for (s = 0; s < N_STREAMS; ++s) {
        case_t *c = &cases[n_cases++];
        if (n_cases > MAX_CASES) {
            fprintf(stderr, "campaign: more than %d cases\n", MAX_CASES);
            exit(2);
        }
        c->filter = filter;
        c->variant = variant;
        c->rate = rate;
        c->sensor = sensor;
        c->stream = s;
    }
}

static void enumerate_cases(void)
{
    int f, k, r, v;
    for (f = 0; f < N_FILTERS; ++f) {
        const filter_info_t *fi = &filters[f];
        for (r = RATE_30; r <= RATE_5K; ++r) {
            add(f, VAR_DEFAULT, r, SENSOR_DEFAULT);
        }
        for (k = 0; k < fi->count; ++k) {
            for (v = VAR_MIN; v <= VAR_MAX; v += VAR_MAX - VAR_MIN) {
                if (k == fi->rate_index) {
                    add(f, v + k, RATE_OWN, SENSOR_DEFAULT);
                } else {
                    for (r = RATE_30; r <= RATE_5K; ++r) {
                        add(f, v + k, r, SENSOR_DEFAULT);
                    }
                }
            }
        }
        for (v = VAR_ALL_MIN; v <= VAR_ALL_MAX; ++v) {
            for (r = RATE_OWN; r <= RATE_5K; ++r) {
                add(f, v, r, SENSOR_DEFAULT);
            }
        }
        for (k = SENSOR_DEFAULT + 1; k < N_SENSORS; ++k) {
            for (r = RATE_30; r <= RATE_5K; ++r) {
                add(f, VAR_DEFAULT, r, k);
            }
        }
        for (k = SENSOR_ALL_MAX; k <= SENSOR_ALL_MIN; ++k) {
            for (r = RATE_30; r <= RATE_5K; ++r) {
                add(f, VAR_ALL_MAX, r, k);
                add(f, VAR_ALL_MIN, r, k);
            }
        }
    }
}

static settings_t case_settings(const case_t *c)
{
    const filter_info_t *fi = &filters[c->filter];
    settings_t s = fi->defaults;
    int k;
    if (c->variant == VAR_ALL_MIN || c->variant == VAR_ALL_MAX) {
        for (k = 0; k < fi->count; ++k) {
            set_raw(&s, &fi->descs[k], c->variant == VAR_ALL_MIN ? fi->min[k] : fi->max[k]);
        }
    } else if (c->variant >= VAR_MAX) {
        set_raw(&s, &fi->descs[c->variant - VAR_MAX], fi->max[c->variant - VAR_MAX]);
    } else if (c->variant >= VAR_MIN) {
        set_raw(&s, &fi->descs[c->variant - VAR_MIN], fi->min[c->variant - VAR_MIN]);
    }
    if (c->rate == RATE_30) {
        set_raw(&s, &fi->descs[fi->rate_index], IMU_QCONST(30.0, 16));
    } else if (c->rate == RATE_5K) {
        /* 5 kHz, or the filter's largest rate below it (nav: 1 kHz) */
        const int32_t fast = IMU_QCONST(5000.0, 16);
        set_raw(&s, &fi->descs[fi->rate_index], fi->max[fi->rate_index] < fast ? fi->max[fi->rate_index] : fast);
    }
    return s;
}

static double case_rate_hz(const case_t *c)
{
    const filter_info_t *fi = &filters[c->filter];
    const settings_t s = case_settings(c);
    return get_raw(&s, &fi->descs[fi->rate_index]) / 65536.0;
}

static void case_name(const case_t *c, char *out, size_t size)
{
    const filter_info_t *fi = &filters[c->filter];
    char variant[96];
    char rate[32];
    if (c->variant == VAR_DEFAULT) {
        snprintf(variant, sizeof variant, "default");
    } else if (c->variant == VAR_ALL_MIN || c->variant == VAR_ALL_MAX) {
        snprintf(variant, sizeof variant, "all=%s", c->variant == VAR_ALL_MIN ? "min" : "max");
    } else if (c->variant >= VAR_MAX) {
        snprintf(variant, sizeof variant, "%s=max", fi->descs[c->variant - VAR_MAX].name);
    } else {
        snprintf(variant, sizeof variant, "%s=min", fi->descs[c->variant - VAR_MIN].name);
    }
    if (c->rate == RATE_30) {
        snprintf(rate, sizeof rate, "30Hz");
    } else if (c->rate == RATE_5K) {
        snprintf(rate, sizeof rate, "%gkHz", case_rate_hz(c) / 1000.0);
    } else {
        snprintf(rate, sizeof rate, "own_rate=%.5gHz", case_rate_hz(c));
    }
    snprintf(out, size, "%s/%s/%s/%s/%s", fi->name, variant, SENSOR_NAMES[c->sensor], STREAM_NAMES[c->stream], rate);
}

/** Settings that differ from the defaults, as name=raw(real), and the sensor scales. */
static void describe_settings(const case_t *c, const settings_t *s, const imu_sensor_settings_t *sensor)
{
    const filter_info_t *fi = &filters[c->filter];
    size_t used = 0;
    int k;
    current_settings[0] = '\0';
    for (k = 0; k < fi->count; ++k) {
        const int32_t v = get_raw(s, &fi->descs[k]);
        if (v != get_raw(&fi->defaults, &fi->descs[k]) && used < sizeof current_settings) {
            used += (size_t)snprintf(current_settings + used, sizeof current_settings - used, "%s=%ld(Q%d: %.6g %s) ",
                                     fi->descs[k].name, (long)v, fi->descs[k].frac_bits,
                                     ldexp((double)v, -fi->descs[k].frac_bits), fi->descs[k].unit);
        }
    }
    if (used < sizeof current_settings) {
        snprintf(current_settings + used, sizeof current_settings - used,
                 "[sensor gyro_scale=%ld acc_scale=%ld mag_scale=%ld]", (long)sensor->gyro_scale,
                 (long)sensor->acc_scale, (long)sensor->mag_scale);
    }
}

/** Samples of a case: enough for every phase within reach (ESKF dip learning: 10 s; EECF
 *  alignment: align_time, capped at ALIGN_CAP samples beyond which only the alignment runs). */
#define POST_SAMPLES 600L
#define ALIGN_CAP 10500L

static long case_length(const case_t *c)
{
    const double rate = case_rate_hz(c);
    long n = POST_SAMPLES;
    if (c->filter == F_EECF) {
        const settings_t s = case_settings(c);
        const double align = s.eecf.align_time / 65536.0 * rate;
        n += align < ALIGN_CAP ? (long)align : ALIGN_CAP;
    }
    if (c->filter == F_ESKF && rate < 100.0) {
        n += (long)(12.0 * rate); /* past the dip learning at low rates */
    }
    return n;
}

static long total_samples;

/** Run one case; 0 when clean, 1 after an OUTPUT report (narrowing and sanitizer errors abort). */
static int run_case(int index)
{
    const case_t *c = &cases[index];
    const filter_info_t *fi = &filters[c->filter];
    const settings_t s = case_settings(c);
    const imu_sensor_settings_t sensor = sensor_variant(c->sensor);
    const double rate = case_rate_hz(c);
    const long length = case_length(c);
    imu_filter_t f;
    long n;
    int status;

    case_name(c, current_case, sizeof current_case);
    describe_settings(c, &s, &sensor);
    printf("CASE %d %s\n", index, current_case);
    fflush(stdout);
    rng_state = UINT64_C(0x1234567) + (uint64_t)index * UINT64_C(7919);
    current_sample = -1;
    memset(&f, 0, sizeof f);
    (void)imu_filter_init(&f, fi->id);
    status = (int)imu_filter_set_settings(&f, &s);
    if (status != IMU_OK) {
        printf("OUTPUT set_settings rejected the settings (status %d) | case %s | settings %s\n", status, current_case,
               current_settings);
        return 1;
    }
    imu_filter_set_sensor(&f, &sensor);
    {
        const imu_calibration_t cal = calibration_variant(c->sensor);
        if (imu_filter_set_calibration(&f, &cal) != IMU_OK) {
            printf("OUTPUT set_calibration rejected the calibration | case %s\n", current_case);
            return 1;
        }
    }
    for (n = 0; n < length; ++n) {
        imu_raw_sample_t raw;
        imu_output_t out;
        double norm2 = 0.0;
        int k;
        current_sample = n;
        stream_sample(c->stream, n, length, rate, &raw);
        imu_filter_update_raw(&f, &raw);
        imu_filter_get(&f, &out);
        for (k = 0; k < 4; ++k) {
            const double q = ldexp((double)out.quat[k], -30);
            norm2 += q * q;
        }
        if (fabs(norm2 - 1.0) > 1e-6) {
            printf("OUTPUT quaternion norm^2 %.9f | case %s | sample %ld | settings %s\n", norm2, current_case, n,
                   current_settings);
            return 1;
        }
        for (k = 0; k < 3; ++k) {
            if (out.euler[k] > IMU_PI_ANGLE || out.euler[k] <= -IMU_PI_ANGLE) {
                printf("OUTPUT euler[%d] = %ld outside (-pi, pi] | case %s | sample %ld | settings %s\n", k,
                       (long)out.euler[k], current_case, n, current_settings);
                return 1;
            }
        }
    }
    total_samples += length;
    return 0;
}

/** run_case, with narrowing failures abandoning the case under --keep-going. */
static int run_case_guarded(int index)
{
    int result;
    if (setjmp(case_escape) != 0) {
        in_case = 0;
        return 1;
    }
    in_case = 1;
    result = run_case(index);
    in_case = 0;
    return result;
}

/* ------------------------------------------------------------------ main */

static int filter_index(const char *name)
{
    int f;
    for (f = 0; f < N_FILTERS; ++f) {
        if (strcmp(filters[f].name, name) == 0) {
            return f;
        }
    }
    fprintf(stderr, "campaign: unknown filter %s\n", name);
    exit(2);
}

int main(int argc, char **argv)
{
    const char *only_filter = NULL;
    const char *only_case = NULL;
    long from = 0, to = -1;
    int list = 0, ranges = 0;
    int i, failures = 0, ran = 0;
    int problems;
    for (i = 1; i < argc; ++i) {
        if (strcmp(argv[i], "--list") == 0) {
            list = 1;
        } else if (strcmp(argv[i], "--ranges") == 0) {
            ranges = 1;
        } else if (strcmp(argv[i], "--keep-going") == 0) {
            keep_going = 1;
        } else if (strcmp(argv[i], "--filter") == 0 && i + 1 < argc) {
            only_filter = argv[++i];
        } else if (strcmp(argv[i], "--case") == 0 && i + 1 < argc) {
            only_case = argv[++i];
        } else if (strcmp(argv[i], "--from") == 0 && i + 1 < argc) {
            from = strtol(argv[++i], NULL, 10);
        } else if (strcmp(argv[i], "--to") == 0 && i + 1 < argc) {
            to = strtol(argv[++i], NULL, 10);
        } else {
            fprintf(stderr, "usage: %s [--ranges] [--list] [--filter eecf|kf1d|eskf|nav] [--from I] [--to J] "
                            "[--case NAME] [--keep-going]\n", argv[0]);
            return 2;
        }
    }
    problems = setup_filters(ranges);
    if (ranges) {
        return problems == 0 ? 0 : 1;
    }
    enumerate_cases();
    if (to < 0 || to > n_cases) {
        to = n_cases;
    }
    for (i = (int)from; i < to; ++i) {
        char name[NAME_LEN];
        if (only_filter != NULL && cases[i].filter != filter_index(only_filter)) {
            continue;
        }
        case_name(&cases[i], name, sizeof name);
        if (only_case != NULL && strcmp(name, only_case) != 0) {
            continue;
        }
        if (list) {
            printf("%d %s %ld\n", i, name, case_length(&cases[i]));
            continue;
        }
        failures += run_case_guarded(i);
        ++ran;
    }
    if (only_case != NULL && ran == 0 && !list) {
        fprintf(stderr, "campaign: no case named %s (see --list)\n", only_case);
        return 2;
    }
    if (!list) {
        printf("DONE cases=%d samples=%ld failures=%d\n", ran, total_samples, failures);
    }
    return failures == 0 ? 0 : 1;
}
