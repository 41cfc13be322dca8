/**
 * @file ubx.h
 * @brief The u-blox UBX protocol (M8/M9 receivers): frames in and out, NAV-PVT and ACK.
 *
 * Follows "u-blox 8 / u-blox M8 Receiver description including protocol specification"
 * (UBX-13003221, "the spec"), section "UBX protocol": a frame is the sync characters
 * 0xB5 0x62, the class and id bytes, a little-endian u16 payload length, the payload and
 * the two bytes CK_A, CK_B of an 8-bit Fletcher checksum over class, id, length and payload.
 *
 * ubx_parser_push() takes the receiver's bytes one at a time, in any chunking, and says
 * when a whole frame with a valid checksum is in the parser's buffer; garbage, NMEA
 * sentences between frames, a bad checksum or a frame longer than the buffer are counted
 * and skipped, and the parser looks for the next sync characters after them (a frame whose
 * length was damaged may swallow the one after it). ubx_nav_pvt() decodes the NAV-PVT
 * payload, ubx_encode()
 * writes a frame (for the CFG messages a board sends at start-up).
 *
 * No dynamic memory, integer only, bounded time per byte.
 */
#ifndef UBX_H
#define UBX_H

#include <stddef.h>
#include <stdint.h>

#define UBX_SYNC_1 0xB5u
#define UBX_SYNC_2 0x62u
/** Bytes around a payload: sync 2, class 1, id 1, length 2, checksum 2. */
#define UBX_OVERHEAD 8u

#define UBX_CLASS_NAV 0x01u
#define UBX_ID_NAV_PVT 0x07u
#define UBX_NAV_PVT_LENGTH 92u
#define UBX_CLASS_ACK 0x05u
#define UBX_ID_ACK_NAK 0x00u
#define UBX_ID_ACK_ACK 0x01u
#define UBX_CLASS_CFG 0x06u

/** Largest payload the parser keeps (NAV-PVT's 92 bytes fit; longer frames are skipped). */
#define UBX_MAX_PAYLOAD 100u

/** A parser. All members are private but the counters. */
typedef struct {
    uint8_t state;                     /**< where in a frame the next byte goes (ubx.c) */
    uint8_t msg_class, msg_id;         /**< of the frame being received */
    uint16_t length;                   /**< its payload length */
    uint16_t received;                 /**< payload bytes received so far */
    uint8_t ck_a, ck_b;                /**< running checksum */
    uint8_t payload[UBX_MAX_PAYLOAD];
    uint32_t frames;                   /**< frames with a valid checksum */
    uint32_t checksum_errors;          /**< frames whose checksum did not match */
    uint32_t oversized;                /**< frames longer than UBX_MAX_PAYLOAD, skipped */
    uint32_t skipped_bytes;            /**< bytes outside any frame (NMEA, noise) */
} ubx_parser_t;

/** @brief An empty parser, counters zero. */
void ubx_parser_init(ubx_parser_t *p);

/**
 * @brief Take one byte.
 * @return 1 when it completed a frame with a valid checksum: its class, id, length and
 *         payload are in the parser until the next call; else 0.
 */
int ubx_parser_push(ubx_parser_t *p, uint8_t byte);

/** @brief The completed frame's class, id, payload and length (valid after push returned 1). */
uint8_t ubx_frame_class(const ubx_parser_t *p);
uint8_t ubx_frame_id(const ubx_parser_t *p);
const uint8_t *ubx_frame_payload(const ubx_parser_t *p, uint16_t *length);

/** @brief The spec's 8-bit Fletcher checksum of `len` bytes (class .. payload): CK_A in the low byte. */
uint16_t ubx_checksum(const uint8_t *data, size_t len);

/**
 * @brief Write a frame: sync, class, id, length, `payload`, checksum.
 * @return bytes written (`len` + UBX_OVERHEAD), or 0 when `cap` is too small.
 */
size_t ubx_encode(uint8_t msg_class, uint8_t msg_id, const uint8_t *payload, uint16_t len, uint8_t *out,
                  size_t cap);

/** Fix types of NAV-PVT (the spec's fixType). */
typedef enum {
    UBX_FIX_NONE = 0,
    UBX_FIX_DEAD_RECKONING = 1,
    UBX_FIX_2D = 2,
    UBX_FIX_3D = 3,
    UBX_FIX_GNSS_DEAD_RECKONING = 4,
    UBX_FIX_TIME_ONLY = 5,
} ubx_fix_type_t;

/** What a navigation filter takes of NAV-PVT, in the spec's units. */
typedef struct {
    uint32_t itow_ms;       /**< GPS time of week of the navigation epoch, ms */
    uint8_t fix_type;       /**< ubx_fix_type_t */
    uint8_t fix_ok;         /**< flags.gnssFixOK: the fix is within the receiver's accuracy masks */
    uint8_t num_sv;         /**< satellites used */
    int32_t lon_1e7deg;     /**< longitude, 1e-7 deg */
    int32_t lat_1e7deg;     /**< latitude, 1e-7 deg */
    int32_t height_mm;      /**< height above the WGS-84 ellipsoid, mm */
    int32_t hmsl_mm;        /**< height above mean sea level, mm */
    uint32_t h_acc_mm;      /**< horizontal accuracy estimate, mm */
    uint32_t v_acc_mm;      /**< vertical accuracy estimate, mm */
    int32_t vel_ned_mm_s[3]; /**< velocity north, east, down, mm/s */
    uint32_t s_acc_mm_s;    /**< speed accuracy estimate, mm/s */
    uint16_t p_dop_cent;    /**< position DOP, 0.01 */
} ubx_nav_pvt_t;

/** @brief Decode a NAV-PVT payload; 0 (and `out` untouched) unless `len` is UBX_NAV_PVT_LENGTH. */
int ubx_nav_pvt(const uint8_t *payload, uint16_t len, ubx_nav_pvt_t *out);

#endif /* UBX_H */
