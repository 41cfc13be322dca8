/**
 * @file imu_proto.h
 * @brief Frame protocol codec: COBS framing, CRC-32, and the messages of
 *        shared/protocol.toml (declared in the generated imu_proto_gen.h, included below).
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
 * Table implementation (256 entries, 1 KiB, generated in imu_proto_gen.c): one lookup per byte.
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

/* The messages of shared/protocol.toml (ids, codes, structs, pack/unpack/encode), generated
 * by tools/gen_protocol.py into a file of their own. */
#include "imu_proto_gen.h"

/** Largest frame of this schema, before COBS. */
#define IMU_PROTO_MAX_FRAME (IMU_PROTO_HEADER_SIZE + IMU_PROTO_MAX_PAYLOAD + IMU_PROTO_CRC_SIZE)
/** Largest frame of this schema on the wire, delimiter included. */
#define IMU_PROTO_MAX_WIRE (IMU_PROTO_COBS_MAX(IMU_PROTO_MAX_FRAME) + 1u)

#endif /* IMU_PROTO_H */
