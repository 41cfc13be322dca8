/**
 * @file vector_driver.c
 * @brief Replays golden vectors (the .vec files in shared/vectors) through the fixed-point core.
 *
 * Compiled directly against firmware/core with -DIMU_FIXED (see tests/test_c_build.py):
 *
 *     gcc -std=c99 -DIMU_FIXED -Ifirmware/core tests/c/vector_driver.c firmware/core/imu_*.c -o vector_driver
 *     ./vector_driver shared/vectors/eecf_random.vec [more.vec ...]
 *
 * For each file: the settings are built from a copy of the filter's default
 * settings struct by writing every raw int32 of the file at the offset given by
 * the filter's descriptor table (every descriptor must be present in the file with
 * the same Q format, and the file may name no other setting), the sensor scales are
 * set from their raw int32, and every sample runs through imu_filter_update_raw and
 * imu_filter_get. Every output integer and the final saturation count are compared.
 * The first mismatch (or format error) is printed and the exit status is 1; 0 when
 * every file matches. The file format is described in shared/vectors/README.md.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "imu_filter.h"

#define MAX_LINE 1024
#define MAX_SETTINGS 64
#define NAME_LEN 64
#define N_IN 9
#define N_OUT 10

static const char *const COLUMNS =
    "gyr_x gyr_y gyr_z acc_x acc_y acc_z mag_x mag_y mag_z "
    "quat_w quat_x quat_y quat_z roll pitch heading bias_x bias_y bias_z";

static const char *const OUT_NAMES[N_OUT] = {"quat_w", "quat_x", "quat_y",  "quat_z", "roll",
                                             "pitch",  "heading", "bias_x", "bias_y", "bias_z"};

typedef struct {
    char name[NAME_LEN];
    int frac_bits;
    long raw;
    int used;
} file_setting_t;

typedef struct {
    const char *path;
    FILE *fp;
    long line_no;
    char line[MAX_LINE];
} reader_t;

/** Next line without its newline; 0 at end of file, -1 (with a message) on an over-long line. */
static int next_line(reader_t *r)
{
    size_t len;
    if (fgets(r->line, sizeof r->line, r->fp) == NULL) {
        return 0;
    }
    ++r->line_no;
    len = strlen(r->line);
    if (len > 0 && r->line[len - 1] == '\n') {
        r->line[--len] = '\0';
    } else if (!feof(r->fp)) {
        fprintf(stderr, "%s:%ld: line longer than %d characters\n", r->path, r->line_no, MAX_LINE - 2);
        return -1;
    }
    return 1;
}

/** Parse a decimal integer in [lo, hi] at *p, advancing *p past it; 0 on error. */
static int parse_long(const char **p, long lo, long hi, long *out)
{
    char *end;
    long v;
    errno = 0;
    v = strtol(*p, &end, 10);
    if (end == *p || errno != 0 || v < lo || v > hi || (*end != ' ' && *end != '\0')) {
        return 0;
    }
    *p = end;
    *out = v;
    return 1;
}

static int fail(const reader_t *r, const char *what)
{
    fprintf(stderr, "%s:%ld: %s\n", r->path, r->line_no, what);
    return 1;
}

/** Replay one vector file; 0 when every output matches. */
static int run_file(const char *path)
{
    reader_t r;
    file_setting_t settings[MAX_SETTINGS];
    int n_settings = 0;
    int have_format = 0, have_columns = 0;
    int filter_id = 0;
    long samples = -1, expected_saturations = -1;
    long sensor_raw[3] = {0, 0, 0};
    int have_sensor[3] = {0, 0, 0};
    static const char *const SENSOR_NAMES[3] = {"gyro_scale", "acc_scale", "mag_scale"};
    static const int SENSOR_FRAC[3] = {40, 32, 24};
    imu_filter_t filter;
    imu_sensor_settings_t sensor;
    union {
        imu_eecf_settings_t eecf;
        imu_kf1d_settings_t kf1d;
        imu_eskf_settings_t eskf;
    } values;
    const imu_setting_desc_t *descs;
    int n_descs;
    long i;
    int k, status;

    memset(&r, 0, sizeof r);
    r.path = path;
    r.fp = fopen(path, "r");
    if (r.fp == NULL) {
        fprintf(stderr, "%s: cannot open\n", path);
        return 1;
    }

    /* ---- header ---- */
    for (;;) {
        char key[NAME_LEN];
        int got = next_line(&r);
        if (got <= 0) {
            fclose(r.fp);
            return got < 0 ? 1 : fail(&r, "end of file before the 'data' line");
        }
        if (r.line[0] == '\0' || r.line[0] == '#') {
            continue;
        }
        if (strcmp(r.line, "data") == 0) {
            break;
        }
        if (sscanf(r.line, "%63s", key) != 1) {
            fclose(r.fp);
            return fail(&r, "bad header line");
        }
        if (strcmp(key, "format") == 0) {
            if (strcmp(r.line, "format imulink-vector 1") != 0) {
                fclose(r.fp);
                return fail(&r, "unsupported format (expected 'format imulink-vector 1')");
            }
            have_format = 1;
        } else if (strcmp(key, "filter_id") == 0) {
            if (sscanf(r.line, "filter_id %d", &filter_id) != 1) {
                fclose(r.fp);
                return fail(&r, "bad filter_id line");
            }
        } else if (strcmp(key, "samples") == 0) {
            if (sscanf(r.line, "samples %ld", &samples) != 1 || samples < 0) {
                fclose(r.fp);
                return fail(&r, "bad samples line");
            }
        } else if (strcmp(key, "saturations") == 0) {
            if (sscanf(r.line, "saturations %ld", &expected_saturations) != 1 || expected_saturations < 0) {
                fclose(r.fp);
                return fail(&r, "bad saturations line");
            }
        } else if (strcmp(key, "columns") == 0) {
            if (strcmp(r.line + strlen("columns "), COLUMNS) != 0) {
                fclose(r.fp);
                return fail(&r, "unexpected columns");
            }
            have_columns = 1;
        } else if (strcmp(key, "sensor") == 0) {
            char name[NAME_LEN];
            int frac;
            long raw;
            if (sscanf(r.line, "sensor %63s %d %ld", name, &frac, &raw) != 3) {
                fclose(r.fp);
                return fail(&r, "bad sensor line");
            }
            for (k = 0; k < 3; ++k) {
                if (strcmp(name, SENSOR_NAMES[k]) == 0) {
                    break;
                }
            }
            if (k == 3 || frac != SENSOR_FRAC[k] || raw < INT32_MIN || raw > INT32_MAX) {
                fclose(r.fp);
                return fail(&r, "unknown sensor scale, wrong Q format or raw value outside int32");
            }
            sensor_raw[k] = raw;
            have_sensor[k] = 1;
        } else if (strcmp(key, "setting") == 0) {
            file_setting_t *s = &settings[n_settings];
            if (n_settings == MAX_SETTINGS) {
                fclose(r.fp);
                return fail(&r, "too many settings");
            }
            if (sscanf(r.line, "setting %63s %d %ld", s->name, &s->frac_bits, &s->raw) != 3 ||
                s->raw < INT32_MIN || s->raw > INT32_MAX) {
                fclose(r.fp);
                return fail(&r, "bad setting line (name, Q format, raw int32 expected)");
            }
            s->used = 0;
            ++n_settings;
        }
        /* Other keys (name, filter, scenario, description, seed, rate_hz) are informative. */
    }
    if (!have_format || !have_columns || samples < 0 || expected_saturations < 0 || !have_sensor[0] ||
        !have_sensor[1] || !have_sensor[2]) {
        fclose(r.fp);
        return fail(&r, "header lacks format, columns, samples, saturations or a sensor scale");
    }

    /* ---- filter, settings through the descriptor table, sensor scales ---- */
    memset(&filter, 0, sizeof filter);
    if (imu_filter_init(&filter, filter_id) != IMU_OK) {
        fclose(r.fp);
        return fail(&r, "unknown filter_id");
    }
    if (filter_id == IMU_FILTER_EECF) {
        values.eecf = imu_eecf_default_settings;
        descs = imu_eecf_setting_descs;
        n_descs = imu_eecf_setting_count;
    } else if (filter_id == IMU_FILTER_KF1D) {
        values.kf1d = imu_kf1d_default_settings;
        descs = imu_kf1d_setting_descs;
        n_descs = imu_kf1d_setting_count;
    } else {
        values.eskf = imu_eskf_default_settings;
        descs = imu_eskf_setting_descs;
        n_descs = imu_eskf_setting_count;
    }
    for (k = 0; k < n_descs; ++k) {
        int j;
        int32_t raw;
        for (j = 0; j < n_settings; ++j) {
            if (strcmp(settings[j].name, descs[k].name) == 0) {
                break;
            }
        }
        if (j == n_settings) {
            fprintf(stderr, "%s: setting %s of the C core is missing from the vector\n", path, descs[k].name);
            fclose(r.fp);
            return 1;
        }
        if (settings[j].frac_bits != descs[k].frac_bits) {
            fprintf(stderr, "%s: setting %s is Q%d in the vector but Q%d in the C core\n", path, descs[k].name,
                    settings[j].frac_bits, descs[k].frac_bits);
            fclose(r.fp);
            return 1;
        }
        raw = (int32_t)settings[j].raw;
        memcpy((char *)&values + descs[k].offset, &raw, sizeof raw);
        settings[j].used = 1;
    }
    for (k = 0; k < n_settings; ++k) {
        if (!settings[k].used) {
            fprintf(stderr, "%s: the C core has no setting %s\n", path, settings[k].name);
            fclose(r.fp);
            return 1;
        }
    }
    status = (int)imu_filter_set_settings(&filter, &values);
    if (status != IMU_OK) {
        fprintf(stderr, "%s: imu_filter_set_settings rejected the settings (status %d)\n", path, status);
        fclose(r.fp);
        return 1;
    }
    sensor = imu_sensor_default_settings; /* the vectors' counts are the GY-86's: its registers' limits */
    sensor.gyro_scale = (int32_t)sensor_raw[0];
    sensor.acc_scale = (int32_t)sensor_raw[1];
    sensor.mag_scale = (int32_t)sensor_raw[2];
    imu_filter_set_sensor(&filter, &sensor);

    /* ---- samples ---- */
    for (i = 0; i < samples; ++i) {
        imu_raw_sample_t raw;
        imu_output_t out;
        int32_t got[N_OUT];
        long v;
        const char *p;
        int line_status = next_line(&r);
        if (line_status <= 0) {
            fclose(r.fp);
            return line_status < 0 ? 1 : fail(&r, "fewer data lines than 'samples'");
        }
        p = r.line;
        for (k = 0; k < N_IN; ++k) {
            if (!parse_long(&p, INT16_MIN, INT16_MAX, &v)) {
                fclose(r.fp);
                return fail(&r, "bad input count (int16 expected)");
            }
            if (k < 3) {
                raw.gyr[k] = (int16_t)v;
            } else if (k < 6) {
                raw.acc[k - 3] = (int16_t)v;
            } else {
                raw.mag[k - 6] = (int16_t)v;
            }
        }
        imu_filter_update_raw(&filter, &raw);
        imu_filter_get(&filter, &out);
        for (k = 0; k < 4; ++k) {
            got[k] = out.quat[k];
        }
        for (k = 0; k < 3; ++k) {
            got[4 + k] = out.euler[k];
            got[7 + k] = out.gyro_bias[k];
        }
        for (k = 0; k < N_OUT; ++k) {
            if (!parse_long(&p, INT32_MIN, INT32_MAX, &v)) {
                fclose(r.fp);
                return fail(&r, "bad output value (int32 expected)");
            }
            if ((int32_t)v != got[k]) {
                fprintf(stderr, "%s:%ld: MISMATCH at sample %ld, field %s: expected %ld, got %ld\n", path, r.line_no,
                        i, OUT_NAMES[k], v, (long)got[k]);
                fclose(r.fp);
                return 1;
            }
        }
        if (*p != '\0') {
            fclose(r.fp);
            return fail(&r, "more than 19 values on a data line");
        }
    }
    if (next_line(&r) != 1 || strcmp(r.line, "end") != 0) {
        fclose(r.fp);
        return fail(&r, "expected 'end' after the data lines");
    }
    fclose(r.fp);
    if ((long)imu_filter_saturations(&filter) != expected_saturations) {
        fprintf(stderr, "%s: MISMATCH in saturations: expected %ld, got %lu\n", path, expected_saturations,
                (unsigned long)imu_filter_saturations(&filter));
        return 1;
    }
    printf("%s: OK, %ld samples\n", path, samples);
    return 0;
}

int main(int argc, char **argv)
{
    int i;
    int failures = 0;
    if (argc < 2) {
        fprintf(stderr, "usage: %s VECTOR.vec [VECTOR.vec ...]\n", argv[0]);
        return 2;
    }
    for (i = 1; i < argc; ++i) {
        failures += run_file(argv[i]);
    }
    return failures == 0 ? 0 : 1;
}
