/**
 * @file frame_ring.c
 * @brief The board's memory of the input frames it sent (see frame_ring.h).
 */
#include "frame_ring.h"

static uint8_t byte_at(const frame_ring_t *ring, uint32_t offset)
{
    return ring->bytes[offset % FRAME_RING_BYTES];
}

static uint16_t seq_at(const frame_ring_t *ring, uint32_t offset)
{
    return (uint16_t)(byte_at(ring, offset) | (byte_at(ring, offset + 1u) << 8));
}

static uint32_t entry_size(const frame_ring_t *ring, uint32_t offset)
{
    return FRAME_RING_ENTRY_HEAD + byte_at(ring, offset + 3u);
}

/** How long ago `seq` was sent, in frames: 1 for the last one sent, 0 for one not sent yet. */
static uint16_t age(uint16_t next_seq, uint16_t seq)
{
    return (uint16_t)(next_seq - seq);
}

void frame_ring_init(frame_ring_t *ring)
{
    ring->oldest = 0;
    ring->used = 0;
    ring->count = 0;
    ring->forgotten = 0;
}

static void drop_oldest(frame_ring_t *ring)
{
    const uint32_t size = entry_size(ring, ring->oldest);
    ring->oldest = (ring->oldest + size) % FRAME_RING_BYTES;
    ring->used -= size;
    --ring->count;
    ring->forgotten = 1;
}

void frame_ring_age(frame_ring_t *ring, uint16_t next_seq)
{
    while (ring->count > 0 && age(next_seq, seq_at(ring, ring->oldest)) >= 0x8000u) {
        drop_oldest(ring);
    }
}

void frame_ring_keep(frame_ring_t *ring, uint16_t seq, uint8_t msg_id, const uint8_t *payload, size_t len)
{
    const uint32_t size = FRAME_RING_ENTRY_HEAD + (uint32_t)len;
    uint32_t at, i;
    if (len > 255u) {
        return; /* no kept message is this long (the largest, GNSS, has 52 bytes) */
    }
    while (FRAME_RING_BYTES - ring->used < size) {
        drop_oldest(ring);
    }
    at = (ring->oldest + ring->used) % FRAME_RING_BYTES;
    ring->bytes[at] = (uint8_t)(seq & 0xFFu);
    ring->bytes[(at + 1u) % FRAME_RING_BYTES] = (uint8_t)(seq >> 8);
    ring->bytes[(at + 2u) % FRAME_RING_BYTES] = msg_id;
    ring->bytes[(at + 3u) % FRAME_RING_BYTES] = (uint8_t)len;
    for (i = 0; i < len; ++i) {
        ring->bytes[(at + FRAME_RING_ENTRY_HEAD + i) % FRAME_RING_BYTES] = payload[i];
    }
    ring->used += size;
    ++ring->count;
}

void frame_ring_cursor_init(const frame_ring_t *ring, frame_ring_cursor_t *cursor)
{
    cursor->offset = ring->oldest;
    cursor->visited = 0;
}

frame_ring_status_t frame_ring_find(const frame_ring_t *ring, frame_ring_cursor_t *cursor, uint16_t next_seq,
                                    uint16_t seq, uint8_t *msg_id, uint8_t *payload, size_t cap, size_t *len)
{
    const uint16_t wanted = age(next_seq, seq);
    uint32_t i, n;
    if (wanted == 0) {
        return FRAME_RING_GONE; /* not sent yet */
    }
    if (ring->count == 0 || wanted > age(next_seq, seq_at(ring, ring->oldest))) {
        /* older than every frame held: lost for good if the ring has forgotten frames, else
         * every kept frame since start-up is still held, so this one was not a kept one */
        return ring->forgotten ? FRAME_RING_GONE : FRAME_RING_NOT_KEPT;
    }
    /* pass the entries older than the one wanted (ages fall from the oldest entry on) */
    while (cursor->visited < ring->count && age(next_seq, seq_at(ring, cursor->offset)) > wanted) {
        cursor->offset = (cursor->offset + entry_size(ring, cursor->offset)) % FRAME_RING_BYTES;
        ++cursor->visited;
    }
    if (cursor->visited == ring->count || seq_at(ring, cursor->offset) != seq) {
        return FRAME_RING_NOT_KEPT;
    }
    *msg_id = byte_at(ring, cursor->offset + 2u);
    n = byte_at(ring, cursor->offset + 3u);
    n = n < cap ? n : (uint32_t)cap;
    for (i = 0; i < n; ++i) {
        payload[i] = byte_at(ring, cursor->offset + FRAME_RING_ENTRY_HEAD + i);
    }
    *len = n;
    return FRAME_RING_HELD;
}
