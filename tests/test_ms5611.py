"""The MS5611 barometer driver (firmware/drivers/ms5611.c) against its data sheet and the
command-level chip model (imulink.board.chips.ms5611).

(a) the compensation: the data sheet's worked example, and the C driver against the
    model's independently written algorithm over the whole input range, second order
    (cold, very cold) included;
(b) the PROM: CRC-4 as the model computes it, a damaged word refused, zeros refused;
(c) the measurement cycle: never waits, each conversion given its time, the result read
    and compensated; failures reported and the cycle started again.
The strict-warning, header and no-floating-point builds of every driver are in
tests/test_drivers.py.
"""
from __future__ import annotations

import random
from pathlib import Path

import pytest

from cffi_module import build
from imulink.board.chips import STATUS_CODES, I2CBus
from imulink.board.chips import ms5611 as model

ROOT = Path(__file__).resolve().parents[1]
DRIVERS = ROOT / "firmware" / "drivers"
ADDRESS = 0x77

CDEF = """
    typedef enum { I2C_OK, ... } i2c_status_t;
    typedef struct {
        i2c_status_t (*write)(void *context, uint8_t address, const uint8_t *data, size_t len);
        i2c_status_t (*write_read)(void *context, uint8_t address, const uint8_t *write_data, size_t write_len,
                                   uint8_t *read_data, size_t read_len);
        void (*delay_ms)(void *context, uint32_t ms);
        void *context;
    } i2c_bus_t;
    typedef enum { SENSOR_CHIP_MS5611, ... } sensor_chip_t;
    typedef enum { SENSOR_OK, SENSOR_ERR_I2C, SENSOR_ERR_PROM_CRC, SENSOR_ERR_ADC, SENSOR_ERR_CONFIG,
                   ... } sensor_result_t;
    typedef struct {
        sensor_result_t result; sensor_chip_t chip; i2c_status_t i2c;
        uint8_t reg; uint8_t wrote; uint8_t count; uint8_t got[3]; uint8_t channels;
    } sensor_status_t;
    const char *sensor_status_text(const sensor_status_t *status, char *buf, size_t cap);
    typedef enum { MS5611_OSR_256, MS5611_OSR_512, MS5611_OSR_1024, MS5611_OSR_2048, MS5611_OSR_4096,
                   ... } ms5611_osr_t;
    typedef struct { int32_t pressure_pa; int32_t temperature_cdeg; uint32_t d1; uint32_t d2; } ms5611_reading_t;
    typedef struct { ...; } ms5611_t;
    sensor_status_t ms5611_init(ms5611_t *dev, const i2c_bus_t *bus, uint8_t address, ms5611_osr_t osr);
    sensor_status_t ms5611_poll(ms5611_t *dev, uint32_t now_us, ms5611_reading_t *out, int *ready);
    uint32_t ms5611_conversion_us(ms5611_osr_t osr);
    uint8_t ms5611_prom_crc(const uint16_t prom[8]);
    void ms5611_compensate(const uint16_t prom[8], uint32_t d1, uint32_t d2, ms5611_reading_t *out);
    extern "Python" i2c_status_t ms_i2c_write(void *, uint8_t, const uint8_t *, size_t);
    extern "Python" i2c_status_t ms_i2c_write_read(void *, uint8_t, const uint8_t *, size_t, uint8_t *, size_t);
    extern "Python" void ms_delay_ms(void *, uint32_t);
"""


@pytest.fixture(scope="module")
def drv(tmp_path_factory):
    module = build("_imulink_ms5611_driver", CDEF, '#include "ms5611.h"\n',
                   [DRIVERS / f for f in ("ms5611.c", "sensor_status.c", "i2c.c")], [DRIVERS],
                   tmp_path_factory.mktemp("ms5611"))
    mffi = module.ffi

    @mffi.def_extern()
    def ms_i2c_write(context, address, data, length):
        return STATUS_CODES[mffi.from_handle(context).bus.write(address, bytes(mffi.buffer(data, length)))]

    @mffi.def_extern()
    def ms_i2c_write_read(context, address, write_data, write_len, read_data, read_len):
        result = mffi.from_handle(context).bus.write_read(address, bytes(mffi.buffer(write_data, write_len)),
                                                          read_len)
        if isinstance(result, bytes):
            mffi.memmove(read_data, result, read_len)
            return STATUS_CODES["OK"]
        mffi.memmove(read_data, b"\xff" * read_len, read_len)
        return STATUS_CODES[result]

    @mffi.def_extern()
    def ms_delay_ms(context, ms):
        rig = mffi.from_handle(context)
        rig.bus.delay_ms(ms)
        rig.now_us += ms * 1000

    return module


class Rig:
    """An MS5611 model on a bus, the C driver talking to it, and the board's clock."""

    def __init__(self, drv, chip: model.MS5611 | None = None):
        self.ffi, self.lib = drv.ffi, drv.lib
        self.bus = I2CBus()
        self.chip = self.bus.attach(ADDRESS, chip or model.MS5611())
        self.now_us = 0
        self._handle = self.ffi.new_handle(self)
        self.i2c = self.ffi.new("i2c_bus_t *", {"write": self.lib.ms_i2c_write,
                                                "write_read": self.lib.ms_i2c_write_read,
                                                "delay_ms": self.lib.ms_delay_ms, "context": self._handle})
        self.dev = self.ffi.new("ms5611_t *")
        self.reading = self.ffi.new("ms5611_reading_t *")
        self.ready = self.ffi.new("int *")

    def init(self, osr: int = 4):
        return self.lib.ms5611_init(self.dev, self.i2c, ADDRESS, osr)

    def text(self, status) -> str:
        buf = self.ffi.new("char[]", 80)
        return self.ffi.string(self.lib.sensor_status_text(self.ffi.new("sensor_status_t *", status), buf, 80)).decode()

    def poll(self):
        return self.lib.ms5611_poll(self.dev, self.now_us & 0xFFFFFFFF, self.reading, self.ready)

    def wait(self, us: int) -> None:
        """The board's time passes (its loop does other work: no delay call of the driver)."""
        self.bus.advance(us / 1000.0)
        self.now_us += us


def compensate_c(drv, prom, d1, d2):
    out = drv.ffi.new("ms5611_reading_t *")
    drv.lib.ms5611_compensate(drv.ffi.new("uint16_t[8]", prom), d1, d2, out)
    return out.pressure_pa, out.temperature_cdeg


# --------------------------------------------------------------------------- (a) the compensation


def test_the_data_sheet_worked_example(drv):
    prom = [0, *model.EXAMPLE_C, 0]
    assert compensate_c(drv, prom, model.EXAMPLE_D1, model.EXAMPLE_D2) == (model.EXAMPLE_P, model.EXAMPLE_TEMP)
    assert model.compensate(model.EXAMPLE_C, model.EXAMPLE_D1, model.EXAMPLE_D2) == (
        model.EXAMPLE_P, model.EXAMPLE_TEMP)


def test_compensation_equals_the_model_over_the_whole_range(drv):
    """Any 16-bit coefficients and 24-bit conversions, the extremes included: the same
    integers (the second order's cold and very cold branches and negative dT among them)."""
    rng = random.Random(5611)
    cases = [(c, d1, d2) for c in ([0] * 6, [0xFFFF] * 6, list(model.EXAMPLE_C))
             for d1 in (0, 1, 0xFFFFFF, model.EXAMPLE_D1) for d2 in (0, 0xFFFFFF, model.EXAMPLE_D2)]
    cases += [([rng.randrange(1 << 16) for _ in range(6)], rng.randrange(1 << 24), rng.randrange(1 << 24))
              for _ in range(3000)]
    branches = set()
    for c, d1, d2 in cases:
        expected = model.compensate(c, d1, d2)
        assert compensate_c(drv, [0, *c, 0], d1, d2) == expected, (c, d1, d2)
        first_order_temp = 2000 + int((d2 - c[4] * 256) * c[5] / 2**23)
        branches.add("very cold" if first_order_temp < -1500 else "cold" if first_order_temp < 2000 else "warm")
    assert branches == {"warm", "cold", "very cold"}


# --------------------------------------------------------------------------- (b) the PROM


def test_prom_crc_is_the_models_and_a_damaged_prom_is_refused(drv):
    rng = random.Random(7)
    for _ in range(200):
        words = model.MS5611.with_coefficients([rng.randrange(1, 1 << 16) for _ in range(6)],
                                               factory=rng.randrange(1 << 16), serial=rng.randrange(1 << 12))
        assert drv.lib.ms5611_prom_crc(drv.ffi.new("uint16_t[8]", words)) == words[7] & 0xF == model.prom_crc(words)
    rig = Rig(drv)
    assert rig.init().result == drv.lib.SENSOR_OK
    damaged = list(rig.chip.prom)
    damaged[3] ^= 0x0100  # one bit of C3
    rig = Rig(drv, model.MS5611(damaged))
    status = rig.init()
    assert status.result == drv.lib.SENSOR_ERR_PROM_CRC
    assert rig.text(status) == (f"MS5611: PROM CRC-4 is 0x0{damaged[7] & 0xF:X}, its contents give "
                                f"0x0{model.prom_crc(damaged):X}")


def test_a_prom_read_before_the_reload_is_refused(drv):
    """Eight zero words have a valid CRC: the driver refuses them as no calibration."""
    rig = Rig(drv, model.MS5611([0] * 8))
    status = rig.init()
    assert status.result == drv.lib.SENSOR_ERR_PROM_CRC
    assert rig.text(status) == "MS5611: PROM holds no calibration (coefficients all zero)"


def test_init_resets_and_waits_for_the_reload(drv):
    rig = Rig(drv)
    assert rig.init().result == drv.lib.SENSOR_OK
    writes = [t for t in rig.bus.log if t.kind == "write"]
    assert writes[0].data == bytes([0x1E])
    delays = [t for t in rig.bus.log if t.kind == "delay"]
    assert delays and delays[0].ms >= 2.8  # the PROM reload: the model gives zeros before it ends


# --------------------------------------------------------------------------- (c) the measurement cycle


@pytest.mark.parametrize("osr", range(5))
def test_a_cycle_gives_each_conversion_its_time_and_never_waits(drv, osr):
    rig = Rig(drv)
    rig.chip.d1, rig.chip.d2 = 8_000_000, 8_600_000
    assert rig.init(osr).result == drv.lib.SENSOR_OK
    conversion = drv.lib.ms5611_conversion_us(osr)
    assert conversion == (600, 1170, 2280, 4540, 9040)[osr]
    delays_before = sum(1 for t in rig.bus.log if t.kind == "delay")
    results = []
    for _ in range(3 * 2 * conversion // 100 + 10):  # polled every 100 us for three cycles
        status = rig.poll()
        assert status.result == drv.lib.SENSOR_OK, rig.text(status)
        if rig.ready[0]:
            results.append((rig.reading.pressure_pa, rig.reading.temperature_cdeg, rig.now_us))
        rig.wait(100)
    assert sum(1 for t in rig.bus.log if t.kind == "delay") == delays_before  # polling never waits
    assert len(results) >= 2
    assert all(r[:2] == model.compensate(model.EXAMPLE_C, 8_000_000, 8_600_000) for r in results)
    assert rig.chip.conversions[:2] == [0x40 + 2 * osr, 0x50 + 2 * osr]
    # a cycle is D1's then D2's conversion time, each rounded up to the next poll
    assert results[1][2] - results[0][2] <= 2 * (conversion + 100) + 100


def test_a_read_too_early_or_after_a_reset_is_an_adc_error_and_the_cycle_starts_again(drv):
    rig = Rig(drv)
    assert rig.init(4).result == drv.lib.SENSOR_OK
    assert rig.poll().result == drv.lib.SENSOR_OK  # D1 started
    rig.chip.i2c_write(bytes([0x1E]))  # the chip resets under the driver (brown-out)
    rig.wait(9040)
    status = rig.poll()
    assert status.result == drv.lib.SENSOR_ERR_ADC and not rig.ready[0]
    assert rig.text(status) == "MS5611: ADC read 0 after command 0x48 (no conversion result)"
    rig.wait(3000)  # the PROM reloaded; the next call starts a new cycle
    for _ in range(30):
        assert rig.poll().result == drv.lib.SENSOR_OK
        if rig.ready[0]:
            break
        rig.wait(1000)
    assert rig.ready[0] and rig.reading.pressure_pa == model.EXAMPLE_P


@pytest.mark.parametrize("failure", ["NACK_ADDRESS", "TIMEOUT"])
def test_an_i2c_failure_is_reported_and_the_cycle_starts_again(drv, failure):
    rig = Rig(drv)
    assert rig.init().result == drv.lib.SENSOR_OK
    rig.bus.inject(failure, ADDRESS)
    status = rig.poll()
    assert status.result == drv.lib.SENSOR_ERR_I2C and status.reg == 0x48
    assert rig.text(status).startswith("MS5611: ")
    ready = False
    for _ in range(40):
        assert rig.poll().result == drv.lib.SENSOR_OK
        ready = ready or bool(rig.ready[0])
        rig.wait(1000)
    assert ready


def test_an_absent_chip_and_an_unknown_oversampling_ratio(drv):
    rig = Rig(drv)
    rig.bus.detach(ADDRESS)
    status = rig.init()
    assert status.result == drv.lib.SENSOR_ERR_I2C and rig.text(status) == "MS5611: address not acknowledged"
    assert Rig(drv).init(5).result == drv.lib.SENSOR_ERR_CONFIG


def test_raw_for_inverts_the_compensation_across_the_chips_range():
    c = model.EXAMPLE_C
    d1, d2 = model.raw_for(c, model.EXAMPLE_P, model.EXAMPLE_TEMP)
    assert model.compensate(c, d1, d2) == (model.EXAMPLE_P, model.EXAMPLE_TEMP)
    # near the data sheet's example: one Pa spans 53 counts of D1, a hundredth of a degree
    # 3 counts of D2 with these coefficients (any of them gives the same values)
    assert abs(d1 - model.EXAMPLE_D1) <= 2 * 53 and abs(d2 - model.EXAMPLE_D2) <= 2 * 3
    for pressure in (30_000, 70_000, 101_325, 110_000):      # within the data sheet's 10-1200 mbar
        for temp in (-3500, -1600, 1500, 2500, 8000):         # below -15 degC and below 20 degC: second order
            p, t = model.compensate(c, *model.raw_for(c, pressure, temp))
            assert abs(p - pressure) <= 1 and abs(t - temp) <= 1
    with pytest.raises(ValueError):
        model.raw_for(c, 101_325, 40_000)  # 400 degC: beyond D2's 24 bits
