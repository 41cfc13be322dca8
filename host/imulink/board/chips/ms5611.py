"""MEAS (TE Connectivity) MS5611-01BA barometer at command level, from its data sheet
("MS5611-01BA03", "DS") and application note AN520 (the PROM's CRC-4).

Modelled:

* the commands of DS's command table, each one I2C write of one byte: RESET (0x1E),
  CONVERT D1 (0x40, 0x42, ... 0x48 for OSR 256 ... 4096), CONVERT D2 (0x50 ... 0x58),
  ADC READ (0x00), PROM READ (0xA0 + 2 k);
* reads: after ADC READ, the three bytes of the last conversion, big-endian, and 0 when
  no conversion finished since the last ADC READ, when it is repeated, or when it comes
  during a conversion (which then gives no result: DS says such a result is wrong);
  after PROM READ, the word, big-endian;
* time: a conversion takes its typical time (DS: 0.54, 1.06, 2.08, 4.13, 8.22 ms); RESET
  reloads the PROM for 2.8 ms: a PROM read before that gives zeros (DS does not say what
  it gives; zeros make a driver that does not wait find no calibration);
* the PROM: a factory word, C1..C6, and word 7 with a serial code and the CRC-4
  (:func:`prom_crc`), as :meth:`MS5611.with_coefficients` builds it, or any eight words
  (a damaged PROM);
* D1 and D2, the raw conversions, set by the test (:attr:`d1`, :attr:`d2`), and
  :func:`compensate`, the data sheet's integer algorithm written independently of the C
  driver.

Not modelled: SPI, the CSB pin (the address is where the chip is attached), a command
other than these (ignored).
"""
from __future__ import annotations

from imulink.board.chips.i2c import I2CDevice

#: Typical conversion times by OSR index (256, 512, 1024, 2048, 4096), ms (DS).
CONVERSION_MS = (0.54, 1.06, 2.08, 4.13, 8.22)
#: PROM reload after RESET, ms (DS).
RESET_MS = 2.8

#: The data sheet's worked example: C1..C6, D1, D2 and what they give (TEMP 20.07 degC, P 1000.09 mbar).
EXAMPLE_C = (40127, 36924, 23317, 23282, 33464, 28312)
EXAMPLE_D1, EXAMPLE_D2 = 9085466, 8569150
EXAMPLE_TEMP, EXAMPLE_P = 2007, 100009


def prom_crc(words) -> int:
    """AN520's CRC-4 of eight PROM words: their sixteen bytes, most significant first,
    word 7's low byte (which holds the CRC) taken as zero, through x^4 + x + 1."""
    data = []
    for k, word in enumerate(words):
        data += [word >> 8, 0 if k == 7 else word & 0xFF]
    remainder = 0
    for byte in data:
        remainder ^= byte
        for _ in range(8):
            remainder = ((remainder << 1) ^ 0x3000) & 0xFFFF if remainder & 0x8000 else (remainder << 1) & 0xFFFF
    return (remainder >> 12) & 0xF


def _div(a: int, b: int) -> int:
    """C's integer division: truncation toward zero."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q


def compensate(c, d1: int, d2: int) -> tuple[int, int]:
    """(P in Pa, TEMP in 0.01 degC) from C1..C6 (`c`, six values) and D1, D2: the data
    sheet's first- and second-order compensation, with C's integer division."""
    c1, c2, c3, c4, c5, c6 = c
    dt = d2 - c5 * 2**8
    temp = 2000 + _div(dt * c6, 2**23)
    off = c2 * 2**16 + _div(c4 * dt, 2**7)
    sens = c1 * 2**15 + _div(c3 * dt, 2**8)
    if temp < 2000:
        t2 = _div(dt * dt, 2**31)
        off2 = _div(5 * (temp - 2000) ** 2, 2)
        sens2 = _div(5 * (temp - 2000) ** 2, 4)
        if temp < -1500:
            off2 += 7 * (temp + 1500) ** 2
            sens2 += _div(11 * (temp + 1500) ** 2, 2)
        temp, off, sens = temp - t2, off - off2, sens - sens2
    return _div(_div(d1 * sens, 2**21) - off, 2**15), temp


def raw_for(c, pressure_pa: float, temp_centi_c: float) -> tuple[int, int]:
    """The conversions D1, D2 (24-bit) a chip with coefficients `c` gives at that pressure
    (Pa) and temperature (0.01 degC): the inverse of :func:`compensate`, by bisection (TEMP
    rises with D2 and P with D1, the second-order terms included), so that compensating
    them gives the values back to the data sheet's resolution (1 Pa, 0.01 degC).

    Raises ValueError for a pressure or temperature the chip cannot report (outside what
    D1 and D2's 24 bits give with these coefficients)."""
    def bisect(f, target: float) -> int:
        lo, hi = 0, (1 << 24) - 1
        if not f(lo) <= target <= f(hi):
            raise ValueError(f"{target:g} is outside {f(lo)}..{f(hi)} for these coefficients")
        while hi - lo > 1:
            mid = (lo + hi) // 2
            lo, hi = (mid, hi) if f(mid) <= target else (lo, mid)
        return lo if abs(f(lo) - target) <= abs(f(hi) - target) else hi

    d2 = bisect(lambda d: compensate(c, 0, d)[1], temp_centi_c)
    d1 = bisect(lambda d: compensate(c, d, d2)[0], pressure_pa)
    return d1, d2


class MS5611(I2CDevice):
    """The chip (see the module docstring). `prom`: its eight words (default: the data
    sheet's example coefficients with a valid CRC)."""

    def __init__(self, prom: list[int] | None = None):
        self.prom = list(prom) if prom is not None else self.with_coefficients(EXAMPLE_C)
        self.d1, self.d2 = EXAMPLE_D1, EXAMPLE_D2
        self._command: int | None = None                   # the last command byte received
        self._converting: tuple[int, float] | None = None  # (result, ms left) of a running conversion
        self._result = 0                                   # what ADC READ gives next
        self._reloading_ms = 0.0                           # PROM reload after RESET
        self._answer: bytes | None = None                  # what is left to read of the answer to the last command
        self.conversions: list[int] = []                   # every CONVERT command received, for the tests

    @staticmethod
    def with_coefficients(c, factory: int = 0x0050, serial: int = 0x123) -> list[int]:
        """Eight PROM words with C1..C6 = `c` and a valid CRC-4."""
        words = [factory, *c, (serial << 4) & 0xFFF0]
        words[7] |= prom_crc(words)
        return words

    def i2c_write(self, data: bytes) -> None:
        if not data:
            return
        command = data[0]
        self._command = command
        self._answer = None  # the next read phase answers this command
        if command == 0x1E:  # RESET
            self._converting, self._result, self._reloading_ms = None, 0, RESET_MS
        elif command & 0xF0 in (0x40, 0x50) and command & 0x01 == 0 and (command & 0x0F) >> 1 < 5:
            osr = (command & 0x0F) >> 1
            self.conversions.append(command)
            value = self.d1 if command & 0xF0 == 0x40 else self.d2
            self._converting = (value & 0xFFFFFF, CONVERSION_MS[osr])
        elif command == 0x00 and self._converting is not None:  # ADC READ during a conversion
            self._converting, self._result = None, 0

    def i2c_read(self, n: int) -> bytes:
        """The answer to the last command, byte after byte however the master splits the
        read (a bus reads a phase at once, a peripheral model a byte at a time); zeros
        after its end."""
        if self._answer is None:
            self._answer = self._answer_to(self._command)
        out, self._answer = self._answer[:n], self._answer[n:]
        return out.ljust(n, b"\x00")

    def _answer_to(self, command: int | None) -> bytes:
        if command == 0x00:
            value, self._result = self._result, 0  # a result is read once
            return value.to_bytes(3, "big")
        if command is not None and 0xA0 <= command <= 0xAE and command % 2 == 0:
            word = self.prom[(command - 0xA0) // 2] if self._reloading_ms <= 0 else 0
            return word.to_bytes(2, "big")
        return b""

    def advance(self, ms: float) -> None:
        self._reloading_ms -= ms
        if self._converting is not None:
            value, left = self._converting
            left -= ms
            if left <= 0:
                self._converting, self._result = None, value
            else:
                self._converting = (value, left)
