/**
 * @file app.c
 * @brief The board application (see app.h): protocol commands, live samples, injection.
 */
#include "app.h"

#include "board.h"
#include "imu_wire.h"
#include "text.h"

/** Bytes of one live sample on the wire: SAMPLE + ESTIMATE frames at their largest. */
#define SAMPLE_WIRE_BYTES                                                                         \
    (2u * (IMU_PROTO_COBS_MAX(IMU_PROTO_HEADER_SIZE + IMU_PROTO_ESTIMATE_SIZE + IMU_PROTO_CRC_SIZE) + 1u))

/** Bytes of a frame with a payload of `size` on the wire, at its largest. */
#define WIRE_BYTES(size) (IMU_PROTO_COBS_MAX(IMU_PROTO_HEADER_SIZE + (size) + IMU_PROTO_CRC_SIZE) + 1u)
#define BARO_WIRE_BYTES WIRE_BYTES(IMU_PROTO_BARO_SIZE)
#define GNSS_WIRE_BYTES WIRE_BYTES(IMU_PROTO_GNSS_SIZE)
/** What the NAV filter adds to a sample: its NAV_STATE, and a MARKER when a POSITION_FIX waits. */
#define NAV_WIRE_BYTES (WIRE_BYTES(IMU_PROTO_NAV_STATE_SIZE) + WIRE_BYTES(IMU_PROTO_MARKER_SIZE))

#define ANSWER_WIRE_BYTES WIRE_BYTES(IMU_PROTO_NACK_SIZE)
#define CHECKPOINT_WIRE_BYTES WIRE_BYTES(IMU_PROTO_CHECKPOINT_SIZE)
/** State bytes in one CHECKPOINT frame: its data field's capacity. */
#define CHECKPOINT_PART_BYTES (IMU_PROTO_CHECKPOINT_SIZE - IMU_PROTO_CHECKPOINT_MIN_SIZE)

/** Sensor failures are reported at most once per this many microseconds, and the sensors set up
 *  again at most as often, so a dead sensor costs little and does not flood the link. */
#define SENSOR_RETRY_US 1000000u

/** Weight of the newest sample in the smoothed CPU load: 1/64 (a time constant of 64 samples). */
#define LOAD_SMOOTHING_SHIFT 6

/* --------------------------------------------------------------------------- the filters */

/** The stored settings of filter kind `kind`. */
static imu_filter_settings_t *settings_of(app_t *app, const imu_filter_kind_t *kind)
{
    return &app->settings[kind - imu_filter_kinds];
}

/** The settings field (an imu_real_t: int32 in Qn) at `index` of a kind's settings struct. */
static imu_real_t *setting_field(imu_filter_settings_t *settings, const imu_filter_kind_t *kind, int index)
{
    return (imu_real_t *)((uint8_t *)settings + kind->descs[index].offset);
}

static void copy_bytes(void *to, const void *from, size_t n)
{
    uint8_t *t = (uint8_t *)to;
    const uint8_t *f = (const uint8_t *)from;
    while (n--) {
        *t++ = *f++;
    }
}

/** Make filter `id` active with its stored settings, from sample index 0. The stored settings
 *  were accepted by the filter before, so this cannot fail. */
static void restart_filter(app_t *app, int id)
{
    const imu_filter_kind_t *kind = imu_filter_kind(id);
    imu_filter_init(&app->filter, id);
    imu_filter_set_sensor(&app->filter, &app->config.sensor);
    (void)imu_filter_set_calibration(&app->filter, &app->calibration); /* checked when it was set */
    (void)imu_filter_set_settings(&app->filter, settings_of(app, kind));
    app->index = 0;
    app->marker_waiting = 0;
}

/** The active filter's sample rate, mHz (the live tick); its setting is in Hz, Q16. */
static uint32_t sample_rate_mhz(app_t *app)
{
    const imu_filter_kind_t *kind = imu_filter_kind(app->filter.id);
    const imu_real_t rate = *setting_field(settings_of(app, kind), kind, 0);
    return (uint32_t)(((uint64_t)(uint32_t)rate * 1000u + 32768u) >> 16);
}

/* --------------------------------------------------------------------------- output */

/** Bytes the link must keep free for the next live sample's frames: what is sent besides them
 *  (RESENT frames, checkpoints) goes only where it leaves that much room. */
static size_t live_reserve(app_t *app)
{
    if (!app->streaming) {
        return ANSWER_WIRE_BYTES;
    }
    return SAMPLE_WIRE_BYTES + BARO_WIRE_BYTES + GNSS_WIRE_BYTES +
           (imu_filter_nav(&app->filter) != 0 ? NAV_WIRE_BYTES : 0u) + ANSWER_WIRE_BYTES;
}

static void send_wire(app_t *app, size_t len)
{
    board_link_write(app->wire, len);
    app->tx_seq = (uint16_t)(app->tx_seq + 1u);
    frame_ring_age(&app->sent, app->tx_seq);
}

/** Send a filter input frame (SAMPLE, BARO, GNSS, MARKER) and keep it for RESEND. */
static void send_kept(app_t *app, uint8_t msg_id, const uint8_t *payload, size_t len)
{
    frame_ring_keep(&app->sent, app->tx_seq, msg_id, payload, len);
    send_wire(app, imu_proto_frame_encode(msg_id, app->tx_seq, payload, len, app->wire, sizeof app->wire));
}

/** A barometer measurement read with sample app->index. */
static void send_baro(app_t *app, uint32_t timestamp_us, const board_baro_t *reading)
{
    imu_proto_baro_t b;
    uint8_t payload[IMU_PROTO_BARO_SIZE];
    b.timestamp_us = timestamp_us;
    b.index = app->index;
    b.d1 = reading->d1;
    b.d2 = reading->d2;
    b.pressure_pa = reading->pressure_pa;
    b.temperature_cdeg = reading->temperature_cdeg;
    send_kept(app, IMU_PROTO_MSG_BARO, payload, imu_proto_baro_pack(&b, payload));
}

static void send_log(app_t *app, uint8_t level, const char *text)
{
    imu_proto_log_t log;
    size_t n = 0;
    log.level = level;
    while (text[n] != '\0' && n < sizeof log.text) {
        log.text[n] = text[n];
        ++n;
    }
    log.text_len = n;
    send_wire(app, imu_proto_log_encode(&log, app->tx_seq, app->wire, sizeof app->wire));
}

void app_send_hello(app_t *app)
{
    imu_proto_hello_t hello;
    size_t i;
    const char *name = app->config.board_name;
    hello.firmware_major = APP_VERSION_MAJOR;
    hello.firmware_minor = APP_VERSION_MINOR;
    hello.firmware_patch = APP_VERSION_PATCH;
    hello.protocol_version = IMU_PROTO_VERSION;
    hello.schema_hash = IMU_PROTO_SCHEMA_HASH;
    for (i = 0; i < sizeof hello.board; ++i) {
        hello.board[i] = *name != '\0' ? *name++ : '\0';
    }
    hello.filters = 0;
    for (i = 0; i < IMU_FILTER_KIND_COUNT; ++i) {
        hello.filters = (uint8_t)(hello.filters | (1u << imu_filter_kinds[i].id));
    }
    hello.gyro_scale = app->config.sensor.gyro_scale;
    hello.acc_scale = app->config.sensor.acc_scale;
    hello.mag_scale = app->config.sensor.mag_scale;
    send_wire(app, imu_proto_hello_encode(&hello, app->tx_seq, app->wire, sizeof app->wire));
}

static void send_status(app_t *app)
{
    imu_proto_status_t s;
    s.uptime_ms = (uint32_t)(board_time_us() / 1000u);
    s.active_filter = (uint8_t)app->filter.id;
    s.sample_rate_mhz = sample_rate_mhz(app);
    s.dropped_samples = app->dropped_samples;
    s.cpu_load_permille = (uint16_t)((app->load_permille_q8 + 128u) >> 8);
    s.filter_saturations = imu_filter_saturations(&app->filter);
    s.sensor_saturations = app->sensor_saturations;
    s.streaming = (uint8_t)app->streaming;
    s.injection_mode = (uint8_t)app->injection;
    s.filter_cycles = app->filter_cycles;
    s.cycle_hz = board_cycle_hz();
    s.sensor_errors = app->sensor_errors;
    send_wire(app, imu_proto_status_encode(&s, app->tx_seq, app->wire, sizeof app->wire));
}

static void send_answer(app_t *app, const imu_proto_command_t *command, uint8_t reason)
{
    if (reason == IMU_PROTO_REASON_OK) {
        imu_proto_ack_t ack;
        ack.command_seq = command->command_seq;
        ack.command = command->command;
        ack.reason = reason;
        send_wire(app, imu_proto_ack_encode(&ack, app->tx_seq, app->wire, sizeof app->wire));
    } else {
        imu_proto_nack_t nack;
        nack.command_seq = command->command_seq;
        nack.command = command->command;
        nack.reason = reason;
        send_wire(app, imu_proto_nack_encode(&nack, app->tx_seq, app->wire, sizeof app->wire));
    }
}

/** A waiting POSITION_FIX given to the NAV filter after the sample `index` (read at
 *  `timestamp_us`), reported in a MARKER frame when `send`. */
static void apply_marker(app_t *app, imu_navfilter_t *nav, uint32_t timestamp_us, uint32_t index, int send)
{
    const imu_proto_cmd_position_fix_t *fix = &app->marker;
    imu_proto_marker_t m;
    m.timestamp_us = timestamp_us;
    m.index = index;
    m.lat_1e7deg = fix->lat_1e7deg;
    m.lon_1e7deg = fix->lon_1e7deg;
    m.height_mm = fix->height_mm;
    m.h_acc_mm = fix->h_acc_mm;
    m.v_acc_mm = fix->v_acc_mm;
    m.used = (uint8_t)imu_navfilter_marker(nav, fix->lat_1e7deg, fix->lon_1e7deg, fix->height_mm, fix->h_acc_mm,
                                           fix->v_acc_mm);
    app->marker_waiting = 0;
    if (send) {
        uint8_t payload[IMU_PROTO_MARKER_SIZE];
        send_kept(app, IMU_PROTO_MSG_MARKER, payload, imu_proto_marker_pack(&m, payload));
    }
}

/** Update the active filter with one sample (read at `timestamp_us`, index `index`); the
 *  NAV filter then takes the barometer's reading and the receiver's fix that came with it
 *  (NULL: none) and a waiting POSITION_FIX (its MARKER frame sent when `send`). */
static void update_filter(app_t *app, const imu_raw_sample_t *raw, uint32_t timestamp_us, uint32_t index,
                          const board_baro_t *baro, const imu_proto_gnss_t *gnss, int send)
{
    imu_navfilter_t *nav = imu_filter_nav(&app->filter);
    imu_filter_update_raw(&app->filter, raw);
    if (nav == 0) {
        return;
    }
    if (baro != 0) {
        imu_navfilter_baro(nav, baro->pressure_pa);
    }
    if (gnss != 0) {
        imu_navfilter_gnss_t fix;
        imu_wire_gnss_fix(gnss, &fix);
        (void)imu_navfilter_gnss(nav, &fix);
    }
    if (app->marker_waiting) {
        apply_marker(app, nav, timestamp_us, index, send);
    }
}

/** Send the active filter's state after sample `index` in CHECKPOINT frames. */
static void send_checkpoint(app_t *app, uint32_t index)
{
    const uint8_t *state = imu_filter_state(&app->filter);
    const size_t size = imu_filter_state_size(&app->filter);
    imu_proto_checkpoint_t c;
    size_t offset, i;
    c.index = index;
    c.filter_id = (uint8_t)app->filter.id;
    c.parts = (uint8_t)((size + CHECKPOINT_PART_BYTES - 1u) / CHECKPOINT_PART_BYTES);
    c.state_size = (uint16_t)size;
    for (offset = 0, c.part = 0; offset < size; offset += CHECKPOINT_PART_BYTES, ++c.part) {
        c.data_len = size - offset < CHECKPOINT_PART_BYTES ? size - offset : CHECKPOINT_PART_BYTES;
        for (i = 0; i < c.data_len; ++i) {
            c.data[i] = state[offset + i];
        }
        send_wire(app, imu_proto_checkpoint_encode(&c, app->tx_seq, app->wire, sizeof app->wire));
    }
}

/** The periodic checkpoint after live sample app->index, when it is due and the link has room for it. */
static void checkpoint_if_due(app_t *app)
{
    const size_t parts = (imu_filter_state_size(&app->filter) + CHECKPOINT_PART_BYTES - 1u) / CHECKPOINT_PART_BYTES;
    if (app->checkpoint_period == 0 || (app->index + 1u) % app->checkpoint_period != 0) {
        return;
    }
    if (board_link_space() >= parts * CHECKPOINT_WIRE_BYTES + live_reserve(app)) {
        send_checkpoint(app, app->index);
    }
}

/** Run the active filter on one sample and send its ESTIMATE (and the NAV filter's NAV_STATE) under `index`. */
static void run_filter(app_t *app, const imu_raw_sample_t *raw, uint32_t timestamp_us, uint32_t index,
                       const board_baro_t *baro, const imu_proto_gnss_t *gnss)
{
    imu_proto_estimate_t e;
    imu_output_t out;
    const imu_navfilter_t *nav;
    const uint32_t started = board_cycles();
    update_filter(app, raw, timestamp_us, index, baro, gnss, 1);
    imu_filter_get(&app->filter, &out);
    app->filter_cycles = board_cycles() - started;

    imu_wire_estimate(&app->filter, &out, index, &e);
    send_wire(app, imu_proto_estimate_encode(&e, app->tx_seq, app->wire, sizeof app->wire));
    nav = imu_filter_nav(&app->filter);
    if (nav != 0) {
        imu_proto_nav_state_t state;
        imu_wire_nav_state(nav, index, &state);
        send_wire(app, imu_proto_nav_state_encode(&state, app->tx_seq, app->wire, sizeof app->wire));
    }
}

/* --------------------------------------------------------------------------- live samples */

static void start_stream(app_t *app)
{
    app->streaming = 1;
    app->samples_until_status = (sample_rate_mhz(app) + 500u) / 1000u;
    board_sample_clock_start(sample_rate_mhz(app));
}

static void stop_stream(app_t *app)
{
    app->streaming = 0;
    board_sample_clock_stop();
}

/** Set the sensors up; say how it went (a failed retry stays quiet: the failed reads are reported). */
static void set_up_sensors(app_t *app, int report_failure)
{
    const char *message = "";
    app->sensors_ok = board_sensors_init(&message) == BOARD_SENSORS_OK;
    app->sensor_retry_us = board_time_us() + SENSOR_RETRY_US;
    if (app->sensors_ok || report_failure) {
        send_log(app, app->sensors_ok ? IMU_PROTO_LOG_LEVEL_INFO : IMU_PROTO_LOG_LEVEL_ERROR, message);
    }
}

/** A read failed: count it, say why now and then, and set the sensors up again now and then. */
static void sensor_failed(app_t *app, const char *why)
{
    const uint64_t now = board_time_us();
    ++app->sensor_errors;
    ++app->dropped_samples;
    ++app->failures_since_log;
    if (app->sensors_ok || now >= app->error_log_us) {
        char line[IMU_PROTO_LOG_SIZE];
        text_t t;
        text_start(&t, line, sizeof line);
        text_add(&t, why);
        if (!app->sensors_ok) {
            text_add(&t, " (");
            text_add_uint(&t, app->failures_since_log);
            text_add(&t, " failed reads in the last second)");
        }
        send_log(app, IMU_PROTO_LOG_LEVEL_ERROR, text_end(&t));
        app->failures_since_log = 0;
        app->error_log_us = now + SENSOR_RETRY_US;
    }
    if (app->sensors_ok) {
        app->sensors_ok = 0;
        app->sensor_retry_us = now + SENSOR_RETRY_US;
    } else if (now >= app->sensor_retry_us) {
        set_up_sensors(app, 0);
    }
}

static void update_load(app_t *app, uint32_t work_cycles)
{
    /* sample_rate_mhz() is at least 10 000: every filter refuses a slower rate */
    const uint64_t period_cycles = (uint64_t)board_cycle_hz() * 1000u / sample_rate_mhz(app);
    uint64_t permille_q8;
    if (period_cycles == 0) {
        return; /* no cycle counter */
    }
    permille_q8 = ((uint64_t)work_cycles * 1000u * 256u) / period_cycles;
    if (permille_q8 > 1000u * 256u) {
        permille_q8 = 1000u * 256u;
    }
    /* load += (newest - load) / 64, in Q8 per mille (at most 256 000: the int32 difference fits) */
    app->load_permille_q8 = (uint32_t)((int32_t)app->load_permille_q8 +
                                       (((int32_t)permille_q8 - (int32_t)app->load_permille_q8) >>
                                        LOAD_SMOOTHING_SHIFT));
}

static void live_sample(app_t *app)
{
    imu_raw_sample_t raw;
    imu_proto_sample_t s;
    int16_t temperature = 0;
    const char *message = "";
    const uint32_t started = board_cycles();
    const uint64_t read_at = board_time_us();
    const board_sensors_result_t result = board_sensors_read(&raw, &temperature, &message);
    board_baro_t baro;
    imu_proto_gnss_t gnss;
    uint8_t payload[IMU_PROTO_GNSS_SIZE]; /* the SAMPLE's payload, then the GNSS's (the larger) */
    int have_baro, have_gnss;
    int i;

    if (result == BOARD_SENSORS_ENDED) {
        char line[IMU_PROTO_LOG_SIZE];
        text_t t;
        text_start(&t, line, sizeof line);
        text_add(&t, message);
        text_add(&t, ": streaming stopped");
        stop_stream(app);
        send_log(app, IMU_PROTO_LOG_LEVEL_INFO, text_end(&t));
        send_status(app);
        return;
    }
    if (result != BOARD_SENSORS_OK) {
        sensor_failed(app, message);
        return;
    }
    if (!app->sensors_ok) {
        char line[IMU_PROTO_LOG_SIZE];
        text_t t;
        text_start(&t, line, sizeof line);
        text_add(&t, "sensors answer again after ");
        text_add_uint(&t, app->failures_since_log);
        text_add(&t, " more failed reads");
        send_log(app, IMU_PROTO_LOG_LEVEL_INFO, text_end(&t));
        app->sensors_ok = 1;
        app->failures_since_log = 0;
    }
    app->sensor_saturations += imu_sample_clipped(&app->config.sensor, &raw) != 0 ? 1u : 0u;
    have_baro = board_baro_read(read_at, &baro);
    have_gnss = board_gnss_read(read_at, &gnss);

    if (board_link_space() < SAMPLE_WIRE_BYTES + (have_baro ? BARO_WIRE_BYTES : 0u) +
                                 (have_gnss ? GNSS_WIRE_BYTES : 0u) +
                                 (imu_filter_nav(&app->filter) != 0 ? NAV_WIRE_BYTES : 0u)) {
        /* The host does not keep up: the filter still runs (its state must follow the sensor),
         * the frames are dropped like a full UART buffer would drop them. */
        update_filter(app, &raw, (uint32_t)read_at, app->index, have_baro ? &baro : 0, have_gnss ? &gnss : 0, 0);
        ++app->dropped_samples;
    } else {
        s.timestamp_us = (uint32_t)read_at;
        s.index = app->index;
        for (i = 0; i < 3; ++i) {
            s.gyr[i] = raw.gyr[i];
            s.acc[i] = raw.acc[i];
            s.mag[i] = raw.mag[i];
        }
        s.temperature = temperature;
        send_kept(app, IMU_PROTO_MSG_SAMPLE, payload, imu_proto_sample_pack(&s, payload));
        if (have_baro) {
            send_baro(app, (uint32_t)read_at, &baro);
        }
        if (have_gnss) {
            gnss.timestamp_us = (uint32_t)read_at;
            gnss.index = app->index;
            send_kept(app, IMU_PROTO_MSG_GNSS, payload, imu_proto_gnss_pack(&gnss, payload));
        }
        run_filter(app, &raw, (uint32_t)read_at, app->index, have_baro ? &baro : 0, have_gnss ? &gnss : 0);
        checkpoint_if_due(app);
    }
    ++app->index;
    update_load(app, board_cycles() - started);
    if (--app->samples_until_status == 0) {
        app->samples_until_status = (sample_rate_mhz(app) + 500u) / 1000u;
        send_status(app);
    }
}

/* --------------------------------------------------------------------------- commands */

/** A command's outcome: the NACK reason, or OK; `after` asks the main loop for a restart. */
typedef struct {
    uint8_t reason;
    app_result_t after;
} outcome_t;

static outcome_t ok(void)
{
    outcome_t o = {IMU_PROTO_REASON_OK, APP_BUSY};
    return o;
}

static outcome_t refuse(uint8_t reason)
{
    outcome_t o;
    o.reason = reason;
    o.after = APP_BUSY;
    return o;
}

static outcome_t cmd_select_filter(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_select_filter_t a;
    (void)imu_proto_cmd_select_filter_unpack(&a, c->args, c->args_len);
    if (imu_filter_kind(a.filter_id) == 0) {
        return refuse(IMU_PROTO_REASON_UNKNOWN_FILTER);
    }
    restart_filter(app, a.filter_id);
    if (app->streaming) {
        start_stream(app); /* the new filter's rate */
    }
    return ok();
}

static outcome_t cmd_get_setting(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_get_setting_t a;
    imu_proto_setting_t s;
    const imu_filter_kind_t *kind = imu_filter_kind(app->filter.id);
    const imu_setting_desc_t *desc;
    size_t i;
    (void)imu_proto_cmd_get_setting_unpack(&a, c->args, c->args_len);
    if (a.index >= *kind->setting_count) {
        return refuse(IMU_PROTO_REASON_UNKNOWN_SETTING);
    }
    desc = &kind->descs[a.index];
    s.filter_id = (uint8_t)kind->id;
    s.index = a.index;
    s.setting_count = (uint8_t)*kind->setting_count;
    s.value = *setting_field(settings_of(app, kind), kind, a.index);
    s.frac_bits = (int8_t)desc->frac_bits;
    s.min = desc->min;
    s.max = desc->max;
    for (i = 0; i < sizeof s.name; ++i) {
        s.name[i] = i < text_length(desc->name) ? desc->name[i] : '\0';
    }
    for (i = 0; i < sizeof s.unit; ++i) {
        s.unit[i] = i < text_length(desc->unit) ? desc->unit[i] : '\0';
    }
    send_wire(app, imu_proto_setting_encode(&s, app->tx_seq, app->wire, sizeof app->wire));
    return ok();
}

static outcome_t cmd_set_setting(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_set_setting_t a;
    const imu_filter_kind_t *kind = imu_filter_kind(app->filter.id);
    imu_filter_settings_t candidate;
    (void)imu_proto_cmd_set_setting_unpack(&a, c->args, c->args_len);
    if (a.index >= *kind->setting_count) {
        return refuse(IMU_PROTO_REASON_UNKNOWN_SETTING);
    }
    candidate = *settings_of(app, kind);
    *setting_field(&candidate, kind, a.index) = a.value;
    /* The filter checks every range; a refused value leaves it unchanged. */
    if (imu_filter_set_settings(&app->filter, &candidate) != IMU_OK) {
        return refuse(IMU_PROTO_REASON_OUT_OF_RANGE);
    }
    *settings_of(app, kind) = candidate;
    restart_filter(app, kind->id);
    if (app->streaming) {
        start_stream(app); /* sample_rate may have changed */
    }
    return ok();
}

/** The calibration of sensor `sensor` (IMU_PROTO_SENSOR_*), 0 for an unknown one. */
static imu_sensor_cal_t *sensor_calibration(imu_calibration_t *cal, uint8_t sensor)
{
    switch (sensor) {
    case IMU_PROTO_SENSOR_GYROSCOPE:
        return &cal->gyr;
    case IMU_PROTO_SENSOR_ACCELEROMETER:
        return &cal->acc;
    case IMU_PROTO_SENSOR_MAGNETOMETER:
        return &cal->mag;
    default:
        return 0;
    }
}

static outcome_t cmd_set_calibration(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_set_calibration_t a;
    imu_calibration_t candidate = app->calibration;
    imu_sensor_cal_t *target;
    int j;
    (void)imu_proto_cmd_set_calibration_unpack(&a, c->args, c->args_len);
    target = sensor_calibration(&candidate, a.sensor);
    if (target == 0 || a.axis > 2) {
        return refuse(IMU_PROTO_REASON_BAD_ARGUMENT);
    }
    target->offset[a.axis] = a.offset;
    for (j = 0; j < 3; ++j) {
        target->matrix[3 * a.axis + j] = a.row[j];
    }
    if (imu_calibration_check(&candidate) != IMU_OK) {
        return refuse(IMU_PROTO_REASON_OUT_OF_RANGE);
    }
    app->calibration = candidate;
    restart_filter(app, app->filter.id);
    if (app->streaming) {
        start_stream(app);
    }
    return ok();
}

static outcome_t cmd_get_calibration(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_get_calibration_t a;
    imu_proto_calibration_t m;
    const imu_sensor_cal_t *source;
    int j;
    (void)imu_proto_cmd_get_calibration_unpack(&a, c->args, c->args_len);
    source = sensor_calibration(&app->calibration, a.sensor);
    if (source == 0 || a.axis > 2) {
        return refuse(IMU_PROTO_REASON_BAD_ARGUMENT);
    }
    m.sensor = a.sensor;
    m.axis = a.axis;
    m.offset = source->offset[a.axis];
    for (j = 0; j < 3; ++j) {
        m.row[j] = source->matrix[3 * a.axis + j];
    }
    m.offset_frac_bits = IMU_CAL_OFFSET_Q;
    m.matrix_frac_bits = IMU_CAL_MATRIX_Q;
    send_wire(app, imu_proto_calibration_encode(&m, app->tx_seq, app->wire, sizeof app->wire));
    return ok();
}

static outcome_t cmd_inject_sample(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_sample_t s;
    imu_raw_sample_t raw;
    int i;
    if (!app->injection) {
        return refuse(IMU_PROTO_REASON_NOT_IN_INJECTION_MODE);
    }
    (void)imu_proto_cmd_inject_sample_unpack(&s, c->args, c->args_len);
    for (i = 0; i < 3; ++i) {
        raw.gyr[i] = s.gyr[i];
        raw.acc[i] = s.acc[i];
        raw.mag[i] = s.mag[i];
    }
    run_filter(app, &raw, 0, s.index, 0, 0);
    ++app->index;
    return ok();
}

/** Frames one RESEND may ask for (its count). */
#define RESEND_MAX_COUNT 64u
#define RESENT_WIRE_BYTES WIRE_BYTES(IMU_PROTO_RESENT_SIZE)

static outcome_t cmd_resend(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_resend_t a;
    frame_ring_cursor_t cursor;
    const uint16_t next_seq = app->tx_seq; /* the ages are taken before the RESENT frames count up */
    uint32_t i;
    (void)imu_proto_cmd_resend_unpack(&a, c->args, c->args_len);
    if (a.count == 0 || a.count > RESEND_MAX_COUNT) {
        return refuse(IMU_PROTO_REASON_BAD_ARGUMENT);
    }
    /* what the frames sent below would age out goes now: the walk below must not lose its entry */
    frame_ring_age(&app->sent, (uint16_t)(next_seq + RESEND_MAX_COUNT + 1u));
    frame_ring_cursor_init(&app->sent, &cursor);
    for (i = 0; i < a.count; ++i) {
        imu_proto_resent_t r;
        if (board_link_space() < RESENT_WIRE_BYTES + live_reserve(app)) {
            break; /* the host asks again for the rest */
        }
        r.original_seq = (uint16_t)(a.first_seq + i);
        r.payload_len = 0;
        r.msg_id = 0;
        r.status = (uint8_t)frame_ring_find(&app->sent, &cursor, next_seq, r.original_seq, &r.msg_id, r.payload,
                                            sizeof r.payload, &r.payload_len);
        send_wire(app, imu_proto_resent_encode(&r, app->tx_seq, app->wire, sizeof app->wire));
    }
    return ok();
}

/** Latitude, longitude and height a position fix may have (imu_nav's origin): 1e-7 deg, mm. */
#define MARKER_MAX_LAT_1E7DEG 850000000
#define MARKER_MAX_LON_1E7DEG 1800000000
#define MARKER_MAX_HEIGHT_MM 10000000
/** Accuracies a position fix may have, mm (imu_navkf_fix_t). */
#define MARKER_MAX_ACC_MM 0x40000000u

static outcome_t cmd_position_fix(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_position_fix_t a;
    (void)imu_proto_cmd_position_fix_unpack(&a, c->args, c->args_len);
    if (imu_filter_nav(&app->filter) == 0) {
        return refuse(IMU_PROTO_REASON_NOT_NAV);
    }
    if (a.lat_1e7deg > MARKER_MAX_LAT_1E7DEG || a.lat_1e7deg < -MARKER_MAX_LAT_1E7DEG ||
        a.lon_1e7deg > MARKER_MAX_LON_1E7DEG || a.lon_1e7deg < -MARKER_MAX_LON_1E7DEG ||
        a.height_mm > MARKER_MAX_HEIGHT_MM || a.height_mm < -MARKER_MAX_HEIGHT_MM || a.h_acc_mm == 0 ||
        a.h_acc_mm > MARKER_MAX_ACC_MM || a.v_acc_mm == 0 || a.v_acc_mm > MARKER_MAX_ACC_MM) {
        return refuse(IMU_PROTO_REASON_OUT_OF_RANGE);
    }
    if (app->marker_waiting) {
        return refuse(IMU_PROTO_REASON_BUSY); /* one at a time: the last is not applied yet */
    }
    app->marker = a;
    app->marker_waiting = 1;
    return ok();
}

static outcome_t cmd_set_injection_mode(app_t *app, const imu_proto_command_t *c)
{
    imu_proto_cmd_set_injection_mode_t a;
    (void)imu_proto_cmd_set_injection_mode_unpack(&a, c->args, c->args_len);
    if (a.enabled > 1) {
        return refuse(IMU_PROTO_REASON_BAD_ARGUMENT);
    }
    if (app->streaming) {
        return refuse(IMU_PROTO_REASON_BUSY);
    }
    app->injection = a.enabled;
    restart_filter(app, app->filter.id);
    return ok();
}

static outcome_t run_command(app_t *app, const imu_proto_command_t *c)
{
    const int args_size = imu_proto_command_args_size(c->command);
    outcome_t o = ok();
    if (args_size < 0) {
        return refuse(IMU_PROTO_REASON_UNKNOWN_COMMAND);
    }
    if ((size_t)args_size != c->args_len) {
        return refuse(IMU_PROTO_REASON_BAD_LENGTH);
    }
    switch (c->command) {
    case IMU_PROTO_CMD_START_STREAM:
        if (app->injection) {
            return refuse(IMU_PROTO_REASON_BUSY);
        }
        if (!app->streaming) {
            start_stream(app);
        }
        return o;
    case IMU_PROTO_CMD_STOP_STREAM:
        stop_stream(app);
        return o;
    case IMU_PROTO_CMD_SELECT_FILTER:
        return cmd_select_filter(app, c);
    case IMU_PROTO_CMD_GET_SETTING:
        return cmd_get_setting(app, c);
    case IMU_PROTO_CMD_SET_SETTING:
        return cmd_set_setting(app, c);
    case IMU_PROTO_CMD_INJECT_SAMPLE:
        return cmd_inject_sample(app, c);
    case IMU_PROTO_CMD_RESET:
        o.after = APP_RESTART;
        return o;
    case IMU_PROTO_CMD_ENTER_BOOTLOADER:
        if (!board_has_bootloader()) {
            return refuse(IMU_PROTO_REASON_NOT_SUPPORTED);
        }
        o.after = APP_BOOTLOADER;
        return o;
    case IMU_PROTO_CMD_GET_VERSION:
        app_send_hello(app);
        return o;
    case IMU_PROTO_CMD_GET_STATUS:
        send_status(app);
        return o;
    case IMU_PROTO_CMD_SET_INJECTION_MODE:
        return cmd_set_injection_mode(app, c);
    case IMU_PROTO_CMD_SET_CALIBRATION:
        return cmd_set_calibration(app, c);
    case IMU_PROTO_CMD_GET_CALIBRATION:
        return cmd_get_calibration(app, c);
    case IMU_PROTO_CMD_POSITION_FIX:
        return cmd_position_fix(app, c);
    case IMU_PROTO_CMD_RESEND:
        return cmd_resend(app, c);
    case IMU_PROTO_CMD_SET_CHECKPOINT_PERIOD: {
        imu_proto_cmd_set_checkpoint_period_t a;
        (void)imu_proto_cmd_set_checkpoint_period_unpack(&a, c->args, c->args_len);
        app->checkpoint_period = a.period;
        return o;
    }
    case IMU_PROTO_CMD_GET_CHECKPOINT:
        if (app->index == 0) {
            return refuse(IMU_PROTO_REASON_BUSY); /* no sample yet: the run starts from its settings */
        }
        send_checkpoint(app, app->index - 1u);
        return o;
    default:
        return refuse(IMU_PROTO_REASON_UNKNOWN_COMMAND);
    }
}

/** Answer one received frame; frames other than COMMAND are not for the board and ignored. */
static app_result_t handle_frame(app_t *app, const imu_proto_frame_t *frame)
{
    imu_proto_command_t command;
    outcome_t o;
    if (frame->msg_id != IMU_PROTO_MSG_COMMAND ||
        imu_proto_command_unpack(&command, frame->payload, frame->payload_len) != IMU_PROTO_OK) {
        return APP_BUSY;
    }
    o = run_command(app, &command);
    send_answer(app, &command, o.reason);
    if (o.after != APP_BUSY) {
        board_link_flush(); /* the ACK must leave before the restart */
    }
    return o.after;
}

/* --------------------------------------------------------------------------- init and poll */

void app_init(app_t *app, const app_config_t *config)
{
    size_t i;
    app->config = *config;
    app->calibration = imu_calibration_identity;
    for (i = 0; i < IMU_FILTER_KIND_COUNT; ++i) {
        const imu_filter_kind_t *kind = &imu_filter_kinds[i];
        copy_bytes(settings_of(app, kind), kind->defaults, kind->settings_size);
        *setting_field(settings_of(app, kind), kind, 0) = config->sample_rate; /* field 0 of every kind */
    }
    restart_filter(app, imu_filter_kind(config->initial_filter) != 0 ? config->initial_filter : IMU_FILTER_EECF);
    app->streaming = 0;
    app->injection = 0;
    app->tx_seq = 0;
    frame_ring_init(&app->sent);
    imu_proto_decoder_init(&app->decoder, app->rx_frame, sizeof app->rx_frame);
    app->dropped_samples = 0;
    app->sensor_errors = 0;
    app->sensor_saturations = 0;
    app->filter_cycles = 0;
    app->load_permille_q8 = 0;
    app->failures_since_log = 0;
    app->error_log_us = 0;
    app->samples_until_status = 0;
    app->marker_waiting = 0;
    app->checkpoint_period = 0;
    board_sample_clock_stop();
    app_send_hello(app);
    if (board_start_up_problem() != 0) {
        send_log(app, IMU_PROTO_LOG_LEVEL_WARNING, board_start_up_problem());
    }
    set_up_sensors(app, 1);
}

app_result_t app_poll(app_t *app)
{
    uint8_t received[64];
    size_t n, i;
    uint32_t ticks;
    app_result_t result = APP_IDLE;

    n = board_link_read(received, sizeof received);
    for (i = 0; i < n; ++i) {
        imu_proto_frame_t frame;
        if (imu_proto_decoder_push(&app->decoder, received[i], &frame)) {
            const app_result_t after = handle_frame(app, &frame);
            if (after == APP_RESTART || after == APP_BOOTLOADER) {
                return after; /* what else arrived belongs to the firmware that is going away */
            }
        }
    }
    if (n == sizeof received) {
        result = APP_BUSY;
    }

    ticks = board_sample_ticks();
    if (ticks > 0 && app->streaming) {
        uint8_t level;
        const char *news;
        app->dropped_samples += ticks - 1; /* ticks that came while the last sample was still at work */
        live_sample(app);
        news = board_news(&level);
        if (news != 0) {
            send_log(app, level, news);
        }
        result = APP_BUSY;
    }
    return result;
}
