/**
 * @file frame_ring.h
 * @brief The board's memory of the input frames it sent, for RESEND.
 *
 * A lost SAMPLE leaves every later estimate of its filter run unverifiable (each depends on
 * every sample before it), so the board keeps the frames the filter consumed (SAMPLE, BARO,
 * GNSS, MARKER: their seq, message id and payload) and sends any of them again when the host
 * asks by seq. Entries are variable-length records in one byte ring, oldest first; a new one
 * pushes out the oldest ones it needs room for.
 *
 * Budget: FRAME_RING_BYTES = 36 KiB. A SAMPLE takes 4 + 28 bytes, so the ring holds 1 152
 * samples alone, and 1.0 s at 1 kHz with a barometer at 50 Hz and a receiver at 10 Hz beside
 * them (1000 * 32 + 50 * 28 + 10 * 56 = 33 960 bytes); at 100 Hz about 11 s.
 */
#ifndef FRAME_RING_H
#define FRAME_RING_H

#include <stddef.h>
#include <stdint.h>

#define FRAME_RING_BYTES 36864u
/** Bytes before each kept payload: seq (u16 LE), message id, payload length. */
#define FRAME_RING_ENTRY_HEAD 4u

typedef struct {
    uint8_t bytes[FRAME_RING_BYTES];
    uint32_t oldest; /**< offset of the oldest entry's head */
    uint32_t used;   /**< bytes held, heads included */
    uint32_t count;  /**< entries held */
    int forgotten;   /**< 1 once an entry was pushed or aged out: older seqs may have been kept ones */
} frame_ring_t;

/** What frame_ring_find() found for a seq (the values of RESENT.status). */
typedef enum {
    FRAME_RING_HELD = 0,     /**< the frame is held: its message id and payload were copied out */
    FRAME_RING_NOT_KEPT = 1, /**< sent, but not a kept frame (after the oldest frame held, or when the
                                  ring has forgotten none since start-up) */
    FRAME_RING_GONE = 2,     /**< older than every frame held once the ring has forgotten some, or not
                                  sent yet */
} frame_ring_status_t;

void frame_ring_init(frame_ring_t *ring);

/** Keep a frame sent with `seq` (payload of `len` bytes, at most 255). */
void frame_ring_keep(frame_ring_t *ring, uint16_t seq, uint8_t msg_id, const uint8_t *payload, size_t len);

/** Forget the entries sent 32 768 frames or more before `next_seq`: seqs are 16 bits, and an
 *  older entry could otherwise pass for a newer frame with the same seq. Call it for every frame
 *  sent (it costs a comparison while nothing is that old). */
void frame_ring_age(frame_ring_t *ring, uint16_t next_seq);

/** A position in the ring for walking it oldest first (frame_ring_find). */
typedef struct {
    uint32_t offset;  /**< the entry's head */
    uint32_t visited; /**< entries passed */
} frame_ring_cursor_t;

void frame_ring_cursor_init(const frame_ring_t *ring, frame_ring_cursor_t *cursor);

/**
 * What the ring holds for `seq`, given `next_seq`, the seq the next frame will be sent with
 * (seqs are compared by their age next_seq - seq, mod 65536). On FRAME_RING_HELD the message id
 * and payload (up to `cap` bytes) are copied out and *len set.
 *
 * `cursor` moves forward only: ask for seqs oldest first with the same cursor and one RESEND
 * walks the ring once.
 */
frame_ring_status_t frame_ring_find(const frame_ring_t *ring, frame_ring_cursor_t *cursor, uint16_t next_seq,
                                    uint16_t seq, uint8_t *msg_id, uint8_t *payload, size_t cap, size_t *len);

#endif /* FRAME_RING_H */
