/**
 * @file ubx.c
 * @brief UBX frames (see ubx.h).
 */
#include "ubx.h"

/** Where the next byte goes. */
enum { WAIT_SYNC_1, WAIT_SYNC_2, GET_CLASS, GET_ID, GET_LENGTH_LOW, GET_LENGTH_HIGH, GET_PAYLOAD, GET_CK_A, GET_CK_B };

void ubx_parser_init(ubx_parser_t *p)
{
    p->state = WAIT_SYNC_1;
    p->msg_class = p->msg_id = 0;
    p->length = p->received = 0;
    p->ck_a = p->ck_b = 0;
    p->frames = p->checksum_errors = p->oversized = p->skipped_bytes = 0;
}

static void checksum_add(ubx_parser_t *p, uint8_t byte)
{
    p->ck_a = (uint8_t)(p->ck_a + byte);
    p->ck_b = (uint8_t)(p->ck_b + p->ck_a);
}

/** A checksum byte that does not match: the frame is dropped, and `byte` may begin the next. */
static int checksum_failed(ubx_parser_t *p, uint8_t byte)
{
    ++p->checksum_errors;
    p->state = byte == UBX_SYNC_1 ? WAIT_SYNC_2 : WAIT_SYNC_1;
    return 0;
}

int ubx_parser_push(ubx_parser_t *p, uint8_t byte)
{
    switch (p->state) {
    case WAIT_SYNC_1:
        if (byte == UBX_SYNC_1) {
            p->state = WAIT_SYNC_2;
        } else {
            ++p->skipped_bytes;
        }
        return 0;
    case WAIT_SYNC_2:
        if (byte == UBX_SYNC_2) {
            p->state = GET_CLASS;
            p->ck_a = p->ck_b = 0;
        } else {
            p->skipped_bytes += 1u + (byte != UBX_SYNC_1); /* 0xB5 0xB5 0x62: the second one may start a frame */
            p->state = byte == UBX_SYNC_1 ? WAIT_SYNC_2 : WAIT_SYNC_1;
        }
        return 0;
    case GET_CLASS:
        p->msg_class = byte;
        checksum_add(p, byte);
        p->state = GET_ID;
        return 0;
    case GET_ID:
        p->msg_id = byte;
        checksum_add(p, byte);
        p->state = GET_LENGTH_LOW;
        return 0;
    case GET_LENGTH_LOW:
        p->length = byte;
        checksum_add(p, byte);
        p->state = GET_LENGTH_HIGH;
        return 0;
    case GET_LENGTH_HIGH:
        p->length = (uint16_t)(p->length | (byte << 8));
        checksum_add(p, byte);
        p->received = 0;
        if (p->length > UBX_MAX_PAYLOAD) {
            /* Not kept: look for the next frame (its bytes are skipped as garbage). */
            ++p->oversized;
            p->state = WAIT_SYNC_1;
        } else {
            p->state = p->length == 0 ? GET_CK_A : GET_PAYLOAD;
        }
        return 0;
    case GET_PAYLOAD:
        p->payload[p->received++] = byte;
        checksum_add(p, byte);
        if (p->received == p->length) {
            p->state = GET_CK_A;
        }
        return 0;
    case GET_CK_A:
        if (byte != p->ck_a) {
            return checksum_failed(p, byte);
        }
        p->state = GET_CK_B;
        return 0;
    default: /* GET_CK_B */
        if (byte != p->ck_b) {
            return checksum_failed(p, byte);
        }
        p->state = WAIT_SYNC_1;
        ++p->frames;
        return 1;
    }
}

uint8_t ubx_frame_class(const ubx_parser_t *p)
{
    return p->msg_class;
}

uint8_t ubx_frame_id(const ubx_parser_t *p)
{
    return p->msg_id;
}

const uint8_t *ubx_frame_payload(const ubx_parser_t *p, uint16_t *length)
{
    *length = p->length;
    return p->payload;
}

uint16_t ubx_checksum(const uint8_t *data, size_t len)
{
    uint8_t a = 0, b = 0;
    size_t i;
    for (i = 0; i < len; ++i) {
        a = (uint8_t)(a + data[i]);
        b = (uint8_t)(b + a);
    }
    return (uint16_t)(a | (b << 8));
}

size_t ubx_encode(uint8_t msg_class, uint8_t msg_id, const uint8_t *payload, uint16_t len, uint8_t *out,
                  size_t cap)
{
    uint16_t ck;
    size_t i;
    if (cap < (size_t)len + UBX_OVERHEAD) {
        return 0;
    }
    out[0] = UBX_SYNC_1;
    out[1] = UBX_SYNC_2;
    out[2] = msg_class;
    out[3] = msg_id;
    out[4] = (uint8_t)(len & 0xFFu);
    out[5] = (uint8_t)(len >> 8);
    for (i = 0; i < len; ++i) {
        out[6 + i] = payload[i];
    }
    ck = ubx_checksum(out + 2, (size_t)len + 4u);
    out[6 + len] = (uint8_t)(ck & 0xFFu);
    out[7 + len] = (uint8_t)(ck >> 8);
    return (size_t)len + UBX_OVERHEAD;
}

static uint32_t u32(const uint8_t *b)
{
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}

/** A little-endian two's-complement int32 without implementation-defined conversion. */
static int32_t i32(const uint8_t *b)
{
    const uint32_t v = u32(b);
    return v < 0x80000000u ? (int32_t)v : -(int32_t)(0xFFFFFFFFu - v) - 1;
}

int ubx_nav_pvt(const uint8_t *payload, uint16_t len, ubx_nav_pvt_t *out)
{
    /* Offsets: the spec's UBX-NAV-PVT payload table. */
    int k;
    if (len != UBX_NAV_PVT_LENGTH) {
        return 0;
    }
    out->itow_ms = u32(payload + 0);
    out->fix_type = payload[20];
    out->fix_ok = (uint8_t)(payload[21] & 0x01u);
    out->num_sv = payload[23];
    out->lon_1e7deg = i32(payload + 24);
    out->lat_1e7deg = i32(payload + 28);
    out->height_mm = i32(payload + 32);
    out->hmsl_mm = i32(payload + 36);
    out->h_acc_mm = u32(payload + 40);
    out->v_acc_mm = u32(payload + 44);
    for (k = 0; k < 3; ++k) {
        out->vel_ned_mm_s[k] = i32(payload + 48 + 4 * k);
    }
    out->s_acc_mm_s = u32(payload + 68);
    out->p_dop_cent = (uint16_t)(payload[76] | (payload[77] << 8));
    return 1;
}
