/**
 * @file harness.c
 * @brief Cortex-M4 benchmark harness of the fixed-point core (tools/bench_arm.py).
 *
 * There is no main loop: the tool runs this ELF in the unicorn emulator and calls
 * C functions one at a time (imu_filter_update_raw, imu_proto_decoder_push, ...)
 * on the globals below, whose addresses it reads from the symbol table. The
 * harness only provides that memory, the setup and read-back helpers that are not
 * measured, and bench_halt, the return address at which every call stops.
 */
#include "imu_filter.h"
#include "imu_navkf.h"
#include "imu_proto.h"

/* Filter under test and its inputs and outputs. The tool writes the settings
 * bytes the host bindings build (imulink.core) before calling bench_setup. */
imu_filter_t bench_filter;
imu_sensor_settings_t bench_sensor;
union {
    imu_eecf_settings_t eecf;
    imu_kf1d_settings_t kf1d;
    imu_eskf_settings_t eskf;
} bench_settings;
imu_raw_sample_t bench_raw;
imu_output_t bench_out;

/* What the tool reads after each sample, beside bench_out: all 32-bit words, so
 * the layout is the same on every compiler. */
struct bench_state {
    uint32_t saturations;
    int32_t eskf_initialised; /* ESKF: 0 before the first sample (which only aligns) */
    int32_t eskf_in_group;    /* ESKF: gyro increments buffered; the next update fuses when 2 */
    int32_t eecf_aligning;    /* EECF: 1 while the next update is an alignment step */
    int32_t cov_mantissa[9];  /* ESKF covariance diagonal (zeros past the state count) */
    int32_t cov_exponent[9];
    int32_t weights[2];       /* ESKF gravity and heading measurement weights, Q30 (zeros otherwise) */
};
struct bench_state bench_state;

/* The nav filter under test (tools/bench_nav.py): its start values and one sample's
 * inputs, and what the tool reads back after each sample (latitude, longitude Q29 rad,
 * height mm, velocity Q20, quaternion Q30, saturations, rejected fixes, zero-velocity updates,
 * samples in the covariance interval). */
imu_navkf_t bench_navkf;
imu_navkf_fix_t bench_navkf_fix;
imu_rate_t bench_navkf_gyr[3];
imu_q16_t bench_navkf_acc[3];
imu_real_t bench_navkf_mag[3];
int32_t bench_navkf_out[14];

/* Codec buffers. */
imu_proto_sample_t bench_sample_msg;
imu_proto_estimate_t bench_estimate_msg;
uint8_t bench_wire[IMU_PROTO_MAX_WIRE];
imu_proto_decoder_t bench_decoder;
uint8_t bench_decoder_buf[IMU_PROTO_MAX_FRAME];
imu_proto_frame_t bench_frame;

/* Sizes the tool reports (structs as this compiler lays them out for the target). */
struct bench_sizes {
    uint32_t filter;  /* imu_filter_t: what the firmware allocates for the active filter */
    uint32_t eecf;
    uint32_t kf1d;
    uint32_t eskf;
    uint32_t cov;     /* imu_cov_t, part of imu_eskf_t */
    uint32_t decoder; /* imu_proto_decoder_t, without its buffer */
    uint32_t decoder_buf;
    uint32_t frame;   /* imu_proto_frame_t, to check the tool's view of its layout */
};
const struct bench_sizes bench_sizes = {
    sizeof(imu_filter_t), sizeof(imu_eecf_t), sizeof(imu_kf1d_t), sizeof(imu_eskf_t), sizeof(imu_cov_t),
    sizeof(imu_proto_decoder_t), IMU_PROTO_MAX_FRAME, sizeof(imu_proto_frame_t),
};

/** Where every call returns: the tool stops the emulator when the PC gets here. */
void bench_halt(void)
{
    for (;;) {
    }
}

/** Filter `id` with the sensor and filter settings in bench_sensor / bench_settings,
 *  in the order of imulink.core.Filter; returns imu_filter_set_settings' status. */
int bench_setup(int id)
{
    if (imu_filter_init(&bench_filter, id) != IMU_OK) {
        return IMU_ERR_UNKNOWN;
    }
    imu_filter_set_sensor(&bench_filter, &bench_sensor);
    return imu_filter_set_settings(&bench_filter, &bench_settings);
}

/** Fill bench_state from the filter. */
void bench_read_state(void)
{
    const imu_eskf_t *eskf = imu_filter_eskf(&bench_filter);
    int i;
    bench_state.saturations = imu_filter_saturations(&bench_filter);
    bench_state.eskf_initialised = eskf != 0 ? eskf->initialised : 0;
    bench_state.eskf_in_group = eskf != 0 ? eskf->in_group : 0;
    bench_state.eecf_aligning = bench_filter.id == IMU_FILTER_EECF ? imu_eecf_aligning(&bench_filter.u.eecf) : 0;
    for (i = 0; i < 9; ++i) {
        bench_state.cov_mantissa[i] = 0;
        bench_state.cov_exponent[i] = 0;
    }
    for (i = 0; eskf != 0 && i < imu_eskf_state_count(eskf); ++i) {
        imu_eskf_covariance(eskf, i, i, &bench_state.cov_mantissa[i], &bench_state.cov_exponent[i]);
    }
    bench_state.weights[0] = bench_state.weights[1] = 0;
    if (eskf != 0) {
        imu_eskf_get_weights(eskf, &bench_state.weights[0], &bench_state.weights[1]);
    }
}

/** SAMPLE and ESTIMATE messages of one sample from bench_raw, bench_out and bench_state
 *  (as the firmware would fill them before encoding). */
void bench_fill_messages(uint32_t index, uint32_t timestamp_us, int32_t temperature, int32_t filter_id)
{
    int k;
    bench_sample_msg.timestamp_us = timestamp_us;
    bench_sample_msg.index = index;
    for (k = 0; k < 3; ++k) {
        bench_sample_msg.gyr[k] = bench_raw.gyr[k];
        bench_sample_msg.acc[k] = bench_raw.acc[k];
        bench_sample_msg.mag[k] = bench_raw.mag[k];
    }
    bench_sample_msg.temperature = (int16_t)temperature;
    bench_estimate_msg.index = index;
    bench_estimate_msg.filter_id = (uint8_t)filter_id;
    for (k = 0; k < 4; ++k) {
        bench_estimate_msg.quat[k] = bench_out.quat[k];
    }
    for (k = 0; k < 3; ++k) {
        bench_estimate_msg.gyro_bias[k] = bench_out.gyro_bias[k];
        bench_estimate_msg.euler[k] = bench_out.euler[k];
    }
    for (k = 0; k < 9; ++k) {
        bench_estimate_msg.cov_mantissa[k] = bench_state.cov_mantissa[k];
        bench_estimate_msg.cov_exponent[k] = (int8_t)bench_state.cov_exponent[k];
    }
    bench_estimate_msg.saturations = bench_state.saturations;
    bench_estimate_msg.weights[0] = bench_state.weights[0];
    bench_estimate_msg.weights[1] = bench_state.weights[1];
}

/** imu_navkf_start at bench_navkf_fix with bench_navkf_acc and _mag; returns its status. */
int bench_navkf_start(int32_t rate_q16)
{
    return imu_navkf_start(&bench_navkf, rate_q16, bench_navkf_acc, bench_navkf_mag, &bench_navkf_fix, 0);
}

/** Fill bench_navkf_out from bench_navkf. */
void bench_navkf_read(void)
{
    int k;
    imu_navkf_position(&bench_navkf, &bench_navkf_out[0], &bench_navkf_out[1], &bench_navkf_out[2]);
    for (k = 0; k < 3; ++k) {
        bench_navkf_out[3 + k] = bench_navkf.nav.vel[k];
    }
    for (k = 0; k < 4; ++k) {
        bench_navkf_out[6 + k] = bench_navkf.nav.q[k];
    }
    bench_navkf_out[10] = (int32_t)bench_navkf.nav.saturations;
    bench_navkf_out[11] = (int32_t)bench_navkf.rejected;
    bench_navkf_out[12] = (int32_t)bench_navkf.zero_velocity;
    bench_navkf_out[13] = bench_navkf.steps; /* 0: the covariance interval has just ended */
}

/** Start a decoder on bench_decoder_buf. */
void bench_decoder_init(void)
{
    imu_proto_decoder_init(&bench_decoder, bench_decoder_buf, sizeof bench_decoder_buf);
}

/* The functions and data the tool calls or reads. Kept by the linker script (the
 * link drops unreferenced sections, as the firmware's does), so this table is
 * the root of everything that ends up in the ELF. */
__attribute__((section(".bench_exports"), used)) const void *const bench_exports[] = {
    (const void *)bench_halt,
    (const void *)bench_setup,
    (const void *)bench_read_state,
    (const void *)bench_fill_messages,
    (const void *)bench_decoder_init,
    (const void *)imu_filter_update_raw,
    (const void *)imu_filter_get,
    (const void *)imu_proto_sample_encode,
    (const void *)imu_proto_estimate_encode,
    (const void *)imu_proto_decoder_push,
    (const void *)bench_navkf_start,
    (const void *)bench_navkf_read,
    (const void *)imu_navkf_step,
    (const void *)imu_navkf_fix,
    (const void *)imu_navkf_baro,
    &bench_sizes,
    &bench_filter,
    &bench_sensor,
    &bench_settings,
    &bench_raw,
    &bench_out,
    &bench_state,
    &bench_sample_msg,
    &bench_estimate_msg,
    bench_wire,
    &bench_decoder,
    &bench_frame,
    &bench_navkf,
    &bench_navkf_fix,
    bench_navkf_gyr,
    bench_navkf_acc,
    bench_navkf_mag,
    bench_navkf_out,
};
