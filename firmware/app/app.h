/**
 * @file app.h
 * @brief The board application, written once for every board: the command
 *        handling of shared/protocol.toml, the live sample loop and injection.
 *
 * A board's main() calls app_init() once per start (and again after
 * board_restart() returns, where it does), then app_poll() in a loop with
 * board_idle() between the calls:
 *
 *     app_init(&app, &config);
 *     for (;;) {
 *         app_result_t r = app_poll(&app);
 *         if (r == APP_RESTART) { board_restart(); app_init(&app, &config); }
 *         else if (r == APP_BOOTLOADER) board_enter_bootloader();
 *         else board_idle();
 *     }
 *
 * Behaviour (docs/protocol.md, docs/firmware.md):
 * - start-up: HELLO, then a LOG line saying whether the sensors were found;
 * - every COMMAND gets its data (HELLO, STATUS, SETTING, ESTIMATE) and then exactly
 *   one ACK, or one NACK with the reason and no effect;
 * - live mode: while streaming, every sample tick reads the sensors, runs the
 *   active filter and sends SAMPLE + ESTIMATE, and once per second of samples a
 *   STATUS; when the link cannot take a sample's frames the sample is dropped
 *   and counted, never queued without bound; a failed sensor read is a dropped
 *   sample, a LOG line (at most one per second) and a retry of the sensor set-up
 *   once per second; an emulated feed that ends stops the stream (LOG + STATUS);
 * - injection mode: INJECT_SAMPLE runs the filter on the host's sample instead;
 * - the NAV filter also takes the barometer's and the receiver's readings that came with
 *   each live sample, and a POSITION_FIX after the next sample (a MARKER frame says so);
 *   a NAV_STATE follows each of its ESTIMATEs.
 * The filters are the fixed-point core (firmware/core); each keeps its settings
 * until RESET, and every change of filter, settings or mode restarts the active
 * filter at sample index 0.
 */
#ifndef APP_H
#define APP_H

#include <stdint.h>

#include "frame_ring.h"
#include "imu_filter.h"
#include "imu_proto.h"

/** Firmware version, sent in HELLO (the same as the host package's version). */
#define APP_VERSION_MAJOR 0
#define APP_VERSION_MINOR 1
#define APP_VERSION_PATCH 0

/** What a board sets up once: its name and what its sensors deliver. */
typedef struct {
    const char *board_name;       /**< HELLO.board, at most 16 characters */
    imu_real_t sample_rate;       /**< default sample_rate of every filter (the live tick), Hz, Q16 */
    uint8_t initial_filter;       /**< imu_filter_id_t active after start-up */
    imu_sensor_settings_t sensor; /**< scales of the counts board_sensors_read() delivers */
} app_config_t;

/** What app_poll() asks the board's main loop to do. */
typedef enum {
    APP_IDLE = 0,       /**< nothing more to do now: board_idle() */
    APP_BUSY = 1,       /**< more work may be waiting: call app_poll() again */
    APP_RESTART = 2,    /**< RESET was acknowledged: board_restart() */
    APP_BOOTLOADER = 3, /**< ENTER_BOOTLOADER was acknowledged: board_enter_bootloader() */
} app_result_t;

/** Application state. All members are private. */
typedef struct {
    app_config_t config;
    imu_filter_settings_t settings[IMU_FILTER_KIND_COUNT]; /**< every kind's, in imu_filter_kinds' order:
                                                               kept while another kind is active */
    imu_calibration_t calibration; /**< applied to the counts before every filter (SET_CALIBRATION) */
    imu_filter_t filter;          /**< the active filter */
    uint32_t index;               /**< samples the active filter has run since it (re)started */
    int streaming;                /**< 1 while live samples are streamed */
    int injection;                /**< 1 in injection mode */
    uint16_t tx_seq;              /**< sequence number of the next frame to the host */
    frame_ring_t sent;            /**< the input frames sent lately, for RESEND */
    uint32_t checkpoint_period;   /**< live samples between CHECKPOINTs, 0: none (SET_CHECKPOINT_PERIOD) */
    imu_proto_decoder_t decoder;
    uint8_t rx_frame[IMU_PROTO_MAX_FRAME];
    uint8_t wire[IMU_PROTO_MAX_WIRE]; /**< one encoded frame on its way out */
    int sensors_ok;               /**< 0 after a failed set-up or read, until a read succeeds */
    uint64_t sensor_retry_us;     /**< board time of the next sensor set-up attempt while failing */
    uint64_t error_log_us;        /**< board time of the next LOG about continuing sensor failures */
    uint32_t failures_since_log;  /**< failed reads not yet reported */
    uint32_t dropped_samples;     /**< STATUS.dropped_samples */
    uint32_t sensor_errors;       /**< STATUS.sensor_errors */
    uint32_t sensor_saturations;  /**< STATUS.sensor_saturations */
    uint32_t filter_cycles;       /**< STATUS.filter_cycles */
    uint32_t load_permille_q8;    /**< smoothed CPU load, per mille, Q8 */
    uint32_t samples_until_status; /**< live samples left before the next periodic STATUS */
    int marker_waiting;           /**< 1 while a POSITION_FIX waits for the next sample */
    imu_proto_cmd_position_fix_t marker; /**< that fix */
} app_t;

/** @brief Start the application: defaults for every filter, HELLO, sensor set-up. */
void app_init(app_t *app, const app_config_t *config);

/** @brief Handle what arrived and what is due; never waits. */
app_result_t app_poll(app_t *app);

/** @brief Send HELLO now (a board calls it when a new host connects, e.g. a TCP client). */
void app_send_hello(app_t *app);

#endif /* APP_H */
