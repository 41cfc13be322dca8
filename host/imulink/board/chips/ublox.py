"""A u-blox M8 GNSS receiver on a UART, at message level, from the u-blox 8 / M8 receiver
description and protocol specification (UBX-13003221, "the spec").

Modelled:

* the UART: one baud for both directions (the spec's default 9600, 8N1); bytes sent at
  another baud arrive as noise on the other side, about as many bytes as were sent (the
  receiver and the board each see the other's bits at the wrong rate);
* out of the box: NMEA RMC and GGA once a second (the defaults' first and third sentences;
  VTG, GSA, GSV and GLL are left out), UBX and NMEA accepted in;
* CFG-PRT (UART1): the new baud and output protocols; its ACK-ACK leaves at the old baud,
  and the receiver then listens and talks at the new one;
* CFG-MSG (the three-byte form, current port): NAV-PVT on (rate >= 1) or off; other
  messages are acknowledged and ignored;
* CFG-RATE: the navigation period; ACK-NAK when it is shorter than the receiver's
  fastest (:attr:`UbloxReceiver.min_period_ms`) or not a whole number of ms;
* ACK-NAK for a CFG message it does not know, and nothing at all for a frame whose checksum
  is wrong (the spec: such a frame is ignored);
* NAV-PVT (92 bytes, the spec's layout) and GGA/RMC carrying the same fix, from
  :meth:`UbloxReceiver.set_fix` (position, velocity, accuracies, fix type);
* faults: an absent receiver (:attr:`present` False: it sends nothing and hears nothing),
  a receiver that speaks NMEA only (:attr:`ubx` False: UBX frames are ignored), frames
  and sentences sent with a damaged checksum (:attr:`damage`, a fraction), a receiver
  that reboots (:meth:`reboot`: the defaults again, silence for :attr:`boot_ms`), a lost
  fix (:meth:`set_fix` with fix_type 0: NAV-PVT says so, GGA and RMC have empty fields).

Not modelled: the UART's capacity (a stream beyond baud / 10 bytes a second is sent
anyway), the receiver's own latency, other ports, the longer CFG-MSG forms, saving
the configuration (a reboot always restores the defaults), the time fields beyond
iTOW and UTC time of day.
"""
from __future__ import annotations

import math
import random
import struct
from dataclasses import dataclass

SYNC = b"\xb5\x62"
CLASS_NAV, CLASS_ACK, CLASS_CFG = 0x01, 0x05, 0x06
ID_NAV_PVT, ID_ACK_NAK, ID_ACK_ACK = 0x07, 0x00, 0x01
ID_CFG_PRT, ID_CFG_MSG, ID_CFG_RATE = 0x00, 0x01, 0x08

#: NAV-PVT's payload (the spec's table), 92 bytes.
NAV_PVT = struct.Struct("<IHBBBBBBIiBBBBiiiiIIiiiiiIIHH4sihH")
assert NAV_PVT.size == 92

DEFAULT_BAUD = 9600
DEFAULT_PERIOD_MS = 1000


def checksum(body: bytes) -> bytes:
    """The spec's 8-bit Fletcher checksum over class, id, length and payload."""
    a = b = 0
    for byte in body:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return bytes([a, b])


def ubx_frame(msg_class: int, msg_id: int, payload: bytes) -> bytes:
    body = bytes([msg_class, msg_id]) + struct.pack("<H", len(payload)) + payload
    return SYNC + body + checksum(body)


def nmea_sentence(body: str) -> bytes:
    """'$' body '*' and the XOR of the body's characters, CR LF."""
    xor = 0
    for char in body.encode("ascii"):
        xor ^= char
    return f"${body}*{xor:02X}\r\n".encode("ascii")


@dataclass
class Fix:
    """What the receiver reports each epoch (the units of NAV-PVT)."""
    lat_deg: float = 47.3769
    lon_deg: float = 8.5417
    height_m: float = 450.0          # above the WGS-84 ellipsoid
    geoid_sep_m: float = 47.0        # geoid above the ellipsoid (GGA's field 11)
    vel_ned_m_s: tuple = (0.0, 0.0, 0.0)
    h_acc_m: float = 2.5
    v_acc_m: float = 5.0
    s_acc_m_s: float = 0.1
    fix_type: int = 3                # 0 none, 2 2D, 3 3D
    num_sv: int = 9
    p_dop: float = 1.5


class UbloxReceiver:
    """The receiver. The board's side drives it: :meth:`receive` with the bytes the board
    sent at its baud, :meth:`advance` for the passing of time, which returns the bytes the
    board's UART received meanwhile at its baud."""

    def __init__(self, *, present: bool = True, ubx: bool = True, baud: int = DEFAULT_BAUD,
                 min_period_ms: int = 100, damage: float = 0.0, boot_ms: int = 500, seed: int = 0):
        self.present = present
        self.ubx = ubx
        self.min_period_ms = min_period_ms
        self.damage = damage
        self.boot_ms = boot_ms
        self.rng = random.Random(seed)
        self.fix = Fix()
        self.time_ms = 0
        self.acked: list[tuple[int, int]] = []   # (class, id) of every ACK-ACK sent
        self.naked: list[tuple[int, int]] = []   # and ACK-NAK
        self._reset(baud)
        self._booting_until = 0

    def _reset(self, baud: int) -> None:
        self.baud = baud
        self.out_ubx, self.out_nmea = True, True
        self.period_ms = DEFAULT_PERIOD_MS
        self.nav_pvt_on = False
        self._next_epoch = self.time_ms + self.period_ms
        self._in = bytearray()
        self._pending: list[tuple[int, bytes]] = []  # (the baud it left at, bytes)

    # ------------------------------------------------------------------ the board's side
    def reboot(self) -> None:
        """Power cycle: the defaults (9600 baud, NMEA once a second), silent while it boots."""
        self._reset(DEFAULT_BAUD)
        self._booting_until = self.time_ms + self.boot_ms
        self._next_epoch = self._booting_until + self.period_ms

    def set_fix(self, **fields) -> None:
        for name, value in fields.items():
            setattr(self.fix, name, value)

    def receive(self, data: bytes, board_baud: int) -> None:
        """Bytes the board sent at `board_baud`."""
        if not self.present or self.time_ms < self._booting_until or not data:
            return
        if board_baud != self.baud:
            data = self._noise(len(data))
        self._in += data
        self._parse_input()

    def advance(self, ms: int, board_baud: int) -> bytes:
        """`ms` milliseconds pass; the bytes the board's UART received meanwhile."""
        end = self.time_ms + ms
        while self.present and self._next_epoch <= end:
            self.time_ms = self._next_epoch
            self._epoch()
            self._next_epoch += self.period_ms
        self.time_ms = end
        out = b"".join(data if baud == board_baud else self._noise(len(data)) for baud, data in self._pending)
        self._pending = []
        return out

    # ------------------------------------------------------------------ inside
    def _noise(self, n: int) -> bytes:
        """What one side's UART makes of n bytes sent at another baud: framing garbage."""
        return bytes(self.rng.randrange(256) for _ in range(n))

    def _send(self, data: bytes) -> None:
        if self.damage and self.rng.random() < self.damage:
            # UBX: the payload's last byte; NMEA: a digit of the checksum
            data = data[:-3] + bytes([data[-3] ^ 0x5A]) + data[-2:]
        self._pending.append((self.baud, data))

    def _send_ubx(self, msg_class: int, msg_id: int, payload: bytes) -> None:
        self._send(ubx_frame(msg_class, msg_id, payload))

    def _ack(self, msg_class: int, msg_id: int, ok: bool) -> None:
        (self.acked if ok else self.naked).append((msg_class, msg_id))
        self._send_ubx(CLASS_ACK, ID_ACK_ACK if ok else ID_ACK_NAK, bytes([msg_class, msg_id]))

    def _parse_input(self) -> None:
        """Whole UBX frames out of the input; everything else (NMEA, noise) is dropped."""
        buf = self._in
        while True:
            start = buf.find(SYNC)
            if start < 0:
                del buf[: max(0, len(buf) - 1)]
                return
            del buf[:start]
            if len(buf) < 6:
                return
            length = struct.unpack_from("<H", buf, 4)[0]
            if length > 512:
                del buf[:2]
                continue
            if len(buf) < 8 + length:
                return
            body, check = bytes(buf[2:6 + length]), bytes(buf[6 + length:8 + length])
            del buf[:8 + length]
            if check == checksum(body) and self.ubx:
                self._command(body[0], body[1], body[4:])

    def _command(self, msg_class: int, msg_id: int, payload: bytes) -> None:
        if msg_class != CLASS_CFG:
            return
        if msg_id == ID_CFG_PRT and len(payload) == 20 and payload[0] == 1:
            baud, in_mask, out_mask = struct.unpack_from("<IHH", payload, 8)
            self._ack(msg_class, msg_id, True)  # at the old baud
            self.baud = baud
            self.out_ubx, self.out_nmea = bool(out_mask & 1), bool(out_mask & 2)
        elif msg_id == ID_CFG_MSG and len(payload) == 3:
            if (payload[0], payload[1]) == (CLASS_NAV, ID_NAV_PVT):
                self.nav_pvt_on = payload[2] > 0
            self._ack(msg_class, msg_id, True)
        elif msg_id == ID_CFG_RATE and len(payload) == 6:
            period, nav_rate, _time_ref = struct.unpack("<HHH", payload)
            ok = period >= self.min_period_ms and nav_rate >= 1
            if ok:
                self.period_ms = period
                self._next_epoch = self.time_ms + period
            self._ack(msg_class, msg_id, ok)
        else:
            self._ack(msg_class, msg_id, False)

    def _epoch(self) -> None:
        if self.time_ms < self._booting_until:
            return
        if self.out_nmea:
            for sentence in self._nmea():
                self._send(sentence)
        if self.out_ubx and self.nav_pvt_on:
            self._send_ubx(CLASS_NAV, ID_NAV_PVT, self.nav_pvt_payload())

    def nav_pvt_payload(self) -> bytes:
        """NAV-PVT of the current fix at the current time (iTOW = the receiver's ms)."""
        f = self.fix
        has_fix = f.fix_type >= 2
        vn, ve, vd = (round(v * 1000) for v in f.vel_ned_m_s)
        speed = round(math.hypot(vn, ve))
        return NAV_PVT.pack(
            self.time_ms % (7 * 86_400_000), 2026, 11, 27, 12, 0, 0, 0x07, 20, 0, f.fix_type,
            0x01 if has_fix else 0x00, 0, f.num_sv if has_fix else 0,
            round(f.lon_deg * 1e7), round(f.lat_deg * 1e7), round(f.height_m * 1000),
            round((f.height_m - f.geoid_sep_m) * 1000),
            round(f.h_acc_m * 1000) if has_fix else 4_294_967, round(f.v_acc_m * 1000) if has_fix else 3_750_000,
            vn, ve, vd, speed, 0, round(f.s_acc_m_s * 1000) if has_fix else 20_000, 18_000_000,
            round(f.p_dop * 100) if has_fix else 9999, 0, b"\0" * 4, 0, 0, 0)

    def _nmea(self) -> list[bytes]:
        f = self.fix
        day_ms = self.time_ms % 86_400_000
        hh, rest = divmod(day_ms, 3_600_000)
        mm, rest = divmod(rest, 60_000)
        stamp = f"{hh:02d}{mm:02d}{rest / 1000:06.3f}"
        if f.fix_type < 2:
            return [nmea_sentence(f"GNRMC,{stamp},V,,,,,,,271126,,,N"),
                    nmea_sentence(f"GNGGA,{stamp},,,,,0,00,99.99,,,,,,")]
        lat, lon = _ddmm(f.lat_deg, "NS", 2), _ddmm(f.lon_deg, "EW", 3)
        speed_kn = math.hypot(*f.vel_ned_m_s[:2]) * 3600 / 1852
        course = math.degrees(math.atan2(f.vel_ned_m_s[1], f.vel_ned_m_s[0])) % 360
        msl = f.height_m - f.geoid_sep_m
        return [nmea_sentence(f"GNRMC,{stamp},A,{lat},{lon},{speed_kn:.3f},{course:.2f},271126,,,A"),
                nmea_sentence(f"GNGGA,{stamp},{lat},{lon},1,{f.num_sv:02d},{f.p_dop:.2f},{msl:.1f},M,"
                              f"{f.geoid_sep_m:.1f},M,,")]


def _ddmm(deg: float, hemispheres: str, width: int) -> str:
    """An angle as NMEA's (d)ddmm.mmmmm,H."""
    hemisphere = hemispheres[0] if deg >= 0 else hemispheres[1]
    deg = abs(deg)
    whole = int(deg)
    minutes = (deg - whole) * 60
    return f"{whole:0{width}d}{minutes:08.5f},{hemisphere}"
