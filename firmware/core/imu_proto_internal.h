/**
 * @file imu_proto_internal.h
 * @brief What the hand-written codec (imu_proto.c) and the generated message code
 *        (imu_proto_gen.c) share: the little-endian helpers and the in-place frame
 *        encoder. Not part of the codec's API.
 */
#ifndef IMU_PROTO_INTERNAL_H
#define IMU_PROTO_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "imu_proto.h"

/* --------------------------------------------------------------------------- little endian */

/* On a little-endian target that reads and writes unaligned words (the Cortex-M4 does),
 * GCC moves a word at once through __builtin_memcpy; it does not merge the byte-wise
 * form below by itself (GCC 12: four loads and three shifts for one word). */
#if defined(__GNUC__) && defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
#define IMU_PROTO_NATIVE_LE 1
#else
#define IMU_PROTO_NATIVE_LE 0
#endif

static inline void put_u16(uint8_t *p, uint16_t v)
{
#if IMU_PROTO_NATIVE_LE
    __builtin_memcpy(p, &v, sizeof v);
#else
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
#endif
}

static inline void put_u32(uint8_t *p, uint32_t v)
{
#if IMU_PROTO_NATIVE_LE
    __builtin_memcpy(p, &v, sizeof v);
#else
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
#endif
}

static inline uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static inline uint32_t get_u32(const uint8_t *p)
{
#if IMU_PROTO_NATIVE_LE
    uint32_t v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
#else
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
#endif
}

/* --------------------------------------------------------------------------- in-place frames */

/** Longest frame (header + payload + CRC) encoded in place by imu_proto_frame_seal. */
#define IMU_PROTO_FRAME_IN_PLACE_MAX 253u
/** Where the messages' encoders pack a payload in the wire buffer: after the COBS code
 *  byte and the header. */
#define IMU_PROTO_FRAME_PAYLOAD_OFFSET (1u + IMU_PROTO_HEADER_SIZE)

/**
 * @brief The frame of a payload already at wire + IMU_PROTO_FRAME_PAYLOAD_OFFSET
 *        (payload_len bytes, the frame at most IMU_PROTO_FRAME_IN_PLACE_MAX), encoded in
 *        place; wire holds payload_len + IMU_PROTO_MIN_FRAME + 2 bytes (code byte and
 *        delimiter). Returns that length.
 */
size_t imu_proto_frame_seal(uint8_t msg_id, uint16_t seq, size_t payload_len, uint8_t *wire);

#endif /* IMU_PROTO_INTERNAL_H */
