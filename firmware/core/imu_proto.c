/**
 * @file imu_proto.c
 * @brief Frame protocol codec: COBS, frame builder, incremental decoder. The CRC-32 and
 *        the message pack/unpack/encode functions are generated from shared/protocol.toml
 *        by tools/gen_protocol.py into imu_proto_gen.c.
 */
#include "imu_proto.h"
#include "imu_proto_internal.h"

/* --------------------------------------------------------------------------- COBS encoding */

/* Streaming COBS encoder into a bounded buffer. A block holds up to 254 data
 * bytes after its code byte (code = data bytes + 1); a block that ends because of
 * a 0x00 in the input has code < 0xFF, a full block has code 0xFF and no zero. */
typedef struct {
    uint8_t *out;
    size_t cap;
    size_t pos;      /* where the next data byte goes */
    size_t code_pos; /* where the open block's code byte goes */
    uint8_t code;    /* 1 + data bytes in the open block */
    int overflow;    /* a byte did not fit in cap */
} cobs_writer_t;

static void cobs_write(cobs_writer_t *w, size_t at, uint8_t byte)
{
    if (at < w->cap) {
        w->out[at] = byte;
    } else {
        w->overflow = 1;
    }
}

static void cobs_start(cobs_writer_t *w, uint8_t *out, size_t cap)
{
    w->out = out;
    w->cap = cap;
    w->code_pos = 0;
    w->pos = 1;
    w->code = 1;
    w->overflow = 0;
}

static void cobs_close_block(cobs_writer_t *w)
{
    cobs_write(w, w->code_pos, w->code);
    w->code_pos = w->pos++;
    w->code = 1;
}

static void cobs_put(cobs_writer_t *w, uint8_t byte)
{
    if (w->code == 0xFFu) {
        /* the previous byte filled a block: open the next only now that more data follows */
        cobs_close_block(w);
    }
    if (byte == 0) {
        cobs_close_block(w);
        return;
    }
    cobs_write(w, w->pos++, byte);
    ++w->code;
}

static void cobs_put_all(cobs_writer_t *w, const uint8_t *data, size_t len)
{
    size_t i;
    for (i = 0; i < len; ++i) {
        cobs_put(w, data[i]);
    }
}

/* Closes the last block; the encoded length, or 0 when it did not fit. */
static size_t cobs_finish(cobs_writer_t *w)
{
    cobs_write(w, w->code_pos, w->code);
    return w->overflow ? 0 : w->pos;
}

size_t imu_proto_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap)
{
    cobs_writer_t w;
    cobs_start(&w, out, out_cap);
    cobs_put_all(&w, in, len);
    return cobs_finish(&w);
}

/*
 * The frame's bytes (header, payload, CRC) are laid out at wire + 1 and COBS-encoded in
 * place: each zero becomes the code byte of the block it ends (its distance to the next
 * zero or the end), wire[0] the first block's. That holds while no block reaches 254
 * data bytes (code 0xFF, a full block followed by an inserted code byte), i.e. for
 * frames up to 253 bytes (IMU_PROTO_FRAME_IN_PLACE_MAX), every message of the protocol
 * (IMU_PROTO_MAX_FRAME); longer ones take the streaming writer. The bytes are the same
 * either way. The messages' encoders (imu_proto_gen.c) pack their payload straight to
 * wire + 1 + IMU_PROTO_HEADER_SIZE (IMU_PROTO_FRAME_PAYLOAD_OFFSET); imu_proto_frame_seal
 * adds the header and the CRC and encodes: about 9 Cortex-M4 instructions per frame byte,
 * where the streaming writer after a CRC by nibbles took 34 (docs/performance.md).
 */

/** Index (0-3, lowest address first in get_u32's order) of the lowest byte of m with
 *  bit 7 set; m has only bits 7 of bytes set, at least one. */
static size_t lowest_marked_byte(uint32_t m)
{
#if defined(__GNUC__)
    return (size_t)__builtin_ctz(m) >> 3; /* RBIT and CLZ on the Cortex-M4 */
#else
    size_t k = 0;
    while ((m & 0x80u) == 0) {
        m >>= 8;
        ++k;
    }
    return k;
#endif
}

size_t imu_proto_frame_seal(uint8_t msg_id, uint16_t seq, size_t payload_len, uint8_t *wire)
{
    const size_t len = IMU_PROTO_HEADER_SIZE + payload_len + IMU_PROTO_CRC_SIZE;
    uint8_t *p = wire + 1;
    uint8_t *const end = wire + 1 + len;
    uint8_t *code = wire;
    size_t words;
    wire[1] = msg_id;
    put_u16(wire + 2, seq);
    put_u32(wire + IMU_PROTO_FRAME_PAYLOAD_OFFSET + payload_len,
            imu_proto_crc32(0, wire + 1, IMU_PROTO_HEADER_SIZE + payload_len));
    /* Four bytes at a time: bit 7 of each byte of `zeros` is set exactly where v has a
     * zero byte ((b & 0x7F) + 0x7F carries into bit 7 unless b & 0x7F is zero, and no
     * byte carries into the next); the zeros are then taken lowest address first. */
    for (words = len / 4u; words != 0; --words, p += 4) {
        const uint32_t v = get_u32(p);
        uint32_t zeros = ~(((v & 0x7F7F7F7Fu) + 0x7F7F7F7Fu) | v | 0x7F7F7F7Fu);
        while (zeros != 0) {
            uint8_t *z = p + lowest_marked_byte(zeros);
            *code = (uint8_t)(z - code); /* below 254 */
            code = z;
            zeros &= zeros - 1u;
        }
    }
    for (; p != end; ++p) {
        if (*p == 0) {
            *code = (uint8_t)(p - code);
            code = p;
        }
    }
    *code = (uint8_t)(end - code);
    wire[len + 1] = 0;
    return len + 2;
}

size_t imu_proto_frame_encode(uint8_t msg_id, uint16_t seq, const uint8_t *payload, size_t payload_len,
                              uint8_t *wire, size_t wire_cap)
{
    uint8_t header[IMU_PROTO_HEADER_SIZE];
    uint8_t crc[IMU_PROTO_CRC_SIZE];
    cobs_writer_t w;
    size_t n;
    if (wire_cap == 0) {
        return 0;
    }
    if (payload_len <= IMU_PROTO_FRAME_IN_PLACE_MAX - IMU_PROTO_MIN_FRAME &&
        payload_len + IMU_PROTO_MIN_FRAME + 2u <= wire_cap) {
        size_t i;
        for (i = 0; i < payload_len; ++i) {
            wire[IMU_PROTO_FRAME_PAYLOAD_OFFSET + i] = payload[i];
        }
        return imu_proto_frame_seal(msg_id, seq, payload_len, wire);
    }
    header[0] = msg_id;
    put_u16(header + 1, seq);
    put_u32(crc, imu_proto_crc32(imu_proto_crc32(0, header, sizeof header), payload, payload_len));
    cobs_start(&w, wire, wire_cap - 1); /* the last byte is kept for the delimiter */
    cobs_put_all(&w, header, sizeof header);
    cobs_put_all(&w, payload, payload_len);
    cobs_put_all(&w, crc, sizeof crc);
    n = cobs_finish(&w);
    if (n == 0) {
        return 0;
    }
    wire[n] = 0;
    return n + 1;
}

/* --------------------------------------------------------------------------- COBS decoding */

static void span_restart(imu_proto_decoder_t *d)
{
    d->len = 0;
    d->span = 0;
    d->remaining = 0;
    d->zero_pending = 0;
    d->overflow = 0;
}

static void emit(imu_proto_decoder_t *d, uint8_t byte)
{
    if (d->len < d->cap) {
        d->buf[d->len++] = byte;
    } else {
        d->overflow = 1;
    }
}

/* One non-zero wire byte of the current span: a code byte when the previous block
 * is complete, a data byte otherwise. The zero that ends a block is written only
 * when the next block starts, so the implicit zero at the end of a frame never is. */
static void cobs_step(imu_proto_decoder_t *d, uint8_t byte)
{
    ++d->span;
    if (d->remaining == 0) {
        if (d->zero_pending) {
            emit(d, 0);
        }
        d->remaining = (uint8_t)(byte - 1u);
        d->zero_pending = byte != 0xFFu;
    } else {
        emit(d, byte);
        --d->remaining;
    }
}

imu_proto_result_t imu_proto_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap,
                                         size_t *out_len)
{
    imu_proto_decoder_t d;
    size_t i;
    imu_proto_decoder_init(&d, out, out_cap);
    if (len == 0) {
        return IMU_PROTO_ERR_COBS;
    }
    for (i = 0; i < len; ++i) {
        if (in[i] == 0) {
            return IMU_PROTO_ERR_COBS;
        }
        cobs_step(&d, in[i]);
    }
    if (d.remaining != 0) {
        return IMU_PROTO_ERR_COBS;
    }
    if (d.overflow) {
        return IMU_PROTO_ERR_SPACE;
    }
    *out_len = d.len;
    return IMU_PROTO_OK;
}

/* --------------------------------------------------------------------------- frame decoder */

void imu_proto_decoder_init(imu_proto_decoder_t *d, uint8_t *buf, size_t cap)
{
    d->buf = buf;
    d->cap = cap;
    d->bytes = 0;
    d->frames = 0;
    d->crc_errors = 0;
    d->resyncs = 0;
    d->oversize = 0;
    span_restart(d);
}

int imu_proto_decoder_push(imu_proto_decoder_t *d, uint8_t byte, imu_proto_frame_t *frame)
{
    int complete = 0;
    ++d->bytes;
    if (byte != 0) {
        cobs_step(d, byte);
        return 0;
    }
    if (d->span == 0) {
        return 0; /* two delimiters in a row: nothing in between */
    }
    if (d->overflow) {
        ++d->oversize;
        ++d->resyncs;
    } else if (d->remaining != 0 || d->len < IMU_PROTO_MIN_FRAME) {
        ++d->resyncs;
    } else if (imu_proto_crc32(0, d->buf, d->len - IMU_PROTO_CRC_SIZE) !=
               get_u32(d->buf + d->len - IMU_PROTO_CRC_SIZE)) {
        ++d->crc_errors;
    } else {
        frame->msg_id = d->buf[0];
        frame->seq = get_u16(d->buf + 1);
        frame->payload = d->buf + IMU_PROTO_HEADER_SIZE;
        frame->payload_len = d->len - IMU_PROTO_MIN_FRAME;
        ++d->frames;
        complete = 1;
    }
    span_restart(d);
    return complete;
}
