/**
 * @file imu_proto.h
 * @brief Frame protocol codec: COBS framing, CRC-32, and the messages of
 *        shared/protocol.toml (generated section below).
 *
 * Wire format of one frame (docs/protocol.md):
 *
 *     COBS( msg_id u8 | seq u16 LE | payload | crc u32 LE ) 0x00
 *
 * crc is CRC-32/ISO-HDLC (the zlib CRC: reflected polynomial 0xEDB88320, initial
 * value and final XOR 0xFFFFFFFF) over msg_id, seq and payload. COBS removes every
 * 0x00 from the frame, so the single 0x00 delimiter marks frame ends and a receiver
 * that lost bytes or started mid-stream is back in sync at the next delimiter.
 * seq counts the frames of one direction (board to host, host to board), so gaps
 * reveal lost frames. Payloads are little-endian, packed byte by byte (no struct
 * punning), so the encoding is the same on every target.
 *
 * Sending: fill a message struct, call its `imu_proto_<message>_encode()` with
 * the next sequence number, write the returned bytes. Receiving: push every
 * received byte into an imu_proto_decoder_t; when imu_proto_decoder_push()
 * returns 1, dispatch on frame.msg_id and unpack frame.payload with
 * `imu_proto_<message>_unpack()`.
 *
 * Everything here is integer C99 without platform headers or allocation; the
 * decoder works in a caller-supplied buffer. Identical in the IMU_FIXED and
 * IMU_FLOAT builds.
 */
#ifndef IMU_PROTO_H
#define IMU_PROTO_H

#include <stddef.h>
#include <stdint.h>

/** Result of the calls that validate their input. */
typedef enum {
    IMU_PROTO_OK = 0,
    IMU_PROTO_ERR_LENGTH = -1, /**< payload length does not match the message, or a length field exceeds its maximum */
    IMU_PROTO_ERR_COBS = -2,   /**< not a valid COBS block (a 0x00 inside, or a block cut short) */
    IMU_PROTO_ERR_SPACE = -3,  /**< the output buffer is too small */
} imu_proto_result_t;

/** Bytes of msg_id + seq in front of the payload. */
#define IMU_PROTO_HEADER_SIZE 3u
/** Bytes of the CRC-32 after the payload. */
#define IMU_PROTO_CRC_SIZE 4u
/** Shortest frame (empty payload), before COBS. */
#define IMU_PROTO_MIN_FRAME (IMU_PROTO_HEADER_SIZE + IMU_PROTO_CRC_SIZE)
/** Largest COBS encoding of n bytes (without the delimiter): one code byte per 254 bytes, at least one. */
#define IMU_PROTO_COBS_MAX(n) ((n) + (n) / 254u + 1u)

/**
 * @brief CRC-32/ISO-HDLC of `len` bytes, continuing from `crc` (0 to start).
 *
 * Same convention as zlib's crc32(): the value returned is final (already
 * XORed) and can be passed back in to continue over more data.
 * Nibble-table implementation (64 bytes of table, two lookups per byte).
 */
uint32_t imu_proto_crc32(uint32_t crc, const uint8_t *data, size_t len);

/**
 * @brief COBS-encode `len` bytes into `out` (no delimiter appended).
 * @return encoded length (at least 1), or 0 when `out_cap` is smaller than needed
 *         (IMU_PROTO_COBS_MAX(len) always suffices). A block of 254 non-zero bytes
 *         at the very end is not followed by an empty block (as in the original paper).
 */
size_t imu_proto_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);

/**
 * @brief Decode one COBS block (the bytes between two delimiters, without them).
 * @param out_len receives the decoded length on success.
 * @return IMU_PROTO_OK; IMU_PROTO_ERR_COBS for empty input, a 0x00 byte, or a block
 *         cut short; IMU_PROTO_ERR_SPACE when the result would exceed `out_cap`.
 */
imu_proto_result_t imu_proto_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap,
                                         size_t *out_len);

/**
 * @brief Wire bytes of one frame: COBS(msg_id, seq, payload, CRC) followed by 0x00.
 * @return bytes written to `wire`, or 0 when they do not fit in `wire_cap`
 *         (IMU_PROTO_MAX_WIRE always suffices for payloads up to IMU_PROTO_MAX_PAYLOAD).
 */
size_t imu_proto_frame_encode(uint8_t msg_id, uint16_t seq, const uint8_t *payload, size_t payload_len,
                              uint8_t *wire, size_t wire_cap);

/** A received frame. `payload` points into the decoder's buffer: valid until the next push. */
typedef struct {
    uint8_t msg_id;
    uint16_t seq;
    const uint8_t *payload;
    size_t payload_len;
} imu_proto_frame_t;

/**
 * Incremental frame decoder. All members are private except the counters, which
 * count since imu_proto_decoder_init() and wrap at 2^32. Every non-empty span of
 * bytes between delimiters ends up counted exactly once: as a frame, a CRC error
 * or a resync.
 */
typedef struct {
    uint8_t *buf;          /**< caller's buffer for the decoded frame */
    size_t cap;            /**< its size; frames longer than this are dropped */
    size_t len;            /**< decoded bytes of the current span */
    size_t span;           /**< wire bytes of the current span */
    uint8_t remaining;     /**< data bytes left in the current COBS block */
    uint8_t zero_pending;  /**< the current block ends with an encoded 0x00 */
    uint8_t overflow;      /**< the current span did not fit in buf: discard it */
    uint32_t bytes;        /**< bytes pushed, delimiters included */
    uint32_t frames;       /**< valid frames reported */
    uint32_t crc_errors;   /**< well-formed spans whose CRC did not match */
    uint32_t resyncs;      /**< other spans discarded: bad COBS, too short, too long */
    uint32_t oversize;     /**< of the resyncs, the spans longer than the buffer */
} imu_proto_decoder_t;

/**
 * @brief Start decoding into `buf` (IMU_PROTO_MAX_FRAME bytes take every message of
 *        this schema). The first byte pushed is taken as the start of a frame.
 */
void imu_proto_decoder_init(imu_proto_decoder_t *d, uint8_t *buf, size_t cap);

/**
 * @brief Push one received byte.
 * @return 1 when this byte (a delimiter) completed a frame with a valid CRC, which
 *         is then stored in *frame; 0 otherwise (the counters tell why a span was
 *         discarded). Message ids and payload lengths are checked by the unpack
 *         functions, not here.
 */
int imu_proto_decoder_push(imu_proto_decoder_t *d, uint8_t byte, imu_proto_frame_t *frame);

/* BEGIN GENERATED by tools/gen_protocol.py from shared/protocol.toml: do not edit by hand */
/** Protocol version ([protocol] version), sent in HELLO. */
#define IMU_PROTO_VERSION 1u
/** Schema hash of shared/protocol.toml (CRC-32 of its canonical form), sent in HELLO. */
#define IMU_PROTO_SCHEMA_HASH 0xA373C5B8u
/** Largest payload of any message, bytes. */
#define IMU_PROTO_MAX_PAYLOAD 201u

/** Message ids (frame byte 0). */
typedef enum {
    IMU_PROTO_MSG_HELLO = 1, /**< Who the board is */
    IMU_PROTO_MSG_STATUS = 2, /**< Board state and health counters */
    IMU_PROTO_MSG_LOG = 3, /**< A human-readable line from the firmware */
    IMU_PROTO_MSG_ACK = 4, /**< The command was carried out */
    IMU_PROTO_MSG_NACK = 5, /**< The command was refused and had no effect */
    IMU_PROTO_MSG_SETTING = 6, /**< One setting of the active filter (answer to GET_SETTING) */
    IMU_PROTO_MSG_CALIBRATION = 7, /**< One axis of a sensor's calibration, applied to the counts before the filter: corrected[axis] = sum_j row[j] * (raw[j] - offset[j]) (answer to GET_CALIBRATION) */
    IMU_PROTO_MSG_SAMPLE = 16, /**< One raw sensor sample, in register counts, as the filter consumed it */
    IMU_PROTO_MSG_ESTIMATE = 17, /**< The filter output after sample `index`, exactly as the fixed-point core computed it */
    IMU_PROTO_MSG_BARO = 18, /**< One barometer measurement (the GY-86's MS5611): the raw conversions and the data sheet's compensation of them with the chip's PROM, as the board's driver computed it */
    IMU_PROTO_MSG_GNSS = 19, /**< One fix of the GNSS receiver, in its own units (u-blox NAV-PVT's), as the board received it */
    IMU_PROTO_MSG_NAV_STATE = 20, /**< The navigation filter's state after a sample, following its ESTIMATE (which carries the attitude and the gyroscope bias) while NAV is the active filter */
    IMU_PROTO_MSG_MARKER = 21, /**< A position fix from a known place (POSITION_FIX), as the board applied it: after the SAMPLE (or injected sample) it follows, before that sample's ESTIMATE */
    IMU_PROTO_MSG_COMMAND = 32, /**< A request to the board */
} imu_proto_msg_id_t;

/** Command ids (COMMAND.command). */
typedef enum {
    IMU_PROTO_CMD_START_STREAM = 1, /**< Start streaming SAMPLE and ESTIMATE frames for every live sensor sample */
    IMU_PROTO_CMD_STOP_STREAM = 2, /**< Stop streaming */
    IMU_PROTO_CMD_SELECT_FILTER = 3, /**< Make a filter active, the active one too: it restarts at sample index 0 from its current settings and re-aligns (the host restarts the active filter to resynchronise a recording after a lost sample) */
    IMU_PROTO_CMD_GET_SETTING = 4, /**< Read one setting of the active filter */
    IMU_PROTO_CMD_SET_SETTING = 5, /**< Write one setting of the active filter (raw fixed-point value, Q format as SETTING reports it); the filter restarts with it */
    IMU_PROTO_CMD_INJECT_SAMPLE = 6, /**< Run the active filter on this sample instead of a sensor reading (injection mode only) */
    IMU_PROTO_CMD_RESET = 7, /**< Restart the firmware */
    IMU_PROTO_CMD_ENTER_BOOTLOADER = 8, /**< Reboot into the serial bootloader (for flashing) */
    IMU_PROTO_CMD_GET_VERSION = 9, /**< Ask for HELLO */
    IMU_PROTO_CMD_GET_STATUS = 10, /**< Ask for STATUS */
    IMU_PROTO_CMD_SET_INJECTION_MODE = 11, /**< 1: the filter runs on INJECT_SAMPLE data and the sensors are ignored; 0: back to the sensors */
    IMU_PROTO_CMD_SET_CALIBRATION = 12, /**< Set one axis of a sensor's calibration (the offset of that axis and its row of the correction matrix, Q formats as CALIBRATION reports them); the active filter restarts with it */
    IMU_PROTO_CMD_GET_CALIBRATION = 13, /**< Read one axis of a sensor's calibration */
    IMU_PROTO_CMD_POSITION_FIX = 14, /**< A position fix from a known place ([seed 003]'s markers) for the NAV filter: trusted as its accuracy says, never gated */
} imu_proto_command_id_t;

/** Filter ids (the same values as imu_filter_id_t in firmware/core/imu_filter.h). */
typedef enum {
    IMU_PROTO_FILTER_EECF = 1, /**< enhanced explicit complementary filter ([seed 004]) */
    IMU_PROTO_FILTER_KF1D = 2, /**< per-axis angle/bias Kalman filter ([seed 002], [seed 003]) */
    IMU_PROTO_FILTER_ESKF = 3, /**< 9-state error-state Kalman filter ([seed 000]) */
    IMU_PROTO_FILTER_NAV = 4, /**< loosely coupled GNSS/INS navigation, 16-state error-state Kalman filter ([seed 002], [seed 003]): NAV_STATE besides ESTIMATE */
} imu_proto_filter_t;

/** Reason code of an ACK (always OK) or a NACK (why the command was refused). */
typedef enum {
    IMU_PROTO_REASON_OK = 0, /**< accepted (the reason of every ACK) */
    IMU_PROTO_REASON_UNKNOWN_COMMAND = 1, /**< the command id is not in this schema */
    IMU_PROTO_REASON_BAD_LENGTH = 2, /**< the argument bytes do not have the command's length */
    IMU_PROTO_REASON_BAD_ARGUMENT = 3, /**< an argument is not one of its allowed values (e.g. a flag other than 0/1) */
    IMU_PROTO_REASON_OUT_OF_RANGE = 4, /**< a setting value outside the range its filter accepts */
    IMU_PROTO_REASON_BUSY = 5, /**< the board cannot do this now (e.g. inject while streaming live samples) */
    IMU_PROTO_REASON_NOT_IN_INJECTION_MODE = 6, /**< INJECT_SAMPLE while injection mode is off */
    IMU_PROTO_REASON_UNKNOWN_FILTER = 7, /**< a filter id the board does not have */
    IMU_PROTO_REASON_UNKNOWN_SETTING = 8, /**< a setting index past the active filter's last setting */
    IMU_PROTO_REASON_NOT_SUPPORTED = 9, /**< a known command this board does not implement (e.g. ENTER_BOOTLOADER in QEMU) */
    IMU_PROTO_REASON_NOT_NAV = 10, /**< a navigation command (POSITION_FIX) while the active filter is not NAV */
} imu_proto_reason_t;

/** The sensors of a calibration (the order of imu_calibration_t in firmware/core/imu_sensor.h). */
typedef enum {
    IMU_PROTO_SENSOR_GYROSCOPE = 0, /**< MPU6050 gyroscope */
    IMU_PROTO_SENSOR_ACCELEROMETER = 1, /**< MPU6050 accelerometer */
    IMU_PROTO_SENSOR_MAGNETOMETER = 2, /**< HMC5883L magnetometer */
} imu_proto_sensor_t;

/** LOG severity, numerically equal to Python's logging levels. */
typedef enum {
    IMU_PROTO_LOG_LEVEL_DEBUG = 10, /**< diagnostics */
    IMU_PROTO_LOG_LEVEL_INFO = 20, /**< normal events (start-up, filter selected) */
    IMU_PROTO_LOG_LEVEL_WARNING = 30, /**< something unexpected that the board recovered from */
    IMU_PROTO_LOG_LEVEL_ERROR = 40, /**< something failed (sensor not answering, overrun) */
} imu_proto_log_level_t;

/** HELLO payload bytes. */
#define IMU_PROTO_HELLO_SIZE 37u

/** HELLO (id 0x01, to_host): Who the board is. Sent after every start-up or reset and in answer to
 *  GET_VERSION; the host refuses a board whose schema_hash differs from its own.
 */
typedef struct {
    uint8_t firmware_major; /**< firmware version, major */
    uint8_t firmware_minor; /**< firmware version, minor */
    uint8_t firmware_patch; /**< firmware version, patch */
    uint8_t protocol_version; /**< [protocol] version of the schema the firmware was built from */
    uint32_t schema_hash; /**< schema hash of the firmware's protocol definition */
    char board[16]; /**< board name: stm32f407-gy86, qemu-stm32f405 (QEMU netduinoplus2), native */
    uint8_t filters; /**< filters the firmware has: bit (1 << filter id) set for each */
    int32_t gyro_scale; /**< gyroscope sensitivity the filters use, rad/s per count, Q40 (imu_sensor_settings_t); the range is 32768 counts (MPU6050 FS_SEL=3: 1.0642e-3, +-2000 deg/s) */
    int32_t acc_scale; /**< accelerometer sensitivity, m/s^2 per count, Q32; the range is 32768 counts (MPU6050 AFS_SEL=2: 2.3943e-3, +-8 g) */
    int32_t mag_scale; /**< magnetometer sensitivity, uT per count, Q24; the range is 2048 counts (HMC5883L GN=1: 9.1743e-2, +-1.3 gauss) */
} imu_proto_hello_t;

/** @brief Payload bytes of HELLO into `payload` (IMU_PROTO_HELLO_SIZE bytes); returns IMU_PROTO_HELLO_SIZE. */
size_t imu_proto_hello_pack(const imu_proto_hello_t *m, uint8_t *payload);
/** @brief Fields of a HELLO payload; IMU_PROTO_ERR_LENGTH when `len` is not a HELLO payload length. */
imu_proto_result_t imu_proto_hello_unpack(imu_proto_hello_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a HELLO frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_hello_encode(const imu_proto_hello_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** STATUS payload bytes. */
#define IMU_PROTO_STATUS_SIZE 37u

/** STATUS (id 0x02, to_host): Board state and health counters. Answer to GET_STATUS; a board may
 *  also send it periodically.
 */
typedef struct {
    uint32_t uptime_ms; /**< time since start-up, ms (wraps after 49.7 days) */
    uint8_t active_filter; /**< filter that produces ESTIMATE */
    uint32_t sample_rate_mhz; /**< configured sensor sample rate, mHz (100 Hz = 100000) */
    uint32_t dropped_samples; /**< sensor samples the board could not process or send in time */
    uint16_t cpu_load_permille; /**< share of the sample period spent working, per mille */
    uint32_t filter_saturations; /**< fixed-point saturation events of the active filter since it (re)started */
    uint32_t sensor_saturations; /**< sensor readings at the end of their range (+-32767 counts) */
    uint8_t streaming; /**< 1 while SAMPLE/ESTIMATE frames are streamed */
    uint8_t injection_mode; /**< 1 while the filter runs on injected samples instead of the sensors */
    uint32_t filter_cycles; /**< cost of the last filter update (update and output of one sample), in ticks of the board's cycle counter */
    uint32_t cycle_hz; /**< frequency of that counter, Hz: the CPU clock where the board counts cycles (the STM32F407: DWT), the rate of its clock where it counts time instead (QEMU: 1000000, native: 1000000000), 0 where it has none */
    uint32_t sensor_errors; /**< sensor reads that failed since start-up (each is also a dropped sample; LOG says why) */
} imu_proto_status_t;

/** @brief Payload bytes of STATUS into `payload` (IMU_PROTO_STATUS_SIZE bytes); returns IMU_PROTO_STATUS_SIZE. */
size_t imu_proto_status_pack(const imu_proto_status_t *m, uint8_t *payload);
/** @brief Fields of a STATUS payload; IMU_PROTO_ERR_LENGTH when `len` is not a STATUS payload length. */
imu_proto_result_t imu_proto_status_unpack(imu_proto_status_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a STATUS frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_status_encode(const imu_proto_status_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** LOG maximum payload bytes. */
#define IMU_PROTO_LOG_SIZE 201u
/** LOG payload bytes with an empty text. */
#define IMU_PROTO_LOG_MIN_SIZE 1u

/** LOG (id 0x03, to_host): A human-readable line from the firmware. */
typedef struct {
    uint8_t level; /**< severity */
    char text[200]; /**< message, UTF-8, no terminator */
    size_t text_len; /**< bytes used in text, at most 200 */
} imu_proto_log_t;

/** @brief Payload bytes of LOG into `payload` (IMU_PROTO_LOG_SIZE bytes); returns the payload length, 0 when a length field exceeds its maximum. */
size_t imu_proto_log_pack(const imu_proto_log_t *m, uint8_t *payload);
/** @brief Fields of a LOG payload; IMU_PROTO_ERR_LENGTH when `len` is not a LOG payload length. */
imu_proto_result_t imu_proto_log_unpack(imu_proto_log_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a LOG frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_log_encode(const imu_proto_log_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** ACK payload bytes. */
#define IMU_PROTO_ACK_SIZE 4u

/** ACK (id 0x04, to_host): The command was carried out. Any data it asked for (HELLO, STATUS,
 *  SETTING, ESTIMATE) was sent before the ACK.
 */
typedef struct {
    uint16_t command_seq; /**< command_seq of the COMMAND answered */
    uint8_t command; /**< command id of the COMMAND answered */
    uint8_t reason; /**< OK */
} imu_proto_ack_t;

/** @brief Payload bytes of ACK into `payload` (IMU_PROTO_ACK_SIZE bytes); returns IMU_PROTO_ACK_SIZE. */
size_t imu_proto_ack_pack(const imu_proto_ack_t *m, uint8_t *payload);
/** @brief Fields of a ACK payload; IMU_PROTO_ERR_LENGTH when `len` is not a ACK payload length. */
imu_proto_result_t imu_proto_ack_unpack(imu_proto_ack_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a ACK frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_ack_encode(const imu_proto_ack_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** NACK payload bytes. */
#define IMU_PROTO_NACK_SIZE 4u

/** NACK (id 0x05, to_host): The command was refused and had no effect. */
typedef struct {
    uint16_t command_seq; /**< command_seq of the COMMAND answered */
    uint8_t command; /**< command id of the COMMAND answered (as received, even when unknown) */
    uint8_t reason; /**< why it was refused */
} imu_proto_nack_t;

/** @brief Payload bytes of NACK into `payload` (IMU_PROTO_NACK_SIZE bytes); returns IMU_PROTO_NACK_SIZE. */
size_t imu_proto_nack_pack(const imu_proto_nack_t *m, uint8_t *payload);
/** @brief Fields of a NACK payload; IMU_PROTO_ERR_LENGTH when `len` is not a NACK payload length. */
imu_proto_result_t imu_proto_nack_unpack(imu_proto_nack_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a NACK frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_nack_encode(const imu_proto_nack_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** SETTING payload bytes. */
#define IMU_PROTO_SETTING_SIZE 52u

/** SETTING (id 0x06, to_host): One setting of the active filter (answer to GET_SETTING). value is
 *  the raw fixed-point integer: the real value is value * 2^-frac_bits.
 */
typedef struct {
    uint8_t filter_id; /**< filter the setting belongs to */
    uint8_t index; /**< position in the filter's settings table */
    uint8_t setting_count; /**< number of settings of this filter (valid indices are 0 .. setting_count - 1) */
    int32_t value; /**< raw value in Q(frac_bits) */
    int8_t frac_bits; /**< fraction bits of the fixed-point format */
    char name[24]; /**< field name as in the C settings struct */
    char unit[12]; /**< SI unit of the real value */
    int32_t min; /**< smallest value SET_SETTING accepts, raw in Q(frac_bits) (the filter's descriptor table) */
    int32_t max; /**< largest value SET_SETTING accepts, raw in Q(frac_bits) */
} imu_proto_setting_t;

/** @brief Payload bytes of SETTING into `payload` (IMU_PROTO_SETTING_SIZE bytes); returns IMU_PROTO_SETTING_SIZE. */
size_t imu_proto_setting_pack(const imu_proto_setting_t *m, uint8_t *payload);
/** @brief Fields of a SETTING payload; IMU_PROTO_ERR_LENGTH when `len` is not a SETTING payload length. */
imu_proto_result_t imu_proto_setting_unpack(imu_proto_setting_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a SETTING frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_setting_encode(const imu_proto_setting_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** CALIBRATION payload bytes. */
#define IMU_PROTO_CALIBRATION_SIZE 20u

/** CALIBRATION (id 0x07, to_host): One axis of a sensor's calibration, applied to the counts before
 *  the filter: corrected[axis] = sum_j row[j] * (raw[j] - offset[j]) (answer to GET_CALIBRATION).
 *  Real values are offset * 2^-offset_frac_bits counts and row[j] * 2^-matrix_frac_bits.
 */
typedef struct {
    uint8_t sensor; /**< the sensor */
    uint8_t axis; /**< the axis, 0..2 (x, y, z) */
    int32_t offset; /**< this axis's offset, counts, raw in Q(offset_frac_bits) */
    int32_t row[3]; /**< this axis's row of the correction matrix, raw in Q(matrix_frac_bits) */
    int8_t offset_frac_bits; /**< fraction bits of offset (8) */
    int8_t matrix_frac_bits; /**< fraction bits of row (24) */
} imu_proto_calibration_t;

/** @brief Payload bytes of CALIBRATION into `payload` (IMU_PROTO_CALIBRATION_SIZE bytes); returns IMU_PROTO_CALIBRATION_SIZE. */
size_t imu_proto_calibration_pack(const imu_proto_calibration_t *m, uint8_t *payload);
/** @brief Fields of a CALIBRATION payload; IMU_PROTO_ERR_LENGTH when `len` is not a CALIBRATION payload length. */
imu_proto_result_t imu_proto_calibration_unpack(imu_proto_calibration_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a CALIBRATION frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_calibration_encode(const imu_proto_calibration_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** SAMPLE payload bytes. */
#define IMU_PROTO_SAMPLE_SIZE 28u

/** SAMPLE (id 0x10, to_host): One raw sensor sample, in register counts, as the filter consumed it. */
typedef struct {
    uint32_t timestamp_us; /**< board time when the sample was read, us (wraps after 71.6 min) */
    uint32_t index; /**< sample counter since the filter (re)started */
    int16_t gyr[3]; /**< gyroscope x, y, z, counts (MPU6050) */
    int16_t acc[3]; /**< accelerometer x, y, z, counts (MPU6050) */
    int16_t mag[3]; /**< magnetometer x, y, z, counts (HMC5883L), in the core's sensor axes */
    int16_t temperature; /**< MPU6050 temperature register, counts */
} imu_proto_sample_t;

/** @brief Payload bytes of SAMPLE into `payload` (IMU_PROTO_SAMPLE_SIZE bytes); returns IMU_PROTO_SAMPLE_SIZE. */
size_t imu_proto_sample_pack(const imu_proto_sample_t *m, uint8_t *payload);
/** @brief Fields of a SAMPLE payload; IMU_PROTO_ERR_LENGTH when `len` is not a SAMPLE payload length. */
imu_proto_result_t imu_proto_sample_unpack(imu_proto_sample_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a SAMPLE frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_sample_encode(const imu_proto_sample_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** ESTIMATE payload bytes. */
#define IMU_PROTO_ESTIMATE_SIZE 102u

/** ESTIMATE (id 0x11, to_host): The filter output after sample `index`, exactly as the fixed-point
 *  core computed it.
 */
typedef struct {
    uint32_t index; /**< index of the SAMPLE (or injected sample) this estimate follows */
    uint8_t filter_id; /**< filter that computed it */
    int32_t quat[4]; /**< sensor-to-earth (ENU) quaternion w, x, y, z, Q30 */
    int32_t gyro_bias[3]; /**< gyroscope bias estimate x, y, z, rad/s, Q24 */
    int32_t euler[3]; /**< roll, pitch, heading, rad, Q29 */
    int32_t cov_mantissa[9]; /**< covariance diagonal P_ii = cov_mantissa[i] * 2^(cov_exponent[i] - 30); ESKF order: attitude error x, y, z (rad^2), gyro bias x, y, z ((rad/s)^2), accelerometer bias x, y, z (g^2); zero where a filter has no such state */
    int8_t cov_exponent[9]; /**< exponents of the covariance diagonal */
    uint32_t saturations; /**< saturation events of the filter since it (re)started */
    int32_t weights[2]; /**< weights of the ESKF's last gravity and heading measurements, Q30 in [0, 1] (0: rejected as disturbed); zero for the other filters */
} imu_proto_estimate_t;

/** @brief Payload bytes of ESTIMATE into `payload` (IMU_PROTO_ESTIMATE_SIZE bytes); returns IMU_PROTO_ESTIMATE_SIZE. */
size_t imu_proto_estimate_pack(const imu_proto_estimate_t *m, uint8_t *payload);
/** @brief Fields of a ESTIMATE payload; IMU_PROTO_ERR_LENGTH when `len` is not a ESTIMATE payload length. */
imu_proto_result_t imu_proto_estimate_unpack(imu_proto_estimate_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a ESTIMATE frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_estimate_encode(const imu_proto_estimate_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** BARO payload bytes. */
#define IMU_PROTO_BARO_SIZE 24u

/** BARO (id 0x12, to_host): One barometer measurement (the GY-86's MS5611): the raw conversions and
 *  the data sheet's compensation of them with the chip's PROM, as the board's driver computed it.
 *  Emulated boards take D1 and D2 from their sensor feed (a BARO frame before the SAMPLE it belongs
 *  to; the other fields there are ignored).
 */
typedef struct {
    uint32_t timestamp_us; /**< board time of the SAMPLE read with it (its timestamp_us), us */
    uint32_t index; /**< index of the SAMPLE read with it (the measurement completed during that sample's read or before) */
    uint32_t d1; /**< raw pressure conversion, 24 bits */
    uint32_t d2; /**< raw temperature conversion, 24 bits */
    int32_t pressure_pa; /**< compensated pressure, Pa (the data sheet's 0.01 mbar) */
    int32_t temperature_cdeg; /**< compensated temperature, 0.01 degC */
} imu_proto_baro_t;

/** @brief Payload bytes of BARO into `payload` (IMU_PROTO_BARO_SIZE bytes); returns IMU_PROTO_BARO_SIZE. */
size_t imu_proto_baro_pack(const imu_proto_baro_t *m, uint8_t *payload);
/** @brief Fields of a BARO payload; IMU_PROTO_ERR_LENGTH when `len` is not a BARO payload length. */
imu_proto_result_t imu_proto_baro_unpack(imu_proto_baro_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a BARO frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_baro_encode(const imu_proto_baro_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** GNSS payload bytes. */
#define IMU_PROTO_GNSS_SIZE 52u

/** GNSS (id 0x13, to_host): One fix of the GNSS receiver, in its own units (u-blox NAV-PVT's), as
 *  the board received it. Emulated boards take it from their sensor feed (a GNSS frame before the
 *  SAMPLE during which it arrives; timestamp_us and index there are not used).
 */
typedef struct {
    uint32_t timestamp_us; /**< board time of the SAMPLE read when the fix had arrived (its timestamp_us), us */
    uint32_t index; /**< index of that SAMPLE: the fix arrived during its read or before */
    uint32_t time_ms; /**< the time the fix is valid for: GPS time of week, ms (NMEA: UTC time of day); earlier than its arrival by the receiver's latency */
    uint8_t fix_type; /**< 0 none, 1 dead reckoning, 2 2-D, 3 3-D, 4 GNSS + dead reckoning, 5 time only (NAV-PVT's fixType) */
    uint8_t fix_ok; /**< 1: within the receiver's accuracy masks (NAV-PVT's gnssFixOK) */
    uint8_t num_sv; /**< satellites used */
    uint8_t has_velocity; /**< 1: vel_ned_mm_s and s_acc_mm_s are valid */
    int32_t lat_1e7deg; /**< latitude, 1e-7 deg */
    int32_t lon_1e7deg; /**< longitude, 1e-7 deg */
    int32_t height_mm; /**< height above the WGS-84 ellipsoid, mm */
    uint32_t h_acc_mm; /**< horizontal accuracy estimate, mm (0: not given) */
    uint32_t v_acc_mm; /**< vertical accuracy estimate, mm (0: not given) */
    int32_t vel_ned_mm_s[3]; /**< velocity north, east, down, mm/s */
    uint32_t s_acc_mm_s; /**< speed accuracy estimate, mm/s (0: not given) */
} imu_proto_gnss_t;

/** @brief Payload bytes of GNSS into `payload` (IMU_PROTO_GNSS_SIZE bytes); returns IMU_PROTO_GNSS_SIZE. */
size_t imu_proto_gnss_pack(const imu_proto_gnss_t *m, uint8_t *payload);
/** @brief Fields of a GNSS payload; IMU_PROTO_ERR_LENGTH when `len` is not a GNSS payload length. */
imu_proto_result_t imu_proto_gnss_unpack(imu_proto_gnss_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a GNSS frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_gnss_encode(const imu_proto_gnss_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** NAV_STATE payload bytes. */
#define IMU_PROTO_NAV_STATE_SIZE 145u

/** NAV_STATE (id 0x14, to_host): The navigation filter's state after a sample, following its
 *  ESTIMATE (which carries the attitude and the gyroscope bias) while NAV is the active filter.
 */
typedef struct {
    uint32_t index; /**< index of the SAMPLE (or injected sample) it follows */
    uint8_t mode; /**< 0 not started (no sample with a force yet: everything else zero), 1 attitude only (no fix yet: the position is nowhere), 2 navigating */
    int32_t lat; /**< latitude, rad, Q29 */
    int32_t lon; /**< longitude, rad, Q29 */
    int32_t height_mm; /**< height above the WGS-84 ellipsoid, mm */
    int32_t vel[3]; /**< velocity east, north, up, m/s, Q20 */
    int32_t acc_bias[3]; /**< accelerometer bias estimate x, y, z, m/s^2, Q16 */
    int32_t baro_bias_mm; /**< the barometer's height minus the true height, mm */
    int32_t var_mantissa[16]; /**< error-state variances P_ii = var_mantissa[i] * 2^(var_exponent[i] - 30) in the states' units squared: position east, north, up (1024 m), velocity (64 m/s), attitude error x, y, z (rad), gyro bias (rad/s), accelerometer bias (m/s^2), barometer bias (1024 m) */
    int8_t var_exponent[16]; /**< exponents of the variances */
    uint32_t since_fix; /**< samples since the last GNSS fix, used or not (stops counting at a minute's) */
    uint32_t rejected; /**< GNSS fixes the gate rejected since the filter started */
    uint32_t zero_velocity; /**< zero-velocity updates since the filter started */
    uint32_t resets; /**< times a run of rejected GNSS fixes that agreed with each other reset the position and velocity to the fixes (the filter's own divergence, a cold receiver's first fix) since the filter started */
    uint32_t fades; /**< GNSS fixes that agreed with the last one used but not with the estimate and scaled the covariance up (a gyro bias step) since the filter started */
} imu_proto_nav_state_t;

/** @brief Payload bytes of NAV_STATE into `payload` (IMU_PROTO_NAV_STATE_SIZE bytes); returns IMU_PROTO_NAV_STATE_SIZE. */
size_t imu_proto_nav_state_pack(const imu_proto_nav_state_t *m, uint8_t *payload);
/** @brief Fields of a NAV_STATE payload; IMU_PROTO_ERR_LENGTH when `len` is not a NAV_STATE payload length. */
imu_proto_result_t imu_proto_nav_state_unpack(imu_proto_nav_state_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a NAV_STATE frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_nav_state_encode(const imu_proto_nav_state_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** MARKER payload bytes. */
#define IMU_PROTO_MARKER_SIZE 29u

/** MARKER (id 0x15, to_host): A position fix from a known place (POSITION_FIX), as the board
 *  applied it: after the SAMPLE (or injected sample) it follows, before that sample's ESTIMATE.
 */
typedef struct {
    uint32_t timestamp_us; /**< board time of that SAMPLE (its timestamp_us; 0 for an injected sample), us */
    uint32_t index; /**< index of that SAMPLE */
    int32_t lat_1e7deg; /**< latitude, 1e-7 deg */
    int32_t lon_1e7deg; /**< longitude, 1e-7 deg */
    int32_t height_mm; /**< height above the WGS-84 ellipsoid, mm */
    uint32_t h_acc_mm; /**< horizontal accuracy, mm */
    uint32_t v_acc_mm; /**< vertical accuracy, mm */
    uint8_t used; /**< 1: the filter took it (0: the filter had not started) */
} imu_proto_marker_t;

/** @brief Payload bytes of MARKER into `payload` (IMU_PROTO_MARKER_SIZE bytes); returns IMU_PROTO_MARKER_SIZE. */
size_t imu_proto_marker_pack(const imu_proto_marker_t *m, uint8_t *payload);
/** @brief Fields of a MARKER payload; IMU_PROTO_ERR_LENGTH when `len` is not a MARKER payload length. */
imu_proto_result_t imu_proto_marker_unpack(imu_proto_marker_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a MARKER frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_marker_encode(const imu_proto_marker_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** COMMAND maximum payload bytes. */
#define IMU_PROTO_COMMAND_SIZE 31u
/** COMMAND payload bytes with an empty args. */
#define IMU_PROTO_COMMAND_MIN_SIZE 3u

/** COMMAND (id 0x20, to_board): A request to the board. Every COMMAND is answered by exactly one
 *  ACK or NACK carrying its command_seq.
 */
typedef struct {
    uint8_t command; /**< command id (see the command table) */
    uint16_t command_seq; /**< chosen by the host, echoed in the ACK/NACK */
    uint8_t args[28]; /**< the command's arguments, packed like a payload (layout per command) */
    size_t args_len; /**< bytes used in args, at most 28 */
} imu_proto_command_t;

/** @brief Payload bytes of COMMAND into `payload` (IMU_PROTO_COMMAND_SIZE bytes); returns the payload length, 0 when a length field exceeds its maximum. */
size_t imu_proto_command_pack(const imu_proto_command_t *m, uint8_t *payload);
/** @brief Fields of a COMMAND payload; IMU_PROTO_ERR_LENGTH when `len` is not a COMMAND payload length. */
imu_proto_result_t imu_proto_command_unpack(imu_proto_command_t *m, const uint8_t *payload, size_t len);
/** @brief Wire bytes of a COMMAND frame (delimiter included); 0 when they do not fit or pack fails. */
size_t imu_proto_command_encode(const imu_proto_command_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap);

/** SELECT_FILTER argument bytes. */
#define IMU_PROTO_CMD_SELECT_FILTER_SIZE 1u
/** Arguments of SELECT_FILTER. */
typedef struct {
    uint8_t filter_id; /**< filter to activate */
} imu_proto_cmd_select_filter_t;

/** @brief Argument bytes of SELECT_FILTER into `args` (IMU_PROTO_CMD_SELECT_FILTER_SIZE bytes); returns that size. */
size_t imu_proto_cmd_select_filter_pack(const imu_proto_cmd_select_filter_t *a, uint8_t *args);
/** @brief Arguments of SELECT_FILTER; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_SELECT_FILTER_SIZE. */
imu_proto_result_t imu_proto_cmd_select_filter_unpack(imu_proto_cmd_select_filter_t *a, const uint8_t *args, size_t len);

/** GET_SETTING argument bytes. */
#define IMU_PROTO_CMD_GET_SETTING_SIZE 1u
/** Arguments of GET_SETTING. */
typedef struct {
    uint8_t index; /**< setting index, 0 .. setting_count - 1 */
} imu_proto_cmd_get_setting_t;

/** @brief Argument bytes of GET_SETTING into `args` (IMU_PROTO_CMD_GET_SETTING_SIZE bytes); returns that size. */
size_t imu_proto_cmd_get_setting_pack(const imu_proto_cmd_get_setting_t *a, uint8_t *args);
/** @brief Arguments of GET_SETTING; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_GET_SETTING_SIZE. */
imu_proto_result_t imu_proto_cmd_get_setting_unpack(imu_proto_cmd_get_setting_t *a, const uint8_t *args, size_t len);

/** SET_SETTING argument bytes. */
#define IMU_PROTO_CMD_SET_SETTING_SIZE 5u
/** Arguments of SET_SETTING. */
typedef struct {
    uint8_t index; /**< setting index */
    int32_t value; /**< raw value in the setting's Q format */
} imu_proto_cmd_set_setting_t;

/** @brief Argument bytes of SET_SETTING into `args` (IMU_PROTO_CMD_SET_SETTING_SIZE bytes); returns that size. */
size_t imu_proto_cmd_set_setting_pack(const imu_proto_cmd_set_setting_t *a, uint8_t *args);
/** @brief Arguments of SET_SETTING; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_SET_SETTING_SIZE. */
imu_proto_result_t imu_proto_cmd_set_setting_unpack(imu_proto_cmd_set_setting_t *a, const uint8_t *args, size_t len);

/** INJECT_SAMPLE argument bytes. */
#define IMU_PROTO_CMD_INJECT_SAMPLE_SIZE 28u
/** @brief Argument bytes of INJECT_SAMPLE into `args` (IMU_PROTO_CMD_INJECT_SAMPLE_SIZE bytes); returns that size. */
size_t imu_proto_cmd_inject_sample_pack(const imu_proto_sample_t *a, uint8_t *args);
/** @brief Arguments of INJECT_SAMPLE; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_INJECT_SAMPLE_SIZE. */
imu_proto_result_t imu_proto_cmd_inject_sample_unpack(imu_proto_sample_t *a, const uint8_t *args, size_t len);

/** SET_INJECTION_MODE argument bytes. */
#define IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE 1u
/** Arguments of SET_INJECTION_MODE. */
typedef struct {
    uint8_t enabled; /**< 0 or 1 */
} imu_proto_cmd_set_injection_mode_t;

/** @brief Argument bytes of SET_INJECTION_MODE into `args` (IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE bytes); returns that size. */
size_t imu_proto_cmd_set_injection_mode_pack(const imu_proto_cmd_set_injection_mode_t *a, uint8_t *args);
/** @brief Arguments of SET_INJECTION_MODE; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE. */
imu_proto_result_t imu_proto_cmd_set_injection_mode_unpack(imu_proto_cmd_set_injection_mode_t *a, const uint8_t *args, size_t len);

/** SET_CALIBRATION argument bytes. */
#define IMU_PROTO_CMD_SET_CALIBRATION_SIZE 18u
/** Arguments of SET_CALIBRATION. */
typedef struct {
    uint8_t sensor; /**< the sensor */
    uint8_t axis; /**< the axis, 0..2 */
    int32_t offset; /**< offset, counts, Q8 */
    int32_t row[3]; /**< row of the correction matrix, Q24 */
} imu_proto_cmd_set_calibration_t;

/** @brief Argument bytes of SET_CALIBRATION into `args` (IMU_PROTO_CMD_SET_CALIBRATION_SIZE bytes); returns that size. */
size_t imu_proto_cmd_set_calibration_pack(const imu_proto_cmd_set_calibration_t *a, uint8_t *args);
/** @brief Arguments of SET_CALIBRATION; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_SET_CALIBRATION_SIZE. */
imu_proto_result_t imu_proto_cmd_set_calibration_unpack(imu_proto_cmd_set_calibration_t *a, const uint8_t *args, size_t len);

/** GET_CALIBRATION argument bytes. */
#define IMU_PROTO_CMD_GET_CALIBRATION_SIZE 2u
/** Arguments of GET_CALIBRATION. */
typedef struct {
    uint8_t sensor; /**< the sensor */
    uint8_t axis; /**< the axis, 0..2 */
} imu_proto_cmd_get_calibration_t;

/** @brief Argument bytes of GET_CALIBRATION into `args` (IMU_PROTO_CMD_GET_CALIBRATION_SIZE bytes); returns that size. */
size_t imu_proto_cmd_get_calibration_pack(const imu_proto_cmd_get_calibration_t *a, uint8_t *args);
/** @brief Arguments of GET_CALIBRATION; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_GET_CALIBRATION_SIZE. */
imu_proto_result_t imu_proto_cmd_get_calibration_unpack(imu_proto_cmd_get_calibration_t *a, const uint8_t *args, size_t len);

/** POSITION_FIX argument bytes. */
#define IMU_PROTO_CMD_POSITION_FIX_SIZE 20u
/** Arguments of POSITION_FIX. */
typedef struct {
    int32_t lat_1e7deg; /**< latitude, 1e-7 deg, within +-85 deg */
    int32_t lon_1e7deg; /**< longitude, 1e-7 deg, within +-180 deg */
    int32_t height_mm; /**< height above the WGS-84 ellipsoid, mm, within +-10 km */
    uint32_t h_acc_mm; /**< horizontal accuracy, mm, 1 .. 2^30 */
    uint32_t v_acc_mm; /**< vertical accuracy, mm, 1 .. 2^30 */
} imu_proto_cmd_position_fix_t;

/** @brief Argument bytes of POSITION_FIX into `args` (IMU_PROTO_CMD_POSITION_FIX_SIZE bytes); returns that size. */
size_t imu_proto_cmd_position_fix_pack(const imu_proto_cmd_position_fix_t *a, uint8_t *args);
/** @brief Arguments of POSITION_FIX; IMU_PROTO_ERR_LENGTH when `len` is not IMU_PROTO_CMD_POSITION_FIX_SIZE. */
imu_proto_result_t imu_proto_cmd_position_fix_unpack(imu_proto_cmd_position_fix_t *a, const uint8_t *args, size_t len);

/** @brief Argument bytes of a command; -1 for an id that is not a command (NACK UNKNOWN_COMMAND). */
int imu_proto_command_args_size(uint8_t command);
/* END GENERATED */

/** Largest frame of this schema, before COBS. */
#define IMU_PROTO_MAX_FRAME (IMU_PROTO_HEADER_SIZE + IMU_PROTO_MAX_PAYLOAD + IMU_PROTO_CRC_SIZE)
/** Largest frame of this schema on the wire, delimiter included. */
#define IMU_PROTO_MAX_WIRE (IMU_PROTO_COBS_MAX(IMU_PROTO_MAX_FRAME) + 1u)

#endif /* IMU_PROTO_H */
