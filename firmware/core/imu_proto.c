/**
 * @file imu_proto.c
 * @brief Frame protocol codec: COBS, frame builder, incremental decoder (written by
 *        hand), the CRC-32 and the message pack/unpack functions (generated from
 *        shared/protocol.toml by tools/gen_protocol.py, at the end of this file).
 */
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

static void put_u16(uint8_t *p, uint16_t v)
{
#if IMU_PROTO_NATIVE_LE
    __builtin_memcpy(p, &v, sizeof v);
#else
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
#endif
}

static void put_u32(uint8_t *p, uint32_t v)
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

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
#if IMU_PROTO_NATIVE_LE
    uint32_t v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
#else
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
#endif
}

/* The CRC-32 (imu_proto_crc32) is generated with its table, in the generated section. */

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
 * frames up to 253 bytes (FRAME_IN_PLACE_MAX), every message of the protocol
 * (IMU_PROTO_MAX_FRAME); longer ones take the streaming writer. The bytes are the same
 * either way. The messages' encoders pack their payload straight to wire + 1 +
 * IMU_PROTO_HEADER_SIZE (FRAME_PAYLOAD_OFFSET); frame_seal adds the header and the CRC
 * and encodes: about 9 Cortex-M4 instructions per frame byte, where the streaming writer
 * after a CRC by nibbles took 34 (docs/performance.md).
 */
#define FRAME_IN_PLACE_MAX 253u
#define FRAME_PAYLOAD_OFFSET (1u + IMU_PROTO_HEADER_SIZE)

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

/** The frame of a payload already at wire + FRAME_PAYLOAD_OFFSET (payload_len bytes, the
 *  frame at most FRAME_IN_PLACE_MAX), encoded in place; wire holds payload_len +
 *  IMU_PROTO_MIN_FRAME + 2 bytes (code byte and delimiter). Returns that length. */
static size_t frame_seal(uint8_t msg_id, uint16_t seq, size_t payload_len, uint8_t *wire)
{
    const size_t len = IMU_PROTO_HEADER_SIZE + payload_len + IMU_PROTO_CRC_SIZE;
    uint8_t *p = wire + 1;
    uint8_t *const end = wire + 1 + len;
    uint8_t *code = wire;
    size_t words;
    wire[1] = msg_id;
    put_u16(wire + 2, seq);
    put_u32(wire + FRAME_PAYLOAD_OFFSET + payload_len,
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
    if (payload_len <= FRAME_IN_PLACE_MAX - IMU_PROTO_MIN_FRAME &&
        payload_len + IMU_PROTO_MIN_FRAME + 2u <= wire_cap) {
        size_t i;
        for (i = 0; i < payload_len; ++i) {
            wire[FRAME_PAYLOAD_OFFSET + i] = payload[i];
        }
        return frame_seal(msg_id, seq, payload_len, wire);
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

/* --------------------------------------------------------------------------- messages */

/* BEGIN GENERATED by tools/gen_protocol.py from shared/protocol.toml: do not edit by hand */
/* CRC-32 of each byte value for the reflected polynomial 0xEDB88320. */
static const uint32_t crc32_table[256] = {
    0x00000000u, 0x77073096u, 0xEE0E612Cu, 0x990951BAu, 0x076DC419u, 0x706AF48Fu,
    0xE963A535u, 0x9E6495A3u, 0x0EDB8832u, 0x79DCB8A4u, 0xE0D5E91Eu, 0x97D2D988u,
    0x09B64C2Bu, 0x7EB17CBDu, 0xE7B82D07u, 0x90BF1D91u, 0x1DB71064u, 0x6AB020F2u,
    0xF3B97148u, 0x84BE41DEu, 0x1ADAD47Du, 0x6DDDE4EBu, 0xF4D4B551u, 0x83D385C7u,
    0x136C9856u, 0x646BA8C0u, 0xFD62F97Au, 0x8A65C9ECu, 0x14015C4Fu, 0x63066CD9u,
    0xFA0F3D63u, 0x8D080DF5u, 0x3B6E20C8u, 0x4C69105Eu, 0xD56041E4u, 0xA2677172u,
    0x3C03E4D1u, 0x4B04D447u, 0xD20D85FDu, 0xA50AB56Bu, 0x35B5A8FAu, 0x42B2986Cu,
    0xDBBBC9D6u, 0xACBCF940u, 0x32D86CE3u, 0x45DF5C75u, 0xDCD60DCFu, 0xABD13D59u,
    0x26D930ACu, 0x51DE003Au, 0xC8D75180u, 0xBFD06116u, 0x21B4F4B5u, 0x56B3C423u,
    0xCFBA9599u, 0xB8BDA50Fu, 0x2802B89Eu, 0x5F058808u, 0xC60CD9B2u, 0xB10BE924u,
    0x2F6F7C87u, 0x58684C11u, 0xC1611DABu, 0xB6662D3Du, 0x76DC4190u, 0x01DB7106u,
    0x98D220BCu, 0xEFD5102Au, 0x71B18589u, 0x06B6B51Fu, 0x9FBFE4A5u, 0xE8B8D433u,
    0x7807C9A2u, 0x0F00F934u, 0x9609A88Eu, 0xE10E9818u, 0x7F6A0DBBu, 0x086D3D2Du,
    0x91646C97u, 0xE6635C01u, 0x6B6B51F4u, 0x1C6C6162u, 0x856530D8u, 0xF262004Eu,
    0x6C0695EDu, 0x1B01A57Bu, 0x8208F4C1u, 0xF50FC457u, 0x65B0D9C6u, 0x12B7E950u,
    0x8BBEB8EAu, 0xFCB9887Cu, 0x62DD1DDFu, 0x15DA2D49u, 0x8CD37CF3u, 0xFBD44C65u,
    0x4DB26158u, 0x3AB551CEu, 0xA3BC0074u, 0xD4BB30E2u, 0x4ADFA541u, 0x3DD895D7u,
    0xA4D1C46Du, 0xD3D6F4FBu, 0x4369E96Au, 0x346ED9FCu, 0xAD678846u, 0xDA60B8D0u,
    0x44042D73u, 0x33031DE5u, 0xAA0A4C5Fu, 0xDD0D7CC9u, 0x5005713Cu, 0x270241AAu,
    0xBE0B1010u, 0xC90C2086u, 0x5768B525u, 0x206F85B3u, 0xB966D409u, 0xCE61E49Fu,
    0x5EDEF90Eu, 0x29D9C998u, 0xB0D09822u, 0xC7D7A8B4u, 0x59B33D17u, 0x2EB40D81u,
    0xB7BD5C3Bu, 0xC0BA6CADu, 0xEDB88320u, 0x9ABFB3B6u, 0x03B6E20Cu, 0x74B1D29Au,
    0xEAD54739u, 0x9DD277AFu, 0x04DB2615u, 0x73DC1683u, 0xE3630B12u, 0x94643B84u,
    0x0D6D6A3Eu, 0x7A6A5AA8u, 0xE40ECF0Bu, 0x9309FF9Du, 0x0A00AE27u, 0x7D079EB1u,
    0xF00F9344u, 0x8708A3D2u, 0x1E01F268u, 0x6906C2FEu, 0xF762575Du, 0x806567CBu,
    0x196C3671u, 0x6E6B06E7u, 0xFED41B76u, 0x89D32BE0u, 0x10DA7A5Au, 0x67DD4ACCu,
    0xF9B9DF6Fu, 0x8EBEEFF9u, 0x17B7BE43u, 0x60B08ED5u, 0xD6D6A3E8u, 0xA1D1937Eu,
    0x38D8C2C4u, 0x4FDFF252u, 0xD1BB67F1u, 0xA6BC5767u, 0x3FB506DDu, 0x48B2364Bu,
    0xD80D2BDAu, 0xAF0A1B4Cu, 0x36034AF6u, 0x41047A60u, 0xDF60EFC3u, 0xA867DF55u,
    0x316E8EEFu, 0x4669BE79u, 0xCB61B38Cu, 0xBC66831Au, 0x256FD2A0u, 0x5268E236u,
    0xCC0C7795u, 0xBB0B4703u, 0x220216B9u, 0x5505262Fu, 0xC5BA3BBEu, 0xB2BD0B28u,
    0x2BB45A92u, 0x5CB36A04u, 0xC2D7FFA7u, 0xB5D0CF31u, 0x2CD99E8Bu, 0x5BDEAE1Du,
    0x9B64C2B0u, 0xEC63F226u, 0x756AA39Cu, 0x026D930Au, 0x9C0906A9u, 0xEB0E363Fu,
    0x72076785u, 0x05005713u, 0x95BF4A82u, 0xE2B87A14u, 0x7BB12BAEu, 0x0CB61B38u,
    0x92D28E9Bu, 0xE5D5BE0Du, 0x7CDCEFB7u, 0x0BDBDF21u, 0x86D3D2D4u, 0xF1D4E242u,
    0x68DDB3F8u, 0x1FDA836Eu, 0x81BE16CDu, 0xF6B9265Bu, 0x6FB077E1u, 0x18B74777u,
    0x88085AE6u, 0xFF0F6A70u, 0x66063BCAu, 0x11010B5Cu, 0x8F659EFFu, 0xF862AE69u,
    0x616BFFD3u, 0x166CCF45u, 0xA00AE278u, 0xD70DD2EEu, 0x4E048354u, 0x3903B3C2u,
    0xA7672661u, 0xD06016F7u, 0x4969474Du, 0x3E6E77DBu, 0xAED16A4Au, 0xD9D65ADCu,
    0x40DF0B66u, 0x37D83BF0u, 0xA9BCAE53u, 0xDEBB9EC5u, 0x47B2CF7Fu, 0x30B5FFE9u,
    0xBDBDF21Cu, 0xCABAC28Au, 0x53B39330u, 0x24B4A3A6u, 0xBAD03605u, 0xCDD70693u,
    0x54DE5729u, 0x23D967BFu, 0xB3667A2Eu, 0xC4614AB8u, 0x5D681B02u, 0x2A6F2B94u,
    0xB40BBE37u, 0xC30C8EA1u, 0x5A05DF1Bu, 0x2D02EF8Du,
};

uint32_t imu_proto_crc32(uint32_t crc, const uint8_t *data, size_t len)
{
    size_t words;
    size_t i;
    crc = ~crc;
    /* Four bytes at a time: the reflected CRC takes them as one little-endian word,
     * then four table steps. */
    for (words = len / 4u; words != 0; --words, data += 4) {
        crc ^= get_u32(data);
        crc = (crc >> 8) ^ crc32_table[crc & 0xFFu];
        crc = (crc >> 8) ^ crc32_table[crc & 0xFFu];
        crc = (crc >> 8) ^ crc32_table[crc & 0xFFu];
        crc = (crc >> 8) ^ crc32_table[crc & 0xFFu];
    }
    for (i = 0; i < len % 4u; ++i) {
        crc = (crc >> 8) ^ crc32_table[(crc ^ data[i]) & 0xFFu];
    }
    return ~crc;
}

/* Two's-complement uint8_t to int8_t, without an implementation-defined conversion. */
static int8_t to_i8(uint8_t u)
{
    return u < 0x80u ? (int8_t)u : (int8_t)(-(int32_t)((uint8_t)~u) - 1);
}

/* Two's-complement uint16_t to int16_t, without an implementation-defined conversion. */
static int16_t to_i16(uint16_t u)
{
    return u < 0x8000u ? (int16_t)u : (int16_t)(-(int32_t)((uint16_t)~u) - 1);
}

/* Two's-complement uint32_t to int32_t, without an implementation-defined conversion. */
static int32_t to_i32(uint32_t u)
{
    return u < 0x80000000u ? (int32_t)u : (int32_t)(-(int32_t)(~u) - 1);
}

size_t imu_proto_hello_pack(const imu_proto_hello_t *m, uint8_t *payload)
{
    size_t i;
    payload[0] = (uint8_t)m->firmware_major;
    payload[1] = (uint8_t)m->firmware_minor;
    payload[2] = (uint8_t)m->firmware_patch;
    payload[3] = (uint8_t)m->protocol_version;
    put_u32(payload + 4, (uint32_t)m->schema_hash);
    for (i = 0; i < 16; ++i) {
        payload[8 + i] = ((const unsigned char *)m->board)[i];
    }
    payload[24] = (uint8_t)m->filters;
    put_u32(payload + 25, (uint32_t)m->gyro_scale);
    put_u32(payload + 29, (uint32_t)m->acc_scale);
    put_u32(payload + 33, (uint32_t)m->mag_scale);
    return IMU_PROTO_HELLO_SIZE;
}

imu_proto_result_t imu_proto_hello_unpack(imu_proto_hello_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_HELLO_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->firmware_major = payload[0];
    m->firmware_minor = payload[1];
    m->firmware_patch = payload[2];
    m->protocol_version = payload[3];
    m->schema_hash = get_u32(payload + 4);
    for (i = 0; i < 16; ++i) {
        ((unsigned char *)m->board)[i] = payload[8 + i];
    }
    m->filters = payload[24];
    m->gyro_scale = to_i32(get_u32(payload + 25));
    m->acc_scale = to_i32(get_u32(payload + 29));
    m->mag_scale = to_i32(get_u32(payload + 33));
    return IMU_PROTO_OK;
}

size_t imu_proto_hello_encode(const imu_proto_hello_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_HELLO_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_hello_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_HELLO, seq, IMU_PROTO_HELLO_SIZE, wire);
}

size_t imu_proto_status_pack(const imu_proto_status_t *m, uint8_t *payload)
{
    put_u32(payload + 0, (uint32_t)m->uptime_ms);
    payload[4] = (uint8_t)m->active_filter;
    put_u32(payload + 5, (uint32_t)m->sample_rate_mhz);
    put_u32(payload + 9, (uint32_t)m->dropped_samples);
    put_u16(payload + 13, (uint16_t)m->cpu_load_permille);
    put_u32(payload + 15, (uint32_t)m->filter_saturations);
    put_u32(payload + 19, (uint32_t)m->sensor_saturations);
    payload[23] = (uint8_t)m->streaming;
    payload[24] = (uint8_t)m->injection_mode;
    put_u32(payload + 25, (uint32_t)m->filter_cycles);
    put_u32(payload + 29, (uint32_t)m->cycle_hz);
    put_u32(payload + 33, (uint32_t)m->sensor_errors);
    return IMU_PROTO_STATUS_SIZE;
}

imu_proto_result_t imu_proto_status_unpack(imu_proto_status_t *m, const uint8_t *payload, size_t len)
{
    if (len != IMU_PROTO_STATUS_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->uptime_ms = get_u32(payload + 0);
    m->active_filter = payload[4];
    m->sample_rate_mhz = get_u32(payload + 5);
    m->dropped_samples = get_u32(payload + 9);
    m->cpu_load_permille = get_u16(payload + 13);
    m->filter_saturations = get_u32(payload + 15);
    m->sensor_saturations = get_u32(payload + 19);
    m->streaming = payload[23];
    m->injection_mode = payload[24];
    m->filter_cycles = get_u32(payload + 25);
    m->cycle_hz = get_u32(payload + 29);
    m->sensor_errors = get_u32(payload + 33);
    return IMU_PROTO_OK;
}

size_t imu_proto_status_encode(const imu_proto_status_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_STATUS_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_status_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_STATUS, seq, IMU_PROTO_STATUS_SIZE, wire);
}

size_t imu_proto_log_pack(const imu_proto_log_t *m, uint8_t *payload)
{
    size_t i;
    if (m->text_len > 200u) {
        return 0;
    }
    payload[0] = (uint8_t)m->level;
    for (i = 0; i < m->text_len; ++i) {
        payload[1 + i] = ((const unsigned char *)m->text)[i];
    }
    return 1u + m->text_len;
}

imu_proto_result_t imu_proto_log_unpack(imu_proto_log_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len < 1u || len > IMU_PROTO_LOG_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->level = payload[0];
    m->text_len = len - 1u;
    for (i = 0; i < m->text_len; ++i) {
        ((unsigned char *)m->text)[i] = payload[1 + i];
    }
    return IMU_PROTO_OK;
}

size_t imu_proto_log_encode(const imu_proto_log_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    uint8_t payload[IMU_PROTO_LOG_SIZE];
    size_t len = imu_proto_log_pack(m, payload);
    if (len == 0) {
        return 0;
    }
    return imu_proto_frame_encode(IMU_PROTO_MSG_LOG, seq, payload, len, wire, wire_cap);
}

size_t imu_proto_ack_pack(const imu_proto_ack_t *m, uint8_t *payload)
{
    put_u16(payload + 0, (uint16_t)m->command_seq);
    payload[2] = (uint8_t)m->command;
    payload[3] = (uint8_t)m->reason;
    return IMU_PROTO_ACK_SIZE;
}

imu_proto_result_t imu_proto_ack_unpack(imu_proto_ack_t *m, const uint8_t *payload, size_t len)
{
    if (len != IMU_PROTO_ACK_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->command_seq = get_u16(payload + 0);
    m->command = payload[2];
    m->reason = payload[3];
    return IMU_PROTO_OK;
}

size_t imu_proto_ack_encode(const imu_proto_ack_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_ACK_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_ack_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_ACK, seq, IMU_PROTO_ACK_SIZE, wire);
}

size_t imu_proto_nack_pack(const imu_proto_nack_t *m, uint8_t *payload)
{
    put_u16(payload + 0, (uint16_t)m->command_seq);
    payload[2] = (uint8_t)m->command;
    payload[3] = (uint8_t)m->reason;
    return IMU_PROTO_NACK_SIZE;
}

imu_proto_result_t imu_proto_nack_unpack(imu_proto_nack_t *m, const uint8_t *payload, size_t len)
{
    if (len != IMU_PROTO_NACK_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->command_seq = get_u16(payload + 0);
    m->command = payload[2];
    m->reason = payload[3];
    return IMU_PROTO_OK;
}

size_t imu_proto_nack_encode(const imu_proto_nack_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_NACK_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_nack_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_NACK, seq, IMU_PROTO_NACK_SIZE, wire);
}

size_t imu_proto_setting_pack(const imu_proto_setting_t *m, uint8_t *payload)
{
    size_t i;
    payload[0] = (uint8_t)m->filter_id;
    payload[1] = (uint8_t)m->index;
    payload[2] = (uint8_t)m->setting_count;
    put_u32(payload + 3, (uint32_t)m->value);
    payload[7] = (uint8_t)m->frac_bits;
    for (i = 0; i < 24; ++i) {
        payload[8 + i] = ((const unsigned char *)m->name)[i];
    }
    for (i = 0; i < 12; ++i) {
        payload[32 + i] = ((const unsigned char *)m->unit)[i];
    }
    put_u32(payload + 44, (uint32_t)m->min);
    put_u32(payload + 48, (uint32_t)m->max);
    return IMU_PROTO_SETTING_SIZE;
}

imu_proto_result_t imu_proto_setting_unpack(imu_proto_setting_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_SETTING_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->filter_id = payload[0];
    m->index = payload[1];
    m->setting_count = payload[2];
    m->value = to_i32(get_u32(payload + 3));
    m->frac_bits = to_i8(payload[7]);
    for (i = 0; i < 24; ++i) {
        ((unsigned char *)m->name)[i] = payload[8 + i];
    }
    for (i = 0; i < 12; ++i) {
        ((unsigned char *)m->unit)[i] = payload[32 + i];
    }
    m->min = to_i32(get_u32(payload + 44));
    m->max = to_i32(get_u32(payload + 48));
    return IMU_PROTO_OK;
}

size_t imu_proto_setting_encode(const imu_proto_setting_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_SETTING_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_setting_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_SETTING, seq, IMU_PROTO_SETTING_SIZE, wire);
}

size_t imu_proto_calibration_pack(const imu_proto_calibration_t *m, uint8_t *payload)
{
    size_t i;
    payload[0] = (uint8_t)m->sensor;
    payload[1] = (uint8_t)m->axis;
    put_u32(payload + 2, (uint32_t)m->offset);
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 6 + 4 * i, (uint32_t)m->row[i]);
    }
    payload[18] = (uint8_t)m->offset_frac_bits;
    payload[19] = (uint8_t)m->matrix_frac_bits;
    return IMU_PROTO_CALIBRATION_SIZE;
}

imu_proto_result_t imu_proto_calibration_unpack(imu_proto_calibration_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_CALIBRATION_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->sensor = payload[0];
    m->axis = payload[1];
    m->offset = to_i32(get_u32(payload + 2));
    for (i = 0; i < 3; ++i) {
        m->row[i] = to_i32(get_u32(payload + 6 + 4 * i));
    }
    m->offset_frac_bits = to_i8(payload[18]);
    m->matrix_frac_bits = to_i8(payload[19]);
    return IMU_PROTO_OK;
}

size_t imu_proto_calibration_encode(const imu_proto_calibration_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_CALIBRATION_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_calibration_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_CALIBRATION, seq, IMU_PROTO_CALIBRATION_SIZE, wire);
}

size_t imu_proto_sample_pack(const imu_proto_sample_t *m, uint8_t *payload)
{
    size_t i;
    put_u32(payload + 0, (uint32_t)m->timestamp_us);
    put_u32(payload + 4, (uint32_t)m->index);
    for (i = 0; i < 3; ++i) {
        put_u16(payload + 8 + 2 * i, (uint16_t)m->gyr[i]);
    }
    for (i = 0; i < 3; ++i) {
        put_u16(payload + 14 + 2 * i, (uint16_t)m->acc[i]);
    }
    for (i = 0; i < 3; ++i) {
        put_u16(payload + 20 + 2 * i, (uint16_t)m->mag[i]);
    }
    put_u16(payload + 26, (uint16_t)m->temperature);
    return IMU_PROTO_SAMPLE_SIZE;
}

imu_proto_result_t imu_proto_sample_unpack(imu_proto_sample_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_SAMPLE_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->timestamp_us = get_u32(payload + 0);
    m->index = get_u32(payload + 4);
    for (i = 0; i < 3; ++i) {
        m->gyr[i] = to_i16(get_u16(payload + 8 + 2 * i));
    }
    for (i = 0; i < 3; ++i) {
        m->acc[i] = to_i16(get_u16(payload + 14 + 2 * i));
    }
    for (i = 0; i < 3; ++i) {
        m->mag[i] = to_i16(get_u16(payload + 20 + 2 * i));
    }
    m->temperature = to_i16(get_u16(payload + 26));
    return IMU_PROTO_OK;
}

size_t imu_proto_sample_encode(const imu_proto_sample_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_SAMPLE_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_sample_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_SAMPLE, seq, IMU_PROTO_SAMPLE_SIZE, wire);
}

size_t imu_proto_estimate_pack(const imu_proto_estimate_t *m, uint8_t *payload)
{
    size_t i;
    put_u32(payload + 0, (uint32_t)m->index);
    payload[4] = (uint8_t)m->filter_id;
    for (i = 0; i < 4; ++i) {
        put_u32(payload + 5 + 4 * i, (uint32_t)m->quat[i]);
    }
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 21 + 4 * i, (uint32_t)m->gyro_bias[i]);
    }
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 33 + 4 * i, (uint32_t)m->euler[i]);
    }
    for (i = 0; i < 9; ++i) {
        put_u32(payload + 45 + 4 * i, (uint32_t)m->cov_mantissa[i]);
    }
    for (i = 0; i < 9; ++i) {
        payload[81 + i] = (uint8_t)m->cov_exponent[i];
    }
    put_u32(payload + 90, (uint32_t)m->saturations);
    for (i = 0; i < 2; ++i) {
        put_u32(payload + 94 + 4 * i, (uint32_t)m->weights[i]);
    }
    return IMU_PROTO_ESTIMATE_SIZE;
}

imu_proto_result_t imu_proto_estimate_unpack(imu_proto_estimate_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_ESTIMATE_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->index = get_u32(payload + 0);
    m->filter_id = payload[4];
    for (i = 0; i < 4; ++i) {
        m->quat[i] = to_i32(get_u32(payload + 5 + 4 * i));
    }
    for (i = 0; i < 3; ++i) {
        m->gyro_bias[i] = to_i32(get_u32(payload + 21 + 4 * i));
    }
    for (i = 0; i < 3; ++i) {
        m->euler[i] = to_i32(get_u32(payload + 33 + 4 * i));
    }
    for (i = 0; i < 9; ++i) {
        m->cov_mantissa[i] = to_i32(get_u32(payload + 45 + 4 * i));
    }
    for (i = 0; i < 9; ++i) {
        m->cov_exponent[i] = to_i8(payload[81 + i]);
    }
    m->saturations = get_u32(payload + 90);
    for (i = 0; i < 2; ++i) {
        m->weights[i] = to_i32(get_u32(payload + 94 + 4 * i));
    }
    return IMU_PROTO_OK;
}

size_t imu_proto_estimate_encode(const imu_proto_estimate_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_ESTIMATE_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_estimate_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_ESTIMATE, seq, IMU_PROTO_ESTIMATE_SIZE, wire);
}

size_t imu_proto_baro_pack(const imu_proto_baro_t *m, uint8_t *payload)
{
    put_u32(payload + 0, (uint32_t)m->timestamp_us);
    put_u32(payload + 4, (uint32_t)m->index);
    put_u32(payload + 8, (uint32_t)m->d1);
    put_u32(payload + 12, (uint32_t)m->d2);
    put_u32(payload + 16, (uint32_t)m->pressure_pa);
    put_u32(payload + 20, (uint32_t)m->temperature_cdeg);
    return IMU_PROTO_BARO_SIZE;
}

imu_proto_result_t imu_proto_baro_unpack(imu_proto_baro_t *m, const uint8_t *payload, size_t len)
{
    if (len != IMU_PROTO_BARO_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->timestamp_us = get_u32(payload + 0);
    m->index = get_u32(payload + 4);
    m->d1 = get_u32(payload + 8);
    m->d2 = get_u32(payload + 12);
    m->pressure_pa = to_i32(get_u32(payload + 16));
    m->temperature_cdeg = to_i32(get_u32(payload + 20));
    return IMU_PROTO_OK;
}

size_t imu_proto_baro_encode(const imu_proto_baro_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_BARO_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_baro_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_BARO, seq, IMU_PROTO_BARO_SIZE, wire);
}

size_t imu_proto_gnss_pack(const imu_proto_gnss_t *m, uint8_t *payload)
{
    size_t i;
    put_u32(payload + 0, (uint32_t)m->timestamp_us);
    put_u32(payload + 4, (uint32_t)m->index);
    put_u32(payload + 8, (uint32_t)m->time_ms);
    payload[12] = (uint8_t)m->fix_type;
    payload[13] = (uint8_t)m->fix_ok;
    payload[14] = (uint8_t)m->num_sv;
    payload[15] = (uint8_t)m->has_velocity;
    put_u32(payload + 16, (uint32_t)m->lat_1e7deg);
    put_u32(payload + 20, (uint32_t)m->lon_1e7deg);
    put_u32(payload + 24, (uint32_t)m->height_mm);
    put_u32(payload + 28, (uint32_t)m->h_acc_mm);
    put_u32(payload + 32, (uint32_t)m->v_acc_mm);
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 36 + 4 * i, (uint32_t)m->vel_ned_mm_s[i]);
    }
    put_u32(payload + 48, (uint32_t)m->s_acc_mm_s);
    return IMU_PROTO_GNSS_SIZE;
}

imu_proto_result_t imu_proto_gnss_unpack(imu_proto_gnss_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_GNSS_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->timestamp_us = get_u32(payload + 0);
    m->index = get_u32(payload + 4);
    m->time_ms = get_u32(payload + 8);
    m->fix_type = payload[12];
    m->fix_ok = payload[13];
    m->num_sv = payload[14];
    m->has_velocity = payload[15];
    m->lat_1e7deg = to_i32(get_u32(payload + 16));
    m->lon_1e7deg = to_i32(get_u32(payload + 20));
    m->height_mm = to_i32(get_u32(payload + 24));
    m->h_acc_mm = get_u32(payload + 28);
    m->v_acc_mm = get_u32(payload + 32);
    for (i = 0; i < 3; ++i) {
        m->vel_ned_mm_s[i] = to_i32(get_u32(payload + 36 + 4 * i));
    }
    m->s_acc_mm_s = get_u32(payload + 48);
    return IMU_PROTO_OK;
}

size_t imu_proto_gnss_encode(const imu_proto_gnss_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_GNSS_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_gnss_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_GNSS, seq, IMU_PROTO_GNSS_SIZE, wire);
}

size_t imu_proto_nav_state_pack(const imu_proto_nav_state_t *m, uint8_t *payload)
{
    size_t i;
    put_u32(payload + 0, (uint32_t)m->index);
    payload[4] = (uint8_t)m->mode;
    put_u32(payload + 5, (uint32_t)m->lat);
    put_u32(payload + 9, (uint32_t)m->lon);
    put_u32(payload + 13, (uint32_t)m->height_mm);
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 17 + 4 * i, (uint32_t)m->vel[i]);
    }
    for (i = 0; i < 3; ++i) {
        put_u32(payload + 29 + 4 * i, (uint32_t)m->acc_bias[i]);
    }
    put_u32(payload + 41, (uint32_t)m->baro_bias_mm);
    for (i = 0; i < 16; ++i) {
        put_u32(payload + 45 + 4 * i, (uint32_t)m->var_mantissa[i]);
    }
    for (i = 0; i < 16; ++i) {
        payload[109 + i] = (uint8_t)m->var_exponent[i];
    }
    put_u32(payload + 125, (uint32_t)m->since_fix);
    put_u32(payload + 129, (uint32_t)m->rejected);
    put_u32(payload + 133, (uint32_t)m->zero_velocity);
    put_u32(payload + 137, (uint32_t)m->resets);
    put_u32(payload + 141, (uint32_t)m->fades);
    return IMU_PROTO_NAV_STATE_SIZE;
}

imu_proto_result_t imu_proto_nav_state_unpack(imu_proto_nav_state_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_NAV_STATE_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->index = get_u32(payload + 0);
    m->mode = payload[4];
    m->lat = to_i32(get_u32(payload + 5));
    m->lon = to_i32(get_u32(payload + 9));
    m->height_mm = to_i32(get_u32(payload + 13));
    for (i = 0; i < 3; ++i) {
        m->vel[i] = to_i32(get_u32(payload + 17 + 4 * i));
    }
    for (i = 0; i < 3; ++i) {
        m->acc_bias[i] = to_i32(get_u32(payload + 29 + 4 * i));
    }
    m->baro_bias_mm = to_i32(get_u32(payload + 41));
    for (i = 0; i < 16; ++i) {
        m->var_mantissa[i] = to_i32(get_u32(payload + 45 + 4 * i));
    }
    for (i = 0; i < 16; ++i) {
        m->var_exponent[i] = to_i8(payload[109 + i]);
    }
    m->since_fix = get_u32(payload + 125);
    m->rejected = get_u32(payload + 129);
    m->zero_velocity = get_u32(payload + 133);
    m->resets = get_u32(payload + 137);
    m->fades = get_u32(payload + 141);
    return IMU_PROTO_OK;
}

size_t imu_proto_nav_state_encode(const imu_proto_nav_state_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_NAV_STATE_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_nav_state_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_NAV_STATE, seq, IMU_PROTO_NAV_STATE_SIZE, wire);
}

size_t imu_proto_marker_pack(const imu_proto_marker_t *m, uint8_t *payload)
{
    put_u32(payload + 0, (uint32_t)m->timestamp_us);
    put_u32(payload + 4, (uint32_t)m->index);
    put_u32(payload + 8, (uint32_t)m->lat_1e7deg);
    put_u32(payload + 12, (uint32_t)m->lon_1e7deg);
    put_u32(payload + 16, (uint32_t)m->height_mm);
    put_u32(payload + 20, (uint32_t)m->h_acc_mm);
    put_u32(payload + 24, (uint32_t)m->v_acc_mm);
    payload[28] = (uint8_t)m->used;
    return IMU_PROTO_MARKER_SIZE;
}

imu_proto_result_t imu_proto_marker_unpack(imu_proto_marker_t *m, const uint8_t *payload, size_t len)
{
    if (len != IMU_PROTO_MARKER_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->timestamp_us = get_u32(payload + 0);
    m->index = get_u32(payload + 4);
    m->lat_1e7deg = to_i32(get_u32(payload + 8));
    m->lon_1e7deg = to_i32(get_u32(payload + 12));
    m->height_mm = to_i32(get_u32(payload + 16));
    m->h_acc_mm = get_u32(payload + 20);
    m->v_acc_mm = get_u32(payload + 24);
    m->used = payload[28];
    return IMU_PROTO_OK;
}

size_t imu_proto_marker_encode(const imu_proto_marker_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    if (wire_cap < IMU_PROTO_MARKER_SIZE + IMU_PROTO_MIN_FRAME + 2u) {
        return 0;
    }
    (void)imu_proto_marker_pack(m, wire + FRAME_PAYLOAD_OFFSET);
    return frame_seal(IMU_PROTO_MSG_MARKER, seq, IMU_PROTO_MARKER_SIZE, wire);
}

size_t imu_proto_command_pack(const imu_proto_command_t *m, uint8_t *payload)
{
    size_t i;
    if (m->args_len > 28u) {
        return 0;
    }
    payload[0] = (uint8_t)m->command;
    put_u16(payload + 1, (uint16_t)m->command_seq);
    for (i = 0; i < m->args_len; ++i) {
        payload[3 + i] = m->args[i];
    }
    return 3u + m->args_len;
}

imu_proto_result_t imu_proto_command_unpack(imu_proto_command_t *m, const uint8_t *payload, size_t len)
{
    size_t i;
    if (len < 3u || len > IMU_PROTO_COMMAND_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    m->command = payload[0];
    m->command_seq = get_u16(payload + 1);
    m->args_len = len - 3u;
    for (i = 0; i < m->args_len; ++i) {
        m->args[i] = payload[3 + i];
    }
    return IMU_PROTO_OK;
}

size_t imu_proto_command_encode(const imu_proto_command_t *m, uint16_t seq, uint8_t *wire, size_t wire_cap)
{
    uint8_t payload[IMU_PROTO_COMMAND_SIZE];
    size_t len = imu_proto_command_pack(m, payload);
    if (len == 0) {
        return 0;
    }
    return imu_proto_frame_encode(IMU_PROTO_MSG_COMMAND, seq, payload, len, wire, wire_cap);
}

size_t imu_proto_cmd_select_filter_pack(const imu_proto_cmd_select_filter_t *a, uint8_t *args)
{
    args[0] = (uint8_t)a->filter_id;
    return IMU_PROTO_CMD_SELECT_FILTER_SIZE;
}

imu_proto_result_t imu_proto_cmd_select_filter_unpack(imu_proto_cmd_select_filter_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_SELECT_FILTER_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->filter_id = args[0];
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_get_setting_pack(const imu_proto_cmd_get_setting_t *a, uint8_t *args)
{
    args[0] = (uint8_t)a->index;
    return IMU_PROTO_CMD_GET_SETTING_SIZE;
}

imu_proto_result_t imu_proto_cmd_get_setting_unpack(imu_proto_cmd_get_setting_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_GET_SETTING_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->index = args[0];
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_set_setting_pack(const imu_proto_cmd_set_setting_t *a, uint8_t *args)
{
    args[0] = (uint8_t)a->index;
    put_u32(args + 1, (uint32_t)a->value);
    return IMU_PROTO_CMD_SET_SETTING_SIZE;
}

imu_proto_result_t imu_proto_cmd_set_setting_unpack(imu_proto_cmd_set_setting_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_SET_SETTING_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->index = args[0];
    a->value = to_i32(get_u32(args + 1));
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_inject_sample_pack(const imu_proto_sample_t *a, uint8_t *args)
{
    return imu_proto_sample_pack(a, args);
}

imu_proto_result_t imu_proto_cmd_inject_sample_unpack(imu_proto_sample_t *a, const uint8_t *args, size_t len)
{
    return imu_proto_sample_unpack(a, args, len);
}

size_t imu_proto_cmd_set_injection_mode_pack(const imu_proto_cmd_set_injection_mode_t *a, uint8_t *args)
{
    args[0] = (uint8_t)a->enabled;
    return IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE;
}

imu_proto_result_t imu_proto_cmd_set_injection_mode_unpack(imu_proto_cmd_set_injection_mode_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->enabled = args[0];
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_set_calibration_pack(const imu_proto_cmd_set_calibration_t *a, uint8_t *args)
{
    size_t i;
    args[0] = (uint8_t)a->sensor;
    args[1] = (uint8_t)a->axis;
    put_u32(args + 2, (uint32_t)a->offset);
    for (i = 0; i < 3; ++i) {
        put_u32(args + 6 + 4 * i, (uint32_t)a->row[i]);
    }
    return IMU_PROTO_CMD_SET_CALIBRATION_SIZE;
}

imu_proto_result_t imu_proto_cmd_set_calibration_unpack(imu_proto_cmd_set_calibration_t *a, const uint8_t *args, size_t len)
{
    size_t i;
    if (len != IMU_PROTO_CMD_SET_CALIBRATION_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->sensor = args[0];
    a->axis = args[1];
    a->offset = to_i32(get_u32(args + 2));
    for (i = 0; i < 3; ++i) {
        a->row[i] = to_i32(get_u32(args + 6 + 4 * i));
    }
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_get_calibration_pack(const imu_proto_cmd_get_calibration_t *a, uint8_t *args)
{
    args[0] = (uint8_t)a->sensor;
    args[1] = (uint8_t)a->axis;
    return IMU_PROTO_CMD_GET_CALIBRATION_SIZE;
}

imu_proto_result_t imu_proto_cmd_get_calibration_unpack(imu_proto_cmd_get_calibration_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_GET_CALIBRATION_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->sensor = args[0];
    a->axis = args[1];
    return IMU_PROTO_OK;
}

size_t imu_proto_cmd_position_fix_pack(const imu_proto_cmd_position_fix_t *a, uint8_t *args)
{
    put_u32(args + 0, (uint32_t)a->lat_1e7deg);
    put_u32(args + 4, (uint32_t)a->lon_1e7deg);
    put_u32(args + 8, (uint32_t)a->height_mm);
    put_u32(args + 12, (uint32_t)a->h_acc_mm);
    put_u32(args + 16, (uint32_t)a->v_acc_mm);
    return IMU_PROTO_CMD_POSITION_FIX_SIZE;
}

imu_proto_result_t imu_proto_cmd_position_fix_unpack(imu_proto_cmd_position_fix_t *a, const uint8_t *args, size_t len)
{
    if (len != IMU_PROTO_CMD_POSITION_FIX_SIZE) {
        return IMU_PROTO_ERR_LENGTH;
    }
    a->lat_1e7deg = to_i32(get_u32(args + 0));
    a->lon_1e7deg = to_i32(get_u32(args + 4));
    a->height_mm = to_i32(get_u32(args + 8));
    a->h_acc_mm = get_u32(args + 12);
    a->v_acc_mm = get_u32(args + 16);
    return IMU_PROTO_OK;
}

int imu_proto_command_args_size(uint8_t command)
{
    switch (command) {
    case IMU_PROTO_CMD_START_STREAM:
        return 0;
    case IMU_PROTO_CMD_STOP_STREAM:
        return 0;
    case IMU_PROTO_CMD_SELECT_FILTER:
        return IMU_PROTO_CMD_SELECT_FILTER_SIZE;
    case IMU_PROTO_CMD_GET_SETTING:
        return IMU_PROTO_CMD_GET_SETTING_SIZE;
    case IMU_PROTO_CMD_SET_SETTING:
        return IMU_PROTO_CMD_SET_SETTING_SIZE;
    case IMU_PROTO_CMD_INJECT_SAMPLE:
        return IMU_PROTO_CMD_INJECT_SAMPLE_SIZE;
    case IMU_PROTO_CMD_RESET:
        return 0;
    case IMU_PROTO_CMD_ENTER_BOOTLOADER:
        return 0;
    case IMU_PROTO_CMD_GET_VERSION:
        return 0;
    case IMU_PROTO_CMD_GET_STATUS:
        return 0;
    case IMU_PROTO_CMD_SET_INJECTION_MODE:
        return IMU_PROTO_CMD_SET_INJECTION_MODE_SIZE;
    case IMU_PROTO_CMD_SET_CALIBRATION:
        return IMU_PROTO_CMD_SET_CALIBRATION_SIZE;
    case IMU_PROTO_CMD_GET_CALIBRATION:
        return IMU_PROTO_CMD_GET_CALIBRATION_SIZE;
    case IMU_PROTO_CMD_POSITION_FIX:
        return IMU_PROTO_CMD_POSITION_FIX_SIZE;
    default:
        return -1;
    }
}
/* END GENERATED */
