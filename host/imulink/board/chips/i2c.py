"""An I2C bus model: chips by 7-bit address, the two transfers of firmware/drivers/i2c.h,
time, and failure injection.

The transfers match the C interface (``i2c_bus_t``):

* :meth:`I2CBus.write` -- START, address + write, bytes, STOP;
* :meth:`I2CBus.write_read` -- START, address + write, bytes, repeated START,
  address + read, ``n`` bytes, STOP;
* :meth:`I2CBus.delay_ms` -- time passes for every chip (also those behind a switch).

A transfer returns a status name (:data:`STATUS_CODES`: "OK", "NACK_ADDRESS", ...) or,
for a successful ``write_read``, the bytes read. A chip that is absent, or not
reachable because the switch in front of it is open (the MPU6050's bypass), does not
acknowledge its address. :meth:`I2CBus.inject` makes transfers fail on purpose: data
not acknowledged, a timeout, a bus error, a chip that stops answering after N
transfers. An injected failure aborts the transfer before the chip sees it.

Chips are :class:`I2CDevice` objects; :class:`RegisterDevice` is the common kind with a
register file and a register pointer (the first byte written sets the pointer, further
bytes are written from there on; reads start at the pointer; after every byte the
pointer moves by the chip's own rule, :meth:`RegisterDevice.next_pointer`).
Every transfer is logged in :attr:`I2CBus.log` (delays too) so tests can check what a
driver did.
"""
from __future__ import annotations

from dataclasses import dataclass

#: Transfer results by name, with the value of ``i2c_status_t`` in firmware/drivers/i2c.h.
STATUS_CODES = {
    "OK": 0,
    "NACK_ADDRESS": -1,  # nobody acknowledged the address
    "NACK_DATA": -2,  # the chip refused a data byte
    "TIMEOUT": -3,  # the transfer did not complete in time
    "BUS": -4,  # misplaced START/STOP
    "ARBITRATION": -5,  # arbitration lost
}
#: The names :meth:`I2CBus.inject` accepts.
FAILURES = frozenset(STATUS_CODES) - {"OK"}


class I2CDevice:
    """A chip on a bus. The bus has matched the address before it calls these."""

    def i2c_write(self, data: bytes) -> None:
        """The bytes of a write phase (after the address was acknowledged)."""
        raise NotImplementedError

    def i2c_read(self, n: int) -> bytes:
        """`n` bytes of a read phase."""
        raise NotImplementedError

    def advance(self, ms: float) -> None:
        """`ms` milliseconds pass."""

    def downstream(self) -> I2CBus | None:
        """A bus this chip connects to its own bus right now (a closed switch), or None."""
        return None

    def buses_behind(self) -> tuple[I2CBus, ...]:
        """Buses behind this chip, connected or not (time passes for their chips too)."""
        return ()


class RegisterDevice(I2CDevice):
    """A chip with registers addressed by a pointer (both chips of the GY-86).

    Subclasses implement :meth:`read_register`, :meth:`write_register` and, if their
    auto-increment is not plain +1, :meth:`next_pointer`.
    """

    def __init__(self):
        self.pointer = 0

    def i2c_write(self, data: bytes) -> None:
        if not data:
            return
        self.pointer = data[0]
        for value in data[1:]:
            self.write_register(self.pointer, value)
            self.pointer = self.next_pointer(self.pointer)

    def i2c_read(self, n: int) -> bytes:
        out = bytearray()
        for _ in range(n):
            out.append(self.read_register(self.pointer) & 0xFF)
            self.pointer = self.next_pointer(self.pointer)
        return bytes(out)

    def next_pointer(self, pointer: int) -> int:
        """The pointer after an access to `pointer`."""
        return (pointer + 1) & 0xFF

    def read_register(self, register: int) -> int:
        """Value of `register` as the bus reads it (side effects allowed: clear-on-read)."""
        raise NotImplementedError

    def write_register(self, register: int, value: int) -> None:
        """A byte written to `register` (read-only and unknown registers ignore it)."""
        raise NotImplementedError


@dataclass
class Fault:
    """A failure injected with :meth:`I2CBus.inject` (see there)."""

    status: str
    address: int | None
    after: int
    count: int | None
    seen: int = 0
    fired: int = 0

    def matches(self, address: int) -> bool:
        return self.address is None or self.address == address

    def exhausted(self) -> bool:
        return self.count is not None and self.fired >= self.count


@dataclass(frozen=True)
class Transfer:
    """One logged bus operation.

    Attributes:
        kind: "write", "write_read" or "delay".
        address: 7-bit address (None for a delay).
        data: bytes written (empty for a delay).
        n_read: bytes asked for (0 for a write or a delay).
        result: status name, or the bytes read.
        ms: length of a delay (0 for a transfer).
    """

    kind: str
    address: int | None
    data: bytes
    n_read: int
    result: str | bytes
    ms: float = 0.0


class I2CBus:
    """Chips by 7-bit address, transfers, time and injected failures."""

    def __init__(self):
        self.devices: dict[int, I2CDevice] = {}
        self.time_ms = 0.0
        self.log: list[Transfer] = []
        self._faults: list[Fault] = []

    # ------------------------------------------------------------------ chips

    def attach(self, address: int, device: I2CDevice) -> I2CDevice:
        """Connect `device` at `address` (7-bit) and return it."""
        _check_address(address)
        if address in self.devices:
            raise ValueError(f"address 0x{address:02X} is taken")
        self.devices[address] = device
        return device

    def detach(self, address: int) -> I2CDevice:
        """Disconnect and return the chip at `address`."""
        return self.devices.pop(address)

    def find(self, address: int) -> I2CDevice | None:
        """The chip that acknowledges `address` now: on this bus or behind a closed switch."""
        if address in self.devices:
            return self.devices[address]
        for device in self.devices.values():
            behind = device.downstream()
            if behind is not None:
                found = behind.find(address)
                if found is not None:
                    return found
        return None

    # ------------------------------------------------------------------ failures

    def inject(self, status: str, address: int | None = None, after: int = 0, count: int | None = 1) -> Fault:
        """Make transfers fail with `status`.

        Args:
            status: one of :data:`FAILURES` ("NACK_ADDRESS" makes a chip vanish).
            address: only transfers to this address (None: to any address).
            after: this many matching transfers succeed first (counted from now).
            count: that many transfers fail, then the bus behaves again; None: all
                further ones fail (a chip that stops answering).
        """
        if status not in FAILURES:
            raise ValueError(f"unknown failure {status!r}; one of {sorted(FAILURES)}")
        if address is not None:
            _check_address(address)
        fault = Fault(status, address, after, count)
        self._faults.append(fault)
        return fault

    def clear_faults(self) -> None:
        """Remove every injected failure."""
        self._faults.clear()

    def _injected(self, address: int) -> str | None:
        status = None
        for fault in self._faults:
            if not fault.matches(address) or fault.exhausted():
                continue
            fault.seen += 1
            if status is None and fault.seen > fault.after:
                fault.fired += 1
                status = fault.status
        return status

    # ------------------------------------------------------------------ transfers

    def write(self, address: int, data: bytes) -> str:
        """START, address + write, `data`, STOP. Returns a status name."""
        _check_address(address)
        data = bytes(data)
        status = self._injected(address)
        if status is None:
            device = self.find(address)
            if device is None:
                status = "NACK_ADDRESS"
            else:
                device.i2c_write(data)
                status = "OK"
        self.log.append(Transfer("write", address, data, 0, status))
        return status

    def write_read(self, address: int, data: bytes, n: int) -> bytes | str:
        """START, address + write, `data`, repeated START, address + read, `n` (>= 1) bytes,
        STOP. Returns the bytes read, or a status name when the transfer failed."""
        _check_address(address)
        if n < 1:
            raise ValueError("a read phase reads at least one byte")
        data = bytes(data)
        result: bytes | str | None = self._injected(address)
        if result is None:
            device = self.find(address)
            if device is None:
                result = "NACK_ADDRESS"
            else:
                device.i2c_write(data)
                result = device.i2c_read(n)
        self.log.append(Transfer("write_read", address, data, n, result))
        return result

    def delay_ms(self, ms: float) -> None:
        """Wait: time passes for every chip, including those behind an open switch."""
        if ms < 0:
            raise ValueError("negative delay")
        self.advance(ms)
        self.log.append(Transfer("delay", None, b"", 0, "OK", ms))

    def advance(self, ms: float) -> None:
        """Time passes (without a log entry): the bus's clock and every chip's."""
        self.time_ms += ms
        for device in list(self.devices.values()):
            device.advance(ms)
            for behind in device.buses_behind():
                behind.advance(ms)

    # ------------------------------------------------------------------ inspection

    def register_writes(self, address: int) -> list[tuple[int, int]]:
        """(register, value) of every successful write transfer to `address`, in order
        (a write of several bytes gives consecutive registers)."""
        out: list[tuple[int, int]] = []
        for t in self.log:
            if t.kind == "write" and t.address == address and t.result == "OK" and len(t.data) > 1:
                out.extend((t.data[0] + i, v) for i, v in enumerate(t.data[1:]))
        return out

    def transfers(self, address: int | None = None) -> list[Transfer]:
        """Logged transfers (no delays), to `address` if given."""
        return [t for t in self.log if t.kind != "delay" and (address is None or t.address == address)]


def _check_address(address: int) -> None:
    if not 0 <= address <= 0x7F:
        raise ValueError(f"0x{address:X} is not a 7-bit I2C address")
