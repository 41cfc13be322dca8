"""Register-level model of the InvenSense MPU-6050 (Register Map RM-MPU-6000A-00 rev 4.2,
Product Specification PS-MPU-6000A-00 rev 3.4).

What is modelled:

* the register file with the reset values of the register map (0x00 everywhere except
  PWR_MGMT_1 = 0x40, the chip asleep, and WHO_AM_I = 0x68); read-only registers ignore
  writes, addresses outside the map read 0 and ignore writes;
* burst access: the register pointer auto-increments after every byte;
* PWR_MGMT_1.DEVICE_RESET: every register returns to its reset value at once; the bit
  reads 1 until the reset completes after ``reset_ms`` of bus time (the data sheets
  give no duration; the PS's 100 ms start-up time is what a driver waits);
* SLEEP: the data registers only follow the values a test sets while the chip is
  awake; asleep (after power-on and after a reset) they keep what they had;
* the data registers ACCEL_XOUT_H .. GYRO_ZOUT_L (big-endian int16 counts), filled
  from :meth:`MPU6050.set_sample`;
* INT_STATUS.DATA_RDY_INT (set by a new sample when INT_ENABLE.DATA_RDY_EN is set,
  cleared by reading INT_STATUS, or by any read when INT_PIN_CFG.INT_RD_CLEAR is set);
* the bypass switch: the chips on :attr:`MPU6050.aux_bus` are visible on the main bus
  exactly when INT_PIN_CFG.I2C_BYPASS_EN = 1 and USER_CTRL.I2C_MST_EN = 0.

Not modelled: sampling timing and the sample-rate divider (each :meth:`set_sample` is
a sample), the digital low-pass filter, self test, FIFO, the I2C master, motion
interrupts, the INT pin's electrical level.

Failure injection: ``who_am_i`` (another chip, e.g. 0x70 for an MPU-6500),
``reset_ms=None`` (a reset that never completes), ``ignore_writes`` (registers that do
not keep what is written), ``stuck_bits`` (bits that always read 1).
"""
from __future__ import annotations

from imulink.board.chips.i2c import I2CBus, RegisterDevice

#: Register addresses by RM name (the rev 4.2 map).
REGISTERS = {
    "SELF_TEST_X": 0x0D, "SELF_TEST_Y": 0x0E, "SELF_TEST_Z": 0x0F, "SELF_TEST_A": 0x10,
    "SMPLRT_DIV": 0x19, "CONFIG": 0x1A, "GYRO_CONFIG": 0x1B, "ACCEL_CONFIG": 0x1C,
    "FIFO_EN": 0x23, "I2C_MST_CTRL": 0x24, "I2C_MST_STATUS": 0x36,
    "INT_PIN_CFG": 0x37, "INT_ENABLE": 0x38, "INT_STATUS": 0x3A,
    "ACCEL_XOUT_H": 0x3B, "TEMP_OUT_H": 0x41, "GYRO_XOUT_H": 0x43, "EXT_SENS_DATA_00": 0x49,
    "I2C_MST_DELAY_CTRL": 0x67, "SIGNAL_PATH_RESET": 0x68, "USER_CTRL": 0x6A,
    "PWR_MGMT_1": 0x6B, "PWR_MGMT_2": 0x6C, "FIFO_COUNTH": 0x72, "FIFO_COUNTL": 0x73,
    "FIFO_R_W": 0x74, "WHO_AM_I": 0x75,
}
_R = REGISTERS

#: Registers the host can write (the map's R/W registers, including the I2C master's 0x24..0x35).
WRITABLE = frozenset([*range(0x0D, 0x11), *range(0x19, 0x1D), 0x23, *range(0x24, 0x36), 0x37, 0x38,
                      *range(0x63, 0x69), 0x6A, 0x6B, 0x6C, 0x74])
#: Registers that only the chip writes.
READ_ONLY = frozenset([0x36, 0x3A, *range(0x3B, 0x61), 0x72, 0x73, 0x75])

#: Bits.
PWR_MGMT_1_DEVICE_RESET = 0x80
PWR_MGMT_1_SLEEP = 0x40
INT_PIN_CFG_INT_RD_CLEAR = 0x10
INT_PIN_CFG_I2C_BYPASS_EN = 0x02
INT_ENABLE_DATA_RDY_EN = 0x01
INT_STATUS_DATA_RDY_INT = 0x01
USER_CTRL_I2C_MST_EN = 0x20
#: USER_CTRL bits that are stored (FIFO_EN, I2C_MST_EN, I2C_IF_DIS); the reset bits clear themselves.
USER_CTRL_STORED = 0x70

#: Reset values that are not 0x00 (RM, register map introduction).
RESET_VALUES = {_R["PWR_MGMT_1"]: 0x40, _R["WHO_AM_I"]: 0x68}


class MPU6050(RegisterDevice):
    """The chip, with its auxiliary bus :attr:`aux_bus` behind the bypass switch.

    Args:
        who_am_i: what WHO_AM_I reads (0x68 for an MPU-6050).
        reset_ms: bus time a DEVICE_RESET takes; None: it never completes.
        ignore_writes: registers whose writes are dropped.
        stuck_bits: {register: bits} that read as 1 whatever is written.
    """

    def __init__(self, who_am_i: int = 0x68, reset_ms: float | None = 50.0,
                 ignore_writes=(), stuck_bits: dict[int, int] | None = None):
        super().__init__()
        self.aux_bus = I2CBus()
        self.who_am_i = who_am_i
        self.reset_ms = reset_ms
        self.ignore_writes = frozenset(ignore_writes)
        self.stuck_bits = dict(stuck_bits or {})
        self.acc: tuple[int, ...] = (0, 0, 0)  # register counts, as set_sample was given them
        self.gyro: tuple[int, ...] = (0, 0, 0)
        self.temperature = 0
        self.samples = 0
        self.power_on()

    # ------------------------------------------------------------------ state

    def power_on(self) -> None:
        """Power applied: reset values, pointer 0, no reset pending."""
        self.regs = bytearray(0x100)
        self._load_reset_values()
        self.pointer = 0
        self._reset_left_ms: float | None = 0.0

    def _load_reset_values(self) -> None:
        self.regs[:] = bytes(0x100)
        for register, value in RESET_VALUES.items():
            self.regs[register] = value
        self.regs[_R["WHO_AM_I"]] = self.who_am_i

    @property
    def resetting(self) -> bool:
        """DEVICE_RESET still reads 1."""
        return self._reset_left_ms is None or self._reset_left_ms > 0

    @property
    def asleep(self) -> bool:
        return bool(self.regs[_R["PWR_MGMT_1"]] & PWR_MGMT_1_SLEEP)

    @property
    def bypass_enabled(self) -> bool:
        """The auxiliary bus is connected to the main bus (RM register 55)."""
        return bool(self.peek("INT_PIN_CFG") & INT_PIN_CFG_I2C_BYPASS_EN) and \
            not self.peek("USER_CTRL") & USER_CTRL_I2C_MST_EN

    @property
    def data_ready_pending(self) -> bool:
        """INT_STATUS.DATA_RDY_INT is set (not yet cleared by a read)."""
        return bool(self.regs[_R["INT_STATUS"]] & INT_STATUS_DATA_RDY_INT)

    def peek(self, register: int | str) -> int:
        """A register's value as the bus would read it, without side effects (for tests)."""
        register = _R[register] if isinstance(register, str) else register
        value = self.regs[register] | self.stuck_bits.get(register, 0)
        if register == _R["PWR_MGMT_1"] and self.resetting:
            value |= PWR_MGMT_1_DEVICE_RESET
        return value & 0xFF

    # ------------------------------------------------------------------ the sensors

    def set_sample(self, acc=(0, 0, 0), gyro=(0, 0, 0), temperature: int = 0) -> None:
        """What the sensors measure now, as register counts (int16). Awake, the chip
        samples it at once: data registers updated, DATA_RDY_INT raised if enabled."""
        for value in (*acc, *gyro, temperature):
            if not -32768 <= int(value) <= 32767:
                raise ValueError(f"{value} is not an int16 count")
        self.acc = tuple(int(v) for v in acc)
        self.gyro = tuple(int(v) for v in gyro)
        self.temperature = int(temperature)
        self._sample()

    def _sample(self) -> None:
        if self.asleep or self.resetting:
            return
        values = (*self.acc, self.temperature, *self.gyro)
        for i, value in enumerate(values):
            self.regs[_R["ACCEL_XOUT_H"] + 2 * i: _R["ACCEL_XOUT_H"] + 2 * i + 2] = (value & 0xFFFF).to_bytes(2, "big")
        self.samples += 1
        if self.regs[_R["INT_ENABLE"]] & INT_ENABLE_DATA_RDY_EN:
            self.regs[_R["INT_STATUS"]] |= INT_STATUS_DATA_RDY_INT

    # ------------------------------------------------------------------ bus side

    def read_register(self, register: int) -> int:
        value = self.peek(register)
        if register == _R["INT_STATUS"] or self.regs[_R["INT_PIN_CFG"]] & INT_PIN_CFG_INT_RD_CLEAR:
            self.regs[_R["INT_STATUS"]] = 0
        return value

    def write_register(self, register: int, value: int) -> None:
        if register not in WRITABLE or register in self.ignore_writes:
            return
        if register == _R["PWR_MGMT_1"] and value & PWR_MGMT_1_DEVICE_RESET:
            self._load_reset_values()
            self._reset_left_ms = self.reset_ms
            return
        was_asleep = self.asleep
        if register == _R["USER_CTRL"]:
            value &= USER_CTRL_STORED
        self.regs[register] = value
        if was_asleep and not self.asleep:
            self._sample()  # awake: the sensors are sampled again

    def advance(self, ms: float) -> None:
        if self._reset_left_ms is not None and self._reset_left_ms > 0:
            self._reset_left_ms = max(0.0, self._reset_left_ms - ms)

    def downstream(self) -> I2CBus | None:
        return self.aux_bus if self.bypass_enabled else None

    def buses_behind(self) -> tuple[I2CBus, ...]:
        return (self.aux_bus,)
