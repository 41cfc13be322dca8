"""The board's ring of sent input frames (firmware/app/frame_ring.c), compiled on the host:
what RESEND finds for a seq, as the ring wraps, forgets and ages its entries."""
from __future__ import annotations

from pathlib import Path

import pytest

from cffi_module import build

APP = Path(__file__).resolve().parents[1] / "firmware" / "app"
CDEF = """
    #define FRAME_RING_BYTES ...
    typedef struct { uint32_t oldest; uint32_t used; uint32_t count; int forgotten; ...; } frame_ring_t;
    typedef struct { ...; } frame_ring_cursor_t;
    enum { FRAME_RING_HELD, FRAME_RING_NOT_KEPT, FRAME_RING_GONE };
    void frame_ring_init(frame_ring_t *ring);
    void frame_ring_keep(frame_ring_t *ring, uint16_t seq, uint8_t msg_id, const uint8_t *payload, size_t len);
    void frame_ring_age(frame_ring_t *ring, uint16_t next_seq);
    void frame_ring_cursor_init(const frame_ring_t *ring, frame_ring_cursor_t *cursor);
    int frame_ring_find(const frame_ring_t *ring, frame_ring_cursor_t *cursor, uint16_t next_seq, uint16_t seq,
                        uint8_t *msg_id, uint8_t *payload, size_t cap, size_t *len);
"""


@pytest.fixture(scope="module")
def ring_lib(tmp_path_factory):
    return build("_imulink_frame_ring", CDEF, '#include "frame_ring.h"\n', [APP / "frame_ring.c"], [APP],
                 tmp_path_factory.mktemp("frame_ring"))


class Ring:
    """A ring and a board's seq counter: sent() for a frame not kept, kept() for one kept."""

    def __init__(self, module):
        self.ffi, self.lib = module.ffi, module.lib
        self.ring = self.ffi.new("frame_ring_t *")
        self.lib.frame_ring_init(self.ring)
        self.next_seq = 0

    def sent(self) -> int:
        seq = self.next_seq
        self.next_seq = (seq + 1) & 0xFFFF
        self.lib.frame_ring_age(self.ring, self.next_seq)
        return seq

    def kept(self, payload: bytes, msg_id: int = 0x10) -> int:
        self.lib.frame_ring_keep(self.ring, self.next_seq, msg_id, payload, len(payload))
        return self.sent()

    def find(self, *seqs: int) -> list:
        """(status, msg_id, payload) for each seq, oldest first, with one cursor."""
        cursor = self.ffi.new("frame_ring_cursor_t *")
        self.lib.frame_ring_cursor_init(self.ring, cursor)
        found = []
        for seq in seqs:
            msg_id, payload, length = self.ffi.new("uint8_t *"), self.ffi.new("uint8_t[64]"), self.ffi.new("size_t *")
            status = self.lib.frame_ring_find(self.ring, cursor, self.next_seq, seq & 0xFFFF, msg_id, payload, 64,
                                              length)
            found.append((status, msg_id[0], bytes(self.ffi.buffer(payload, length[0]))
                          if status == self.lib.FRAME_RING_HELD else None))
        return found


def _payload(k: int) -> bytes:
    return bytes((k + i) & 0xFF for i in range(28))


def test_held_not_kept_and_not_sent(ring_lib):
    ring, lib = Ring(ring_lib), ring_lib.lib
    hello, first, estimate, second = ring.sent(), ring.kept(_payload(1)), ring.sent(), ring.kept(_payload(2), 0x12)
    found = ring.find(hello, first, estimate, second, ring.next_seq)
    # nothing forgotten yet: the HELLO before the first kept frame was not a kept one
    assert [status for status, _, _ in found] == [lib.FRAME_RING_NOT_KEPT, lib.FRAME_RING_HELD,
                                                  lib.FRAME_RING_NOT_KEPT, lib.FRAME_RING_HELD, lib.FRAME_RING_GONE]
    assert found[1][1:] == (0x10, _payload(1)) and found[3][1:] == (0x12, _payload(2))


def test_a_full_ring_forgets_the_oldest_and_wraps_its_bytes(ring_lib):
    ring, lib = Ring(ring_lib), ring_lib.lib
    capacity = lib.FRAME_RING_BYTES // 32  # a SAMPLE's entry: 4 bytes of head, 28 of payload
    seqs = []
    for k in range(3 * capacity + 7):  # with an output frame after each, as a stream has
        seqs.append(ring.kept(_payload(k)))
        ring.sent()
    assert ring.ring.count == capacity and ring.ring.forgotten
    held = seqs[-capacity:]
    found = ring.find(seqs[-capacity - 1], *held)
    assert found[0][0] == lib.FRAME_RING_GONE
    assert [payload for _, _, payload in found[1:]] == [_payload(k) for k in range(2 * capacity + 7, 3 * capacity + 7)]
    # an output frame within the ring's stretch, asked for between kept ones
    assert ring.find(held[5], held[5] + 1, held[6]) == [(lib.FRAME_RING_HELD, 0x10, _payload(2 * capacity + 12)),
                                                       (lib.FRAME_RING_NOT_KEPT, 0, None),
                                                       (lib.FRAME_RING_HELD, 0x10, _payload(2 * capacity + 13))]


def test_entries_age_out_before_their_seq_comes_round_again(ring_lib):
    """A board that sits idle after a stream keeps sending frames (STATUS, ACKs): after 32 768
    of them a held SAMPLE's seq would soon name a newer frame, so it is forgotten."""
    ring, lib = Ring(ring_lib), ring_lib.lib
    old = ring.kept(_payload(9))
    for _ in range(0x7FFE):
        ring.sent()
    assert ring.find(old)[0][0] == lib.FRAME_RING_HELD  # 32 767 frames ago
    ring.sent()
    assert ring.ring.count == 0 and ring.find(old)[0][0] == lib.FRAME_RING_GONE
    for _ in range(0x8000):  # the seq comes round: a new frame with it is not the old one
        ring.sent()
    assert ring.next_seq == old
    ring.sent()  # an output frame now has the old SAMPLE's seq
    assert ring.find(old)[0][0] == lib.FRAME_RING_GONE
