"""cffi build script: the C core compiled twice from the same sources.

`imulink.core._fixed` is the firmware arithmetic (IMU_FIXED, integer only);
`imulink.core._float` is the float twin (IMU_FLOAT, double). Both expose the same
declarations; only the arithmetic-layer typedefs differ.
"""
import runpy
from pathlib import Path

from cffi import FFI

ROOT = Path(__file__).resolve().parents[3]
CORE_DIR = ROOT / "firmware" / "core"
CORE_SOURCES = ["imu_math.c", "imu_settings.c", "imu_sensor.c", "imu_cov.c", "imu_rest.c", "imu_eecf.c", "imu_kf1d.c",
                "imu_eskf.c", "imu_filter.c", "imu_proto.c", "imu_proto_gen.c", "imu_nav.c", "imu_navcov.c",
                "imu_navkf.c", "imu_navfilter.c", "imu_wire.c"]

_TYPEDEFS = {
    "fixed": """
        typedef int32_t imu_q30_t; typedef int32_t imu_angle_t; typedef int32_t imu_rate_t;
        typedef int32_t imu_q16_t; typedef int32_t imu_real_t;
    """,
    "float": """
        typedef double imu_q30_t; typedef double imu_angle_t; typedef double imu_rate_t;
        typedef double imu_q16_t; typedef double imu_real_t;
    """,
}

# The declarations generated from shared/protocol.toml by tools/gen_protocol.py.
_SCHEMA = runpy.run_path(str(Path(__file__).parents[1] / "protocol" / "_schema.py"))

_DECLARATIONS = """
    typedef enum { IMU_OK = 0, IMU_ERR_RANGE = -1, IMU_ERR_UNKNOWN = -2 } imu_status_t;
"""
# The filter ids (imu_filter_id_t): the values of the schema's filter code table.
_DECLARATIONS += _SCHEMA["CFFI_FILTER_ID"]
_DECLARATIONS += """
    typedef struct { int16_t gyr[3]; int16_t acc[3]; int16_t mag[3]; } imu_raw_sample_t;
    typedef struct { imu_real_t gyro_scale; imu_real_t acc_scale; imu_real_t mag_scale; int16_t gyro_limits[2];
                     int16_t acc_limits[2]; int16_t mag_limits[2]; } imu_sensor_settings_t;
    typedef struct { imu_real_t offset[3]; imu_real_t matrix[9]; } imu_sensor_cal_t;
    typedef struct { imu_sensor_cal_t gyr; imu_sensor_cal_t acc; imu_sensor_cal_t mag; } imu_calibration_t;
    typedef struct { imu_rate_t gyr[3]; imu_q16_t acc[3]; imu_q16_t mag[3]; unsigned clipped; } imu_sample_t;
    typedef struct { imu_q30_t quat[4]; imu_angle_t euler[3]; imu_rate_t gyro_bias[3]; } imu_output_t;
    typedef struct {
        const char *name; size_t offset; int frac_bits; const char *unit; imu_real_t min; imu_real_t max;
    } imu_setting_desc_t;
    typedef struct { ...; } imu_eecf_settings_t;
    typedef struct { ...; } imu_kf1d_settings_t;
    typedef struct { ...; } imu_eskf_settings_t;
    typedef struct { ...; } imu_navfilter_settings_t;
    typedef struct { ...; } imu_eskf_t;
    typedef struct { imu_filter_id_t id; ...; } imu_filter_t;

    extern const imu_sensor_settings_t imu_sensor_default_settings;
    extern const imu_calibration_t imu_calibration_identity;
    extern const imu_eecf_settings_t imu_eecf_default_settings;
    extern const imu_setting_desc_t imu_eecf_setting_descs[];
    extern const int imu_eecf_setting_count;
    extern const imu_kf1d_settings_t imu_kf1d_default_settings;
    extern const imu_setting_desc_t imu_kf1d_setting_descs[];
    extern const int imu_kf1d_setting_count;
    extern const imu_eskf_settings_t imu_eskf_default_settings;
    extern const imu_setting_desc_t imu_eskf_setting_descs[];
    extern const int imu_eskf_setting_count;
    extern const imu_navfilter_settings_t imu_navfilter_default_settings;
    extern const imu_setting_desc_t imu_navfilter_setting_descs[];
    extern const int imu_navfilter_setting_count;

    imu_status_t imu_filter_init(imu_filter_t *f, int id);
    imu_status_t imu_filter_set_settings(imu_filter_t *f, const void *settings);
    void imu_filter_set_sensor(imu_filter_t *f, const imu_sensor_settings_t *sensor);
    imu_status_t imu_filter_set_calibration(imu_filter_t *f, const imu_calibration_t *cal);
    void imu_sample_from_raw(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw, imu_sample_t *out,
                             uint32_t *sat);
    void imu_sample_from_raw_calibrated(const imu_sensor_settings_t *settings, const imu_calibration_t *cal,
                                        const imu_raw_sample_t *raw, imu_sample_t *out, uint32_t *sat);
    void imu_filter_update_raw(imu_filter_t *f, const imu_raw_sample_t *raw);
    void imu_filter_get(const imu_filter_t *f, imu_output_t *out);
    uint32_t imu_filter_saturations(const imu_filter_t *f);
    const uint8_t *imu_filter_state(const imu_filter_t *f);
    size_t imu_filter_state_size(const imu_filter_t *f);
    imu_status_t imu_filter_restore(imu_filter_t *f, const uint8_t *state, size_t size);
    void imu_filter_run(imu_filter_t *f, const int16_t *gyr, const int16_t *acc, const int16_t *mag, size_t n,
                        imu_q30_t *quat, imu_angle_t *euler, imu_rate_t *gyro_bias);

    int imu_eskf_state_count(const imu_eskf_t *f);
    void imu_eskf_get_weights(const imu_eskf_t *f, imu_q30_t *gravity, imu_q30_t *heading);
    void imu_eskf_covariance(const imu_eskf_t *f, int i, int j, imu_real_t *mant, int32_t *exp);
    void imu_eskf_get_acc_bias(const imu_eskf_t *f, imu_real_t acc_bias[3]);
    const imu_eskf_t *imu_filter_eskf(const imu_filter_t *f);

    imu_angle_t imu_atan2(imu_real_t y, imu_real_t x);
    imu_real_t imu_hypot(imu_real_t a, imu_real_t b);
    imu_real_t imu_vec3_norm(const imu_real_t v[3]);
    int imu_vec3_normalize(const imu_real_t v[3], imu_q30_t unit[3], imu_real_t *norm);
    void imu_sincos(imu_angle_t angle, imu_q30_t *s, imu_q30_t *c);
    void imu_quat_integrate(imu_q30_t q[4], const imu_q30_t theta[3]);
    void imu_quat_from_rotation(imu_q30_t q[4], const imu_q30_t theta[3]);
    void imu_quat_turn(imu_q30_t q[4], const imu_q30_t theta[3]);
    void imu_quat_matrix_row(const imu_q30_t q[4], int row, imu_q30_t out[3]);
    void imu_quat_y_axis(const imu_q30_t q[4], imu_q30_t out[3]);
    typedef struct { imu_q30_t row[3][3]; } imu_rotation_t;
    void imu_quat_rotation(const imu_q30_t q[4], imu_rotation_t *r);
    void imu_rotation_apply(const imu_rotation_t *r, const imu_real_t v[3], imu_real_t out[3]);
    imu_angle_t imu_heading_from_mag(const imu_real_t mag[3], imu_angle_t roll, imu_angle_t pitch);
    imu_angle_t imu_heading_from_mag_tilt(const imu_real_t mag[3], imu_q30_t sr, imu_q30_t cr, imu_q30_t sp,
                                          imu_q30_t cp);
    imu_q30_t imu_deviation_weight(imu_real_t deviation, imu_real_t tolerance, uint32_t *sat);
    typedef struct { int32_t trusted; int32_t held; } imu_field_trust_t;
    void imu_field_trust_reset(imu_field_trust_t *t);
    void imu_field_trust_confirm(imu_field_trust_t *t, int32_t steps, int32_t limit);
    void imu_field_trust_drop(imu_field_trust_t *t);
    int imu_field_trust_hold(imu_field_trust_t *t, int32_t steps, int32_t minimum);
    void imu_quat_to_euler(const imu_q30_t q[4], imu_angle_t euler[3]);
    typedef struct { imu_q30_t up[3]; imu_q30_t y[3]; imu_q30_t cos_pitch; } imu_euler_axes_t;
    void imu_quat_to_euler_axes(const imu_q30_t q[4], imu_angle_t euler[3], imu_euler_axes_t *axes);
    void imu_euler_to_quat(const imu_angle_t euler[3], imu_q30_t q[4]);

    typedef enum { IMU_PROTO_OK = 0, IMU_PROTO_ERR_LENGTH = -1, IMU_PROTO_ERR_COBS = -2,
                   IMU_PROTO_ERR_SPACE = -3 } imu_proto_result_t;
    #define IMU_PROTO_HEADER_SIZE ...
    #define IMU_PROTO_CRC_SIZE ...
    #define IMU_PROTO_MIN_FRAME ...
    #define IMU_PROTO_MAX_FRAME ...
    #define IMU_PROTO_MAX_WIRE ...
    typedef struct { uint8_t msg_id; uint16_t seq; const uint8_t *payload; size_t payload_len; } imu_proto_frame_t;
    typedef struct { uint32_t bytes; uint32_t frames; uint32_t crc_errors; uint32_t resyncs; uint32_t oversize;
                     ...; } imu_proto_decoder_t;
    uint32_t imu_proto_crc32(uint32_t crc, const uint8_t *data, size_t len);
    size_t imu_proto_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);
    imu_proto_result_t imu_proto_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap,
                                             size_t *out_len);
    size_t imu_proto_frame_encode(uint8_t msg_id, uint16_t seq, const uint8_t *payload, size_t payload_len,
                                  uint8_t *wire, size_t wire_cap);
    void imu_proto_decoder_init(imu_proto_decoder_t *d, uint8_t *buf, size_t cap);
    int imu_proto_decoder_push(imu_proto_decoder_t *d, uint8_t byte, imu_proto_frame_t *frame);

    #define IMU_NAVKF_STATES ...
    typedef enum { IMU_NAVKF_GNSS = 0, IMU_NAVKF_MARKER = 1 } imu_navkf_source_t;
    typedef struct {
        int source; imu_angle_t lat; imu_angle_t lon; imu_real_t height; imu_real_t vel[3]; int has_vel;
        imu_real_t h_acc; imu_real_t v_acc; imu_real_t s_acc; imu_q30_t age;
    } imu_navkf_fix_t;
    typedef struct { imu_q30_t q[4]; imu_real_t vel[3]; uint32_t saturations; ...; } imu_nav_t;
    typedef struct {
        imu_nav_t nav; uint32_t rejected; uint32_t resets; uint32_t fades; uint32_t zero_velocity; ...;
    } imu_navkf_t;
    imu_status_t imu_navkf_start(imu_navkf_t *f, imu_real_t rate, const imu_q16_t acc[3], const imu_real_t mag[3],
                                 const imu_navkf_fix_t *fix, const imu_real_t lever_arm[3]);
    typedef struct { ...; } imu_navkf_tuning_t;
    imu_status_t imu_navkf_tune(imu_navkf_t *f, const imu_navkf_tuning_t *tuning);
    void imu_navkf_position(const imu_navkf_t *f, imu_angle_t *lat, imu_angle_t *lon, imu_real_t *height);
    void imu_navkf_variance(const imu_navkf_t *f, int i, imu_real_t *mant, int32_t *exp);
    void navkf_run(imu_navkf_t *f, size_t n, const imu_rate_t *gyr, const imu_q16_t *acc, const imu_real_t *mag,
                   const int32_t *baro_after, size_t baro_count, const imu_real_t *baro_pa,
                   const int32_t *fix_after, size_t fix_count, const imu_navkf_fix_t *fixes, uint8_t *accepted,
                   imu_angle_t *lat_lon, imu_real_t *height, imu_real_t *vel, imu_q30_t *quat, imu_real_t *var_mant,
                   int32_t *var_exp);
"""
# The message structs and functions of imu_proto.h, generated from shared/protocol.toml.
_DECLARATIONS += _SCHEMA["CFFI_DECLARATIONS"]
_DECLARATIONS += """
    void navfilter_run(imu_filter_t *f, size_t n, const int16_t *gyr, const int16_t *acc, const int16_t *mag,
                       const int32_t *baro_after, size_t baro_count, const int32_t *baro_pa,
                       const int32_t *gnss_after, size_t gnss_count, const imu_proto_gnss_t *gnss,
                       const int32_t *marker_after, size_t marker_count, const imu_proto_marker_t *markers,
                       imu_output_t *out, uint32_t *saturations, imu_real_t *position, void *nav_states,
                       void *estimates);
    void estimates_run(imu_filter_t *f, size_t n, const int16_t *gyr, const int16_t *acc, const int16_t *mag,
                       void *estimates);
"""


# The nav filter over a whole recording in one call (the per-sample loop in C): after the
# IMU sample k, the barometer samples and then the fixes whose *_after is k (ascending);
# the outputs of every sample.
_NAVKF_RUN = """
static void navkf_run(imu_navkf_t *f, size_t n, const imu_rate_t *gyr, const imu_q16_t *acc, const imu_real_t *mag,
                      const int32_t *baro_after, size_t baro_count, const imu_real_t *baro_pa,
                      const int32_t *fix_after, size_t fix_count, const imu_navkf_fix_t *fixes, uint8_t *accepted,
                      imu_angle_t *lat_lon, imu_real_t *height, imu_real_t *vel, imu_q30_t *quat, imu_real_t *var_mant,
                      int32_t *var_exp)
{
    size_t k, j = 0, b = 0;
    int i;
    for (k = 0; k < n; ++k) {
        imu_navkf_step(f, gyr + 3 * k, acc + 3 * k, mag + 3 * k);
        for (; b < baro_count && baro_after[b] == (int32_t)k; ++b) {
            imu_navkf_baro(f, baro_pa[b]);
        }
        for (; j < fix_count && fix_after[j] == (int32_t)k; ++j) {
            accepted[j] = (uint8_t)imu_navkf_fix(f, &fixes[j]);
        }
        imu_navkf_position(f, &lat_lon[2 * k], &lat_lon[2 * k + 1], &height[k]);
        for (i = 0; i < 3; ++i) {
            vel[3 * k + i] = f->nav.vel[i];
        }
        for (i = 0; i < 4; ++i) {
            quat[4 * k + i] = f->nav.q[i];
        }
        for (i = 0; i < IMU_NAVKF_STATES; ++i) {
            imu_navkf_variance(f, i, &var_mant[IMU_NAVKF_STATES * k + i], &var_exp[IMU_NAVKF_STATES * k + i]);
        }
    }
}
"""


# The nav filter as the board runs it (firmware/app/app.c) over a recorded run, in one
# call: sample k's counts, then its barometer reading, its receiver's fix and a marker
# (those whose *_after is k, ascending), then the outputs: the ESTIMATE's attitude and
# saturations, the position (lat, lon, height, velocity: n x 6) and, in the fixed build,
# the NAV_STATE (NULL: not wanted).
_NAVFILTER_RUN = """
static void navfilter_run(imu_filter_t *f, size_t n, const int16_t *gyr, const int16_t *acc, const int16_t *mag,
                          const int32_t *baro_after, size_t baro_count, const int32_t *baro_pa,
                          const int32_t *gnss_after, size_t gnss_count, const imu_proto_gnss_t *gnss,
                          const int32_t *marker_after, size_t marker_count, const imu_proto_marker_t *markers,
                          imu_output_t *out, uint32_t *saturations, imu_real_t *position, void *nav_states,
                          void *estimates)
{
    imu_navfilter_t *nav = imu_filter_nav(f);
    size_t k, b = 0, g = 0, m = 0;
    int i;
    for (k = 0; k < n; ++k) {
        const imu_navkf_t *state;
        imu_filter_update_counts(f, gyr + 3 * k, acc + 3 * k, mag + 3 * k);
        for (; b < baro_count && baro_after[b] == (int32_t)k; ++b) {
            imu_navfilter_baro(nav, baro_pa[b]);
        }
        for (; g < gnss_count && gnss_after[g] == (int32_t)k; ++g) {
            imu_navfilter_gnss_t fix;
            imu_wire_gnss_fix(&gnss[g], &fix);
            (void)imu_navfilter_gnss(nav, &fix);
        }
        for (; m < marker_count && marker_after[m] == (int32_t)k; ++m) {
            const imu_proto_marker_t *a = &markers[m];
            (void)imu_navfilter_marker(nav, a->lat_1e7deg, a->lon_1e7deg, a->height_mm, a->h_acc_mm, a->v_acc_mm);
        }
        imu_filter_get(f, &out[k]);
        saturations[k] = imu_filter_saturations(f);
        state = imu_navfilter_state(nav);
        for (i = 0; i < 6; ++i) {
            position[6 * k + i] = 0;
        }
        if (state != 0) {
            imu_navkf_position(state, &position[6 * k], &position[6 * k + 1], &position[6 * k + 2]);
            for (i = 0; i < 3; ++i) {
                position[6 * k + 3 + i] = state->nav.vel[i];
            }
        }
#ifdef IMU_FIXED
        if (nav_states != 0) {
            imu_wire_nav_state(nav, (uint32_t)k, (imu_proto_nav_state_t *)nav_states + k);
        }
        if (estimates != 0) {
            imu_wire_estimate(f, &out[k], (uint32_t)k, (imu_proto_estimate_t *)estimates + k);
        }
#else
        (void)nav_states;
        (void)estimates;
#endif
    }
}
"""

# The board's ESTIMATE after each of n samples, as imu_wire_estimate assembles it, numbered
# 0..n-1: the fixed build's (the message carries its integers; the float build leaves it).
_ESTIMATES_RUN = """
static void estimates_run(imu_filter_t *f, size_t n, const int16_t *gyr, const int16_t *acc, const int16_t *mag,
                          void *estimates)
{
#ifdef IMU_FIXED
    size_t k;
    for (k = 0; k < n; ++k) {
        imu_output_t out;
        imu_filter_update_counts(f, gyr + 3 * k, acc + 3 * k, mag + 3 * k);
        imu_filter_get(f, &out);
        imu_wire_estimate(f, &out, (uint32_t)k, (imu_proto_estimate_t *)estimates + k);
    }
#else
    (void)f;
    (void)n;
    (void)gyr;
    (void)acc;
    (void)mag;
    (void)estimates;
#endif
}
"""

# The ESTIMATE as the board assembles it (imu_wire.h): the fixed build's only, whose integers it carries.
_FIXED_DECLARATIONS = """
    void imu_wire_estimate(const imu_filter_t *f, const imu_output_t *out, uint32_t index, imu_proto_estimate_t *msg);
"""


def _make(arithmetic: str) -> FFI:
    ffi = FFI()
    ffi.cdef(_TYPEDEFS[arithmetic] + _DECLARATIONS + (_FIXED_DECLARATIONS if arithmetic == "fixed" else ""))
    rel = Path(__file__).resolve().parents[3]
    ffi.set_source(
        f"imulink.core._{arithmetic}",
        '#include "imu_filter.h"\n#include "imu_math.h"\n#include "imu_proto.h"\n#include "imu_navkf.h"\n'
        '#include "imu_wire.h"\n'
        + _SCHEMA["CFFI_FILTER_ID_CHECK"] + _NAVKF_RUN + _NAVFILTER_RUN + _ESTIMATES_RUN,
        sources=[str((CORE_DIR / s).relative_to(rel)) for s in CORE_SOURCES],
        include_dirs=[str(CORE_DIR.relative_to(rel))],
        define_macros=[("IMU_FIXED" if arithmetic == "fixed" else "IMU_FLOAT", "1")],
        extra_compile_args=["-std=c99", "-O2", "-Wall", "-Wextra"],
        libraries=["m"] if arithmetic == "float" else [],
    )
    return ffi


ffi_fixed = _make("fixed")
ffi_float = _make("float")

if __name__ == "__main__":
    ffi_fixed.compile(verbose=True)
    ffi_float.compile(verbose=True)
