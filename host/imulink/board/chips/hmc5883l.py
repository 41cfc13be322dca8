"""Register-level model of the Honeywell HMC5883L (data sheet "3-Axis Digital Compass IC
HMC5883L", Form #900405 Rev E).

What is modelled:

* the 13 registers: Configuration A (reset 0x10: 1 sample, 15 Hz, normal measurement),
  Configuration B (reset 0x20: gain 1090 LSB/gauss), Mode (reset 0x01: single
  measurement), the data output registers X MSB/LSB, Z MSB/LSB, Y MSB/LSB (0x03..0x08,
  in that order, big-endian), Status (LOCK, RDY) and Identification A, B, C ('H', '4',
  '3'); registers 3..12 are read-only, addresses from 13 on read 0 and ignore writes;
* the register pointer: +1 after each byte, except that after register 8 it returns to
  3 and after register 12 or higher to 0 (data sheet, "pointer locations"); the data
  sheet describes the rule for reads, the model applies it to multi-byte writes too;
* measurements: single-measurement mode measures once, 6 ms after the mode is written
  (and at power-on, single being the power-on mode), then sets the mode bits to idle
  (MD = 11); continuous-measurement mode measures 6 ms after the mode is written, then
  at the data output rate of Configuration A; idle does not measure;
* a measurement stores the counts a test set with :meth:`HMC5883L.set_field` in the data
  registers; a channel outside -2048..2047 stores -4096 (ADC overflow or underflow);
  RDY is set once data is stored (the data sheet clears it only while the chip writes);
* the data lock: reading some but not all six data registers, or reading the Mode
  register, sets LOCK and new measurements are not stored; reading all six, writing the
  Mode register or Configuration A, or power-on clears it.

Not modelled: the self-test bias fields (positive/negative bias measure like normal),
averaging, the one-measurement delay of a gain change (the counts a test sets are
already at the configured gain), the DRDY pin, high-speed I2C.

Failure injection: ``identity`` (other identification bytes), ``ignore_writes``.
"""
from __future__ import annotations

from imulink.board.chips.i2c import RegisterDevice

#: Register addresses by data-sheet name.
REGISTERS = {
    "CONFIG_A": 0x00, "CONFIG_B": 0x01, "MODE": 0x02,
    "DATA_X_MSB": 0x03, "DATA_X_LSB": 0x04, "DATA_Z_MSB": 0x05, "DATA_Z_LSB": 0x06,
    "DATA_Y_MSB": 0x07, "DATA_Y_LSB": 0x08, "STATUS": 0x09,
    "IDENT_A": 0x0A, "IDENT_B": 0x0B, "IDENT_C": 0x0C,
}
_R = REGISTERS
N_REGISTERS = 13
DATA = range(0x03, 0x09)

RESET_VALUES = {_R["CONFIG_A"]: 0x10, _R["CONFIG_B"]: 0x20, _R["MODE"]: 0x01}

#: Data output rates of Configuration A DO2..DO0, Hz (7 is reserved).
OUTPUT_RATES_HZ = (0.75, 1.5, 3.0, 7.5, 15.0, 30.0, 75.0, None)
#: Sensitivity of each gain GN2..GN0, LSB/gauss.
GAINS_LSB_PER_GAUSS = (1370, 1090, 820, 660, 440, 390, 330, 230)

MODE_CONTINUOUS, MODE_SINGLE, MODE_IDLE = 0b00, 0b01, 0b11
STATUS_LOCK = 0x02
STATUS_RDY = 0x01
#: Time from a mode write to the first stored measurement (data sheet, operational examples).
MEASUREMENT_MS = 6.0
#: Output range of a data register; beyond it the register holds OVERFLOW.
COUNT_MIN, COUNT_MAX = -2048, 2047
OVERFLOW = -4096


class HMC5883L(RegisterDevice):
    """The chip.

    Args:
        identity: the three identification bytes (b"H43" for an HMC5883L).
        ignore_writes: registers whose writes are dropped.
    """

    def __init__(self, identity: bytes = b"H43", ignore_writes=()):
        super().__init__()
        if len(identity) != 3:
            raise ValueError("three identification bytes")
        self.identity = bytes(identity)
        self.ignore_writes = frozenset(ignore_writes)
        self.field = (0, 0, 0)
        self.measurements = 0
        self._now_ms = 0.0
        self.power_on()

    # ------------------------------------------------------------------ state

    def power_on(self) -> None:
        """Power applied: reset values, unlocked, pointer 0, a single measurement started."""
        self.regs = bytearray(N_REGISTERS)
        for register, value in RESET_VALUES.items():
            self.regs[register] = value
        self.regs[_R["IDENT_A"]:_R["IDENT_C"] + 1] = self.identity
        self.pointer = 0
        self._data_read: set[int] = set()
        self._next_measurement_ms: float | None = None
        self._start_mode()

    @property
    def mode(self) -> int:
        """Operating mode bits MD1..MD0 of the Mode register."""
        return self.regs[_R["MODE"]] & 0x03

    @property
    def locked(self) -> bool:
        return bool(self.regs[_R["STATUS"]] & STATUS_LOCK)

    @property
    def output_rate_hz(self) -> float | None:
        return OUTPUT_RATES_HZ[(self.regs[_R["CONFIG_A"]] >> 2) & 0x07]

    @property
    def lsb_per_gauss(self) -> int:
        return GAINS_LSB_PER_GAUSS[self.regs[_R["CONFIG_B"]] >> 5]

    def peek(self, register: int | str) -> int:
        """A register's value without side effects (for tests)."""
        register = _R[register] if isinstance(register, str) else register
        return self.regs[register] if register < N_REGISTERS else 0

    def data_counts(self) -> tuple[int, int, int]:
        """(x, y, z) as the data registers hold them now (stored order X, Z, Y)."""
        raw = [int.from_bytes(self.regs[r:r + 2], "big", signed=True) for r in (0x03, 0x05, 0x07)]
        return raw[0], raw[2], raw[1]

    # ------------------------------------------------------------------ the sensor

    def set_field(self, x: int, y: int, z: int) -> None:
        """What the ADC measures from now on, counts at the configured gain (beyond
        -2048..2047 a measurement stores -4096 in that channel)."""
        self.field = (int(x), int(y), int(z))

    def _measure(self) -> None:
        if self.locked:
            return  # new data are not placed in locked registers
        x, y, z = (v if COUNT_MIN <= v <= COUNT_MAX else OVERFLOW for v in self.field)
        for register, value in ((0x03, x), (0x05, z), (0x07, y)):
            self.regs[register:register + 2] = (value & 0xFFFF).to_bytes(2, "big")
        self.regs[_R["STATUS"]] |= STATUS_RDY
        self.measurements += 1

    def _start_mode(self) -> None:
        measuring = self.mode in (MODE_CONTINUOUS, MODE_SINGLE)
        self._next_measurement_ms = self._now_ms + MEASUREMENT_MS if measuring else None

    def advance(self, ms: float) -> None:
        end = self._now_ms + ms
        while self._next_measurement_ms is not None and self._next_measurement_ms <= end:
            self._now_ms = self._next_measurement_ms
            self._measure()
            if self.mode == MODE_SINGLE:
                self.regs[_R["MODE"]] = (self.regs[_R["MODE"]] & ~0x03) | MODE_IDLE
                self._next_measurement_ms = None
            else:
                rate = self.output_rate_hz
                self._next_measurement_ms = None if rate is None else self._now_ms + 1000.0 / rate
        self._now_ms = end

    # ------------------------------------------------------------------ bus side

    def next_pointer(self, pointer: int) -> int:
        if pointer == 0x08:
            return 0x03
        if pointer >= 0x0C:
            return 0x00
        return pointer + 1

    def read_register(self, register: int) -> int:
        if register >= N_REGISTERS:
            return 0
        value = self.regs[register]
        if register in DATA:
            self._data_read.add(register)
            if len(self._data_read) == len(DATA):
                self._unlock()
            else:
                self.regs[_R["STATUS"]] |= STATUS_LOCK
        elif register == _R["MODE"]:
            self.regs[_R["STATUS"]] |= STATUS_LOCK
        return value

    def write_register(self, register: int, value: int) -> None:
        if register > _R["MODE"] or register in self.ignore_writes:
            return  # read-only or invalid: ignored
        self.regs[register] = value & 0xFF
        if register in (_R["CONFIG_A"], _R["MODE"]):
            self._unlock()
        if register == _R["MODE"]:
            self._start_mode()

    def _unlock(self) -> None:
        self.regs[_R["STATUS"]] &= ~STATUS_LOCK & 0xFF
        self._data_read.clear()
