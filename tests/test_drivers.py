"""The GY-86 sensor drivers (firmware/drivers) against register-level chip models.

The C drivers are compiled at test time into a cffi module (out-of-line API mode) whose
i2c_bus_t is implemented by `extern "Python"` callbacks on an imulink.board.chips.I2CBus
carrying an MPU6050 model with an HMC5883L model on its auxiliary bus (the GY-86).

Sections:
  (a) the chip models themselves, against their data sheets;
  (b) the drivers: configuration written, samples and axes, scale constants;
  (c) every failure: status, text, bounded return;
  (d) builds: strict warnings, self-contained headers, no platform headers, no floating
      point (x86-64 and Cortex-M4: arm-none-eabi-gcc is required, the test fails without it).
"""
from __future__ import annotations

import platform
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from cffi_module import build
from imulink.board.chips import FAILURES, HMC5883L, MPU6050, STATUS_CODES, I2CBus
from imulink.board.chips import hmc5883l as hmc_model
from imulink.core import to_fixed
from imulink.core.counts import STANDARD_GRAVITY, SensorProfile

ROOT = Path(__file__).resolve().parents[1]
DRIVERS = ROOT / "firmware" / "drivers"
CORE = ROOT / "firmware" / "core"
DRIVER_SOURCES = sorted(DRIVERS.glob("*.c"))
DRIVER_HEADERS = sorted(DRIVERS.glob("*.h"))
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
GCC = shutil.which("gcc")
ARM_GCC = "arm-none-eabi-gcc"
ARM_NM = "arm-none-eabi-nm"

MPU_ADDRESS = 0x68
HMC_ADDRESS = 0x1E

#: Data-sheet sensitivities, indexed by the register field value (FS_SEL, AFS_SEL, GN).
GYRO_LSB_PER_DPS = (131.0, 65.5, 32.8, 16.4)
ACC_LSB_PER_G = (16384.0, 8192.0, 4096.0, 2048.0)
MAG_LSB_PER_GAUSS = (1370, 1090, 820, 660, 440, 390, 330, 230)

# --------------------------------------------------------------------------- the cffi module

CDEF = """
    typedef int32_t imu_real_t;
    typedef struct { int16_t gyr[3]; int16_t acc[3]; int16_t mag[3]; } imu_raw_sample_t;
    typedef struct { imu_real_t gyro_scale; imu_real_t acc_scale; imu_real_t mag_scale; int16_t gyro_limits[2];
                     int16_t acc_limits[2]; int16_t mag_limits[2]; } imu_sensor_settings_t;
    typedef struct { int32_t gyr[3]; int32_t acc[3]; int32_t mag[3]; unsigned clipped; } imu_sample_t;
    #define IMU_CLIPPED_MAG ...
    extern const imu_sensor_settings_t imu_sensor_default_settings;
    void imu_sample_from_raw(const imu_sensor_settings_t *settings, const imu_raw_sample_t *raw,
                             imu_sample_t *out, uint32_t *sat);

    typedef enum { I2C_OK, I2C_ERR_NACK_ADDRESS, I2C_ERR_NACK_DATA, I2C_ERR_TIMEOUT, I2C_ERR_BUS,
                   I2C_ERR_ARBITRATION, ... } i2c_status_t;
    typedef struct {
        i2c_status_t (*write)(void *context, uint8_t address, const uint8_t *data, size_t len);
        i2c_status_t (*write_read)(void *context, uint8_t address, const uint8_t *write_data, size_t write_len,
                                   uint8_t *read_data, size_t read_len);
        void (*delay_ms)(void *context, uint32_t ms);
        void *context;
    } i2c_bus_t;
    const char *i2c_status_text(i2c_status_t status);

    typedef enum { SENSOR_CHIP_MPU6050, SENSOR_CHIP_HMC5883L, ... } sensor_chip_t;
    typedef enum { SENSOR_OK, SENSOR_MAG_OVERFLOW, SENSOR_ERR_I2C, SENSOR_ERR_IDENTITY, SENSOR_ERR_READBACK,
                   SENSOR_ERR_RESET, SENSOR_ERR_CONFIG, ... } sensor_result_t;
    #define SENSOR_CHANNEL_X ...
    #define SENSOR_CHANNEL_Y ...
    #define SENSOR_CHANNEL_Z ...
    #define SENSOR_STATUS_TEXT_SIZE ...
    typedef struct {
        sensor_result_t result; sensor_chip_t chip; i2c_status_t i2c;
        uint8_t reg; uint8_t wrote; uint8_t count; uint8_t got[3]; uint8_t channels;
    } sensor_status_t;
    const char *sensor_status_text(const sensor_status_t *status, char *buf, size_t cap);

    typedef enum { MPU6050_GYRO_250DPS, MPU6050_GYRO_500DPS, MPU6050_GYRO_1000DPS, MPU6050_GYRO_2000DPS,
                   ... } mpu6050_gyro_range_t;
    typedef enum { MPU6050_ACC_2G, MPU6050_ACC_4G, MPU6050_ACC_8G, MPU6050_ACC_16G,
                   ... } mpu6050_acc_range_t;
    typedef struct {
        mpu6050_gyro_range_t gyro_range; mpu6050_acc_range_t acc_range;
        uint8_t dlpf_cfg; uint8_t sample_rate_div; uint8_t data_ready_interrupt;
    } mpu6050_config_t;
    typedef struct { int16_t acc[3]; int16_t temperature; int16_t gyr[3]; } mpu6050_sample_t;
    typedef struct { ...; } mpu6050_t;
    sensor_status_t mpu6050_init(mpu6050_t *mpu, const i2c_bus_t *bus, uint8_t address,
                                 const mpu6050_config_t *config);
    sensor_status_t mpu6050_set_bypass(mpu6050_t *mpu, int enable);
    sensor_status_t mpu6050_read(mpu6050_t *mpu, mpu6050_sample_t *sample);
    uint8_t mpu6050_dlpf_for_rate(uint32_t sample_rate_hz);
    uint32_t mpu6050_sample_rate_mhz(const mpu6050_config_t *config);
    imu_real_t mpu6050_gyro_scale(mpu6050_gyro_range_t range);
    imu_real_t mpu6050_acc_scale(mpu6050_acc_range_t range);

    typedef enum { HMC5883L_AVERAGE_1, HMC5883L_AVERAGE_2, HMC5883L_AVERAGE_4, HMC5883L_AVERAGE_8,
                   ... } hmc5883l_averaging_t;
    typedef enum { HMC5883L_RATE_0_75HZ, HMC5883L_RATE_15HZ, HMC5883L_RATE_75HZ, ... } hmc5883l_rate_t;
    typedef enum { HMC5883L_BIAS_NONE, HMC5883L_BIAS_POSITIVE, HMC5883L_BIAS_NEGATIVE, ... } hmc5883l_bias_t;
    typedef enum { HMC5883L_GAIN_1370, HMC5883L_GAIN_1090, HMC5883L_GAIN_820, HMC5883L_GAIN_230,
                   ... } hmc5883l_gain_t;
    typedef struct {
        hmc5883l_averaging_t averaging; hmc5883l_rate_t rate; hmc5883l_bias_t bias; hmc5883l_gain_t gain;
    } hmc5883l_config_t;
    typedef struct { ...; } hmc5883l_t;
    #define HMC5883L_OVERFLOW ...
    sensor_status_t hmc5883l_init(hmc5883l_t *mag, const i2c_bus_t *bus, uint8_t address,
                                  const hmc5883l_config_t *config);
    sensor_status_t hmc5883l_read(hmc5883l_t *mag, int16_t xyz[3]);
    uint16_t hmc5883l_lsb_per_gauss(hmc5883l_gain_t gain);
    imu_real_t hmc5883l_mag_scale(hmc5883l_gain_t gain);

    typedef struct { mpu6050_config_t mpu; hmc5883l_config_t mag; } gy86_config_t;
    typedef struct { mpu6050_t mpu; hmc5883l_t mag; } gy86_t;
    extern const gy86_config_t gy86_default_config;
    sensor_status_t gy86_init(gy86_t *gy, const i2c_bus_t *bus, const gy86_config_t *config);
    sensor_status_t gy86_read(gy86_t *gy, imu_raw_sample_t *raw, int16_t *temperature);
    void gy86_sensor_settings(const gy86_config_t *config, imu_sensor_settings_t *settings);

    extern "Python" i2c_status_t py_i2c_write(void *, uint8_t, const uint8_t *, size_t);
    extern "Python" i2c_status_t py_i2c_write_read(void *, uint8_t, const uint8_t *, size_t, uint8_t *, size_t);
    extern "Python" void py_delay_ms(void *, uint32_t);
"""


@pytest.fixture(scope="session")
def drv(tmp_path_factory):
    """The drivers (and the core's sensor conversion) compiled into a cffi module."""
    module = build("_imulink_gy86_drivers", CDEF, '#include "gy86.h"\n#include "imu_sensor.h"\n',
                   [*DRIVER_SOURCES, CORE / "imu_sensor.c"], [DRIVERS, CORE], tmp_path_factory.mktemp("drivers"),
                   define_macros=[("IMU_FIXED", "1")])
    mffi = module.ffi

    @mffi.def_extern()
    def py_i2c_write(context, address, data, length):
        rig = mffi.from_handle(context)
        try:
            return STATUS_CODES[rig.bus.write(address, bytes(mffi.buffer(data, length)))]
        except BaseException as exc:  # never let a model bug look like I2C_OK to the driver
            rig.errors.append(exc)
            return STATUS_CODES["BUS"]

    @mffi.def_extern()
    def py_i2c_write_read(context, address, write_data, write_len, read_data, read_len):
        rig = mffi.from_handle(context)
        try:
            result = rig.bus.write_read(address, bytes(mffi.buffer(write_data, write_len)), read_len)
            if isinstance(result, bytes):
                mffi.memmove(read_data, result, read_len)
                return STATUS_CODES["OK"]
            # What a failed read leaves: the released bus reads ones. A driver must not use it.
            mffi.memmove(read_data, b"\xff" * read_len, read_len)
            return STATUS_CODES[result]
        except BaseException as exc:
            rig.errors.append(exc)
            return STATUS_CODES["BUS"]

    @mffi.def_extern()
    def py_delay_ms(context, ms):
        rig = mffi.from_handle(context)
        try:
            rig.bus.delay_ms(ms)
        except BaseException as exc:
            rig.errors.append(exc)

    return module


class Rig:
    """A GY-86 model on a bus, and the C drivers talking to it.

    `mpu`/`hmc`: the chip models to use (None: default ones; False: the chip is absent;
    without an MPU6050 the HMC5883L sits on the main bus).
    """

    def __init__(self, drv, mpu: MPU6050 | bool | None = None, hmc: HMC5883L | bool | None = None):
        self.ffi, self.lib = drv.ffi, drv.lib
        self.bus = I2CBus()
        self.mpu = self.bus.attach(MPU_ADDRESS, mpu or MPU6050()) if mpu is not False else None
        if hmc is not False:
            self.hmc = hmc or HMC5883L()
            (self.mpu.aux_bus if self.mpu is not None else self.bus).attach(HMC_ADDRESS, self.hmc)
        self.errors: list[BaseException] = []
        self._handle = self.ffi.new_handle(self)
        self.c_bus = self.ffi.new("i2c_bus_t *")
        self.c_bus.write = self.lib.py_i2c_write
        self.c_bus.write_read = self.lib.py_i2c_write_read
        self.c_bus.delay_ms = self.lib.py_delay_ms
        self.c_bus.context = self._handle
        self.gy = self.ffi.new("gy86_t *")
        self.config = self.ffi.new("gy86_config_t *")
        self.config[0] = self.lib.gy86_default_config

    def _checked(self, status):
        if self.errors:
            raise self.errors.pop(0)
        return status

    def init(self):
        return self._checked(self.lib.gy86_init(self.gy, self.c_bus, self.config))

    def read(self):
        """(status, raw sample, temperature); the outputs are pre-filled with a marker
        so that "unchanged on failure" is visible."""
        raw = self.ffi.new("imu_raw_sample_t *", {"gyr": [111] * 3, "acc": [111] * 3, "mag": [111] * 3})
        temperature = self.ffi.new("int16_t *", 111)
        status = self._checked(self.lib.gy86_read(self.gy, raw, temperature))
        return status, raw, temperature[0]

    def text(self, status) -> str:
        buf = self.ffi.new("char[]", self.lib.SENSOR_STATUS_TEXT_SIZE)
        return self.ffi.string(self.lib.sensor_status_text(self.ffi.addressof(status), buf, len(buf))).decode()

    def delays(self) -> list[float]:
        return [t.ms for t in self.bus.log if t.kind == "delay"]


@pytest.fixture
def rig(drv):
    return Rig(drv)


def ready_rig(drv, **kwargs) -> Rig:
    """A rig whose GY-86 was brought up with the default configuration."""
    r = Rig(drv, **kwargs)
    status = r.init()
    assert status.result == r.lib.SENSOR_OK, r.text(status)
    return r


def be16(value: int) -> bytes:
    return (value & 0xFFFF).to_bytes(2, "big")


# =========================================================================== (a) the chip models


def test_status_names_match_i2c_h(drv):
    lib = drv.lib
    assert STATUS_CODES == {"OK": lib.I2C_OK, "NACK_ADDRESS": lib.I2C_ERR_NACK_ADDRESS,
                            "NACK_DATA": lib.I2C_ERR_NACK_DATA, "TIMEOUT": lib.I2C_ERR_TIMEOUT,
                            "BUS": lib.I2C_ERR_BUS, "ARBITRATION": lib.I2C_ERR_ARBITRATION}
    assert FAILURES == set(STATUS_CODES) - {"OK"}


def test_bus_absent_chip_and_injected_failures():
    bus = I2CBus()
    mpu = bus.attach(MPU_ADDRESS, MPU6050())
    assert bus.write_read(0x69, b"\x75", 1) == "NACK_ADDRESS"
    assert bus.write(0x69, b"\x6b\x00") == "NACK_ADDRESS"
    # one NACK on data, after two good transfers; the aborted write never reaches the chip
    bus.inject("NACK_DATA", MPU_ADDRESS, after=2)
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == b"\x68"
    assert bus.write(0x50, b"\x00") == "NACK_ADDRESS"  # other addresses do not count
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == b"\x68"
    assert bus.write(MPU_ADDRESS, b"\x19\x07") == "NACK_DATA"
    assert mpu.peek("SMPLRT_DIV") == 0
    assert bus.write(MPU_ADDRESS, b"\x19\x07") == "OK" and mpu.peek("SMPLRT_DIV") == 7
    # timeout and bus error on any address, twice
    bus.inject("TIMEOUT", count=2)
    assert [bus.write_read(MPU_ADDRESS, b"\x75", 1), bus.write(0x11, b"\x00")] == ["TIMEOUT", "TIMEOUT"]
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == b"\x68"
    bus.inject("BUS")
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == "BUS"
    # a chip that stops answering after 3 transfers, for good
    bus.inject("NACK_ADDRESS", MPU_ADDRESS, after=3, count=None)
    assert [bus.write_read(MPU_ADDRESS, b"\x75", 1) for _ in range(6)] == [b"\x68"] * 3 + ["NACK_ADDRESS"] * 3
    bus.clear_faults()
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == b"\x68"
    with pytest.raises(ValueError):
        bus.inject("SMOKE")
    with pytest.raises(ValueError):
        bus.write(0x80, b"\x00")
    assert [t.result for t in bus.transfers(0x69)] == ["NACK_ADDRESS", "NACK_ADDRESS"]


def test_mpu6050_model_power_on_state_and_read_only_registers():
    bus = I2CBus()
    mpu = bus.attach(MPU_ADDRESS, MPU6050())
    # reset values: 0x00 except PWR_MGMT_1 (asleep) and WHO_AM_I
    assert bus.write_read(MPU_ADDRESS, b"\x6b", 1) == b"\x40"
    assert bus.write_read(MPU_ADDRESS, b"\x75", 1) == b"\x68"
    assert bus.write_read(MPU_ADDRESS, b"\x19", 4) == bytes(4)
    assert mpu.asleep and not mpu.bypass_enabled
    # asleep, the data registers do not follow the sensors
    mpu.set_sample(acc=(1, 2, 3), gyro=(4, 5, 6), temperature=7)
    assert bus.write_read(MPU_ADDRESS, b"\x3b", 14) == bytes(14)
    # waking samples them; a burst auto-increments over all 14 bytes, big-endian
    assert bus.write(MPU_ADDRESS, b"\x6b\x01") == "OK"
    assert bus.write_read(MPU_ADDRESS, b"\x3b", 14) == b"".join(be16(v) for v in (1, 2, 3, 7, 4, 5, 6))
    mpu.set_sample(acc=(-32768, 32767, -1), gyro=(0, -2, 2), temperature=-521)
    assert bus.write_read(MPU_ADDRESS, b"\x3b", 14) == b"".join(be16(v) for v in (-32768, 32767, -1, -521, 0, -2, 2))
    # read-only registers ignore writes; a multi-byte write fills consecutive registers
    assert bus.write(MPU_ADDRESS, b"\x75\x00") == "OK" and mpu.peek("WHO_AM_I") == 0x68
    assert bus.write(MPU_ADDRESS, b"\x3b\x12\x34") == "OK" and mpu.peek(0x3B) == 0x80
    assert bus.write(MPU_ADDRESS, b"\x19\x09\x03\x18\x10") == "OK"
    assert bus.write_read(MPU_ADDRESS, b"\x19", 4) == b"\x09\x03\x18\x10"
    with pytest.raises(ValueError):
        mpu.set_sample(acc=(40000, 0, 0))


def test_mpu6050_model_device_reset():
    bus = I2CBus()
    mpu = bus.attach(MPU_ADDRESS, MPU6050(reset_ms=50))
    bus.write(MPU_ADDRESS, b"\x6b\x01")
    bus.write(MPU_ADDRESS, b"\x37\x02")
    assert mpu.bypass_enabled
    bus.write(MPU_ADDRESS, b"\x6b\x80")
    # every register is back at its reset value at once (the bypass is off again) ...
    assert not mpu.bypass_enabled and mpu.peek("INT_PIN_CFG") == 0
    # ... and DEVICE_RESET reads 1 until the reset has taken its time
    assert bus.write_read(MPU_ADDRESS, b"\x6b", 1) == b"\xc0"
    bus.delay_ms(49)
    assert bus.write_read(MPU_ADDRESS, b"\x6b", 1) == b"\xc0"
    bus.delay_ms(1)
    assert bus.write_read(MPU_ADDRESS, b"\x6b", 1) == b"\x40"
    stuck = I2CBus()
    stuck.attach(MPU_ADDRESS, MPU6050(reset_ms=None))
    stuck.write(MPU_ADDRESS, b"\x6b\x80")
    stuck.delay_ms(10_000)
    assert stuck.write_read(MPU_ADDRESS, b"\x6b", 1) == b"\xc0"


def test_mpu6050_model_bypass_switch():
    bus = I2CBus()
    mpu = bus.attach(MPU_ADDRESS, MPU6050())
    mpu.aux_bus.attach(HMC_ADDRESS, HMC5883L())
    ident = b"\x0a"
    assert bus.write_read(HMC_ADDRESS, ident, 3) == "NACK_ADDRESS"
    bus.write(MPU_ADDRESS, b"\x37\x02")  # I2C_BYPASS_EN
    assert bus.write_read(HMC_ADDRESS, ident, 3) == b"H43"
    bus.write(MPU_ADDRESS, b"\x6a\x20")  # I2C_MST_EN: the switch opens whatever I2C_BYPASS_EN says
    assert bus.write_read(HMC_ADDRESS, ident, 3) == "NACK_ADDRESS"
    bus.write(MPU_ADDRESS, b"\x6a\x00")
    assert bus.write_read(HMC_ADDRESS, ident, 3) == b"H43"
    bus.write(MPU_ADDRESS, b"\x37\x00")
    assert bus.write_read(HMC_ADDRESS, ident, 3) == "NACK_ADDRESS"


def test_mpu6050_model_data_ready_status():
    bus = I2CBus()
    mpu = bus.attach(MPU_ADDRESS, MPU6050())
    bus.write(MPU_ADDRESS, b"\x6b\x01")
    mpu.set_sample()
    assert not mpu.data_ready_pending  # DATA_RDY_EN off
    bus.write(MPU_ADDRESS, b"\x38\x01")
    mpu.set_sample()
    assert mpu.data_ready_pending
    bus.write_read(MPU_ADDRESS, b"\x3b", 14)
    assert mpu.data_ready_pending  # INT_RD_CLEAR = 0: only reading INT_STATUS clears it
    assert bus.write_read(MPU_ADDRESS, b"\x3a", 1) == b"\x01"
    assert not mpu.data_ready_pending
    bus.write(MPU_ADDRESS, b"\x37\x10")  # INT_RD_CLEAR: any read clears
    mpu.set_sample()
    bus.write_read(MPU_ADDRESS, b"\x3b", 14)
    assert not mpu.data_ready_pending


def test_hmc5883l_model_registers_and_pointer_rules():
    bus = I2CBus()
    hmc = bus.attach(HMC_ADDRESS, HMC5883L())
    # reset values and identification (one burst 10, 11, 12)
    assert bus.write_read(HMC_ADDRESS, b"\x00", 3) == b"\x10\x20\x01"
    assert bus.write_read(HMC_ADDRESS, b"\x0a", 3) == b"H43"
    # after 12 the pointer goes to 0; after 8 back to 3
    assert bus.write_read(HMC_ADDRESS, b"\x0b", 4) == b"43\x10\x20"
    hmc.set_field(0x123, -0x234, 0x345)
    bus.write(HMC_ADDRESS, b"\x02\x00")
    bus.delay_ms(hmc_model.MEASUREMENT_MS)
    data = be16(0x123) + be16(0x345) + be16(-0x234)  # X, Z, Y
    assert bus.write_read(HMC_ADDRESS, b"\x03", 9) == data + data[:3]
    assert bus.write_read(HMC_ADDRESS, b"\x07", 4) == data[4:6] + data[0:2]
    assert hmc.data_counts() == (0x123, -0x234, 0x345)
    # without a new address the next read continues at the pointer
    hmc.pointer = 0x0A
    assert hmc.i2c_read(2) == b"H4"
    # read-only and invalid registers ignore writes and invalid ones read 0
    bus.write(HMC_ADDRESS, b"\x0a\x00")
    bus.write(HMC_ADDRESS, b"\x0d\x55")
    assert hmc.peek("IDENT_A") == ord("H") and bus.write_read(HMC_ADDRESS, b"\x0d", 1) == b"\x00"


def test_hmc5883l_model_measurement_modes_overflow_and_lock():
    bus = I2CBus()
    hmc = bus.attach(HMC_ADDRESS, HMC5883L())
    bus.delay_ms(10)  # the power-on single measurement, then idle (MD = 11)
    assert hmc.measurements == 1 and hmc.mode == 0b11
    bus.write(HMC_ADDRESS, b"\x00\x18")  # 75 Hz
    bus.write(HMC_ADDRESS, b"\x02\x00")  # continuous
    bus.delay_ms(5.5)
    assert hmc.measurements == 1
    bus.delay_ms(0.5)
    assert hmc.measurements == 2
    bus.delay_ms(1000 / 75 * 10 + 1)  # 10 more periods
    assert hmc.measurements == 12
    # beyond the output range a channel stores -4096; the next valid measurement clears it
    hmc.set_field(2048, -2048, 5)
    bus.delay_ms(1000 / 75)
    assert hmc.data_counts() == (hmc_model.OVERFLOW, -2048, 5)
    assert bus.write_read(HMC_ADDRESS, b"\x09", 1) == b"\x01"  # RDY
    # a partial read locks the data registers: new measurements are not stored
    bus.write_read(HMC_ADDRESS, b"\x03", 2)
    assert hmc.locked
    hmc.set_field(1, 2, 3)
    bus.delay_ms(100)
    assert hmc.data_counts() == (hmc_model.OVERFLOW, -2048, 5)
    assert bus.write_read(HMC_ADDRESS, b"\x09", 1) == b"\x03"  # LOCK | RDY
    bus.write_read(HMC_ADDRESS, b"\x05", 4)  # the remaining four: unlocked
    assert not hmc.locked
    bus.delay_ms(1000 / 75)
    assert hmc.data_counts() == (1, 2, 3)
    # reading the mode register locks too; writing it unlocks
    bus.write_read(HMC_ADDRESS, b"\x02", 1)
    assert hmc.locked
    bus.write(HMC_ADDRESS, b"\x02\x00")
    assert not hmc.locked


# =========================================================================== (b) the drivers


def test_i2c_status_text(drv):
    lib, ffi = drv.lib, drv.ffi
    texts = {name: ffi.string(lib.i2c_status_text(code)).decode() for name, code in STATUS_CODES.items()}
    assert texts == {"OK": "OK", "NACK_ADDRESS": "address not acknowledged", "NACK_DATA": "data not acknowledged",
                     "TIMEOUT": "timeout", "BUS": "bus error", "ARBITRATION": "arbitration lost"}
    assert ffi.string(lib.i2c_status_text(ffi.cast("i2c_status_t", 42))) == b"unknown I2C status"


def test_gy86_init_configures_both_chips(rig):
    lib = rig.lib
    status = rig.init()
    assert status.result == lib.SENSOR_OK and rig.text(status) == "HMC5883L: OK"
    mpu, hmc = rig.mpu, rig.hmc
    # MPU6050: awake on the X-gyro PLL, 100 Hz with DLPF_CFG 3, +-2000 deg/s, +-8 g
    assert mpu.peek("PWR_MGMT_1") == 0x01 and not mpu.asleep
    assert mpu.peek("SMPLRT_DIV") == 9 and mpu.peek("CONFIG") == 3
    assert mpu.peek("GYRO_CONFIG") == 3 << 3 and mpu.peek("ACCEL_CONFIG") == 2 << 3
    # data ready: active high, push-pull, pulse, cleared by any read; bypass on, master off
    assert mpu.peek("INT_PIN_CFG") == 0x10 | 0x02 and mpu.peek("INT_ENABLE") == 0x01
    assert mpu.peek("USER_CTRL") & 0x20 == 0 and mpu.bypass_enabled
    # HMC5883L: 1 sample, 75 Hz, normal measurement; 1090 LSB/gauss; continuous
    assert (hmc.peek("CONFIG_A"), hmc.peek("CONFIG_B"), hmc.peek("MODE")) == (0x18, 0x20, 0x00)
    assert hmc.output_rate_hz == 75.0 and hmc.lsb_per_gauss == 1090


def test_gy86_init_sequence(rig):
    """Identity before the first write; reset first; 100 ms after the reset; the HMC5883L
    only after the bypass; every configuration register read back."""
    rig.init()
    log = rig.bus.log
    mpu_transfers = rig.bus.transfers(MPU_ADDRESS)
    assert mpu_transfers[0].kind == "write_read" and mpu_transfers[0].data == b"\x75"
    assert mpu_transfers[1].kind == "write" and mpu_transfers[1].data == b"\x6b\x80"
    reset_at = log.index(mpu_transfers[1])
    waited = 0.0
    for t in log[reset_at + 1:]:
        if t.kind != "delay":
            break
        waited += t.ms
    assert waited >= 100
    writes = rig.bus.register_writes(MPU_ADDRESS)
    assert writes[:8] == [(0x6B, 0x80), (0x6B, 0x01), (0x19, 9), (0x1A, 3), (0x1B, 0x18), (0x1C, 0x10),
                          (0x37, 0x10), (0x38, 0x01)]
    assert writes[8:] == [(0x6A, 0x00), (0x37, 0x12)]
    read_back = {t.data[0] for t in mpu_transfers if t.kind == "write_read" and t.n_read == 1}
    assert {0x19, 0x1A, 0x1B, 0x1C, 0x37, 0x38, 0x6B, 0x6A} <= read_back
    hmc_transfers = rig.bus.transfers(HMC_ADDRESS)
    bypass_at = log.index(next(t for t in mpu_transfers if t.kind == "write" and t.data == b"\x37\x12"))
    assert log.index(hmc_transfers[0]) > bypass_at
    assert hmc_transfers[0].data == b"\x0a" and hmc_transfers[0].n_read == 3
    assert rig.bus.register_writes(HMC_ADDRESS) == [(0x00, 0x18), (0x01, 0x20), (0x02, 0x00)]
    assert hmc_transfers[-2].data == b"\x00" and hmc_transfers[-2].n_read == 3  # read-back of 0, 1, 2
    # reading the Mode register locked the data registers: one full read releases them
    assert hmc_transfers[-1].data == b"\x03" and hmc_transfers[-1].n_read == 6
    assert not rig.hmc.locked
    assert rig.delays()[-1] >= hmc_model.MEASUREMENT_MS


def test_gy86_read_sample_axes_and_temperature(drv):
    r = ready_rig(drv)
    r.mpu.set_sample(acc=(-120, 340, 4096), gyro=(-32768, 32767, 5), temperature=-3920)
    r.hmc.set_field(101, -202, 303)
    r.bus.delay_ms(20)
    status, raw, temperature = r.read()
    assert status.result == r.lib.SENSOR_OK
    assert list(raw.acc) == [-120, 340, 4096] and list(raw.gyr) == [-32768, 32767, 5]
    assert temperature == -3920
    # The documented GY-86 mapping (gy86.c): HMC5883L X, Y, Z are the MPU6050's x, y, z.
    # Distinct values per axis also prove the X, Z, Y register order is undone.
    assert list(raw.mag) == [101, -202, 303]
    # one burst per chip: 14 bytes from ACCEL_XOUT_H, 6 from Data Output X MSB
    last_two = r.bus.transfers()[-2:]
    assert [(t.address, t.data, t.n_read) for t in last_two] == [(MPU_ADDRESS, b"\x3b", 14), (HMC_ADDRESS, b"\x03", 6)]
    # the burst released the HMC5883L's data lock, so the next measurement arrives
    r.hmc.set_field(-1, -2, -3)
    r.bus.delay_ms(20)
    assert list(r.read()[1].mag) == [-1, -2, -3]


def test_gy86_read_clears_the_data_ready_interrupt(drv):
    r = ready_rig(drv)
    r.mpu.set_sample(acc=(0, 0, 4096))
    assert r.mpu.data_ready_pending
    assert r.read()[0].result == r.lib.SENSOR_OK
    assert not r.mpu.data_ready_pending  # INT_RD_CLEAR: the burst itself acknowledged it


def test_gy86_read_flat_board_through_the_core(drv):
    """Counts at the default ranges, converted by the core with gy86_sensor_settings: 1 g on z."""
    r = ready_rig(drv)
    lib, ffi = r.lib, r.ffi
    r.mpu.set_sample(acc=(0, 0, 4096), gyro=(164, 0, -164))  # 1 g; +-10 deg/s
    r.hmc.set_field(218, 0, -436)  # 0.2 and -0.4 gauss at 1090 LSB/gauss
    r.bus.delay_ms(20)
    status, raw, _ = r.read()
    settings = ffi.new("imu_sensor_settings_t *")
    lib.gy86_sensor_settings(r.config, settings)
    out, sat = ffi.new("imu_sample_t *"), ffi.new("uint32_t *")
    lib.imu_sample_from_raw(settings, raw, out, sat)
    assert out.acc[2] / 2**16 == pytest.approx(STANDARD_GRAVITY, abs=2e-4)
    assert out.gyr[0] / 2**24 == pytest.approx(0.17453, abs=1e-4) and out.gyr[2] < 0
    assert out.mag[0] / 2**16 == pytest.approx(20.0, abs=2e-3) and out.mag[2] / 2**16 == pytest.approx(-40.0, abs=4e-3)
    assert out.clipped == 0 and sat[0] == 0


def test_scale_constants_equal_the_hosts(drv):
    lib = drv.lib
    for fs, lsb in enumerate(GYRO_LSB_PER_DPS):
        assert lib.mpu6050_gyro_scale(fs) == to_fixed(SensorProfile(gyro_lsb_per_dps=lsb).gyro_scale, 40), lsb
    for afs, lsb in enumerate(ACC_LSB_PER_G):
        assert lib.mpu6050_acc_scale(afs) == to_fixed(SensorProfile(acc_lsb_per_g=lsb).acc_scale, 32), lsb
    for gn, lsb in enumerate(MAG_LSB_PER_GAUSS):
        assert lib.hmc5883l_lsb_per_gauss(gn) == lsb
        assert lib.hmc5883l_mag_scale(gn) == to_fixed(SensorProfile(mag_lsb_per_gauss=lsb).mag_scale, 24), lsb
    assert lib.mpu6050_gyro_scale(4) == 0 and lib.mpu6050_acc_scale(9) == 0 and lib.hmc5883l_mag_scale(8) == 0
    assert lib.hmc5883l_lsb_per_gauss(8) == 0


def test_default_configuration_matches_the_cores_default_settings(drv):
    ffi, lib = drv.ffi, drv.lib
    settings = ffi.new("imu_sensor_settings_t *")
    lib.gy86_sensor_settings(ffi.addressof(lib.gy86_default_config), settings)
    core = lib.imu_sensor_default_settings
    assert (settings.gyro_scale, settings.acc_scale, settings.mag_scale) == \
        (core.gyro_scale, core.acc_scale, core.mag_scale)
    for limits in ("gyro_limits", "acc_limits", "mag_limits"):  # the registers' ranges: the host profile's too
        assert list(getattr(settings, limits)) == list(getattr(core, limits)) == list(getattr(SensorProfile(), limits))
    broad = SensorProfile(acc_lsb_per_g=2048.0)  # the BROAD profile: +-16 g
    config = ffi.new("gy86_config_t *")
    config[0] = lib.gy86_default_config
    config.mpu.acc_range = lib.MPU6050_ACC_16G
    lib.gy86_sensor_settings(config, settings)
    assert settings.acc_scale == to_fixed(broad.acc_scale, 32)
    assert lib.mpu6050_sample_rate_mhz(ffi.addressof(lib.gy86_default_config.mpu)) == 100_000


def test_dlpf_for_rate_and_sample_rate(drv):
    lib, ffi = drv.lib, drv.ffi
    # widest bandwidth (max of gyro/accel: 260 188 98 44 21 10 5 Hz) strictly below rate / 2
    expected = {2000: 0, 521: 0, 520: 1, 400: 1, 377: 1, 376: 2, 200: 2, 197: 2, 196: 3, 100: 3, 89: 3, 88: 4,
                50: 4, 43: 4, 42: 5, 41: 5, 22: 5, 21: 5, 20: 6, 11: 6, 10: 6, 1: 6, 0: 6}
    assert {rate: lib.mpu6050_dlpf_for_rate(rate) for rate in expected} == expected
    config = ffi.new("mpu6050_config_t *", {"dlpf_cfg": 0, "sample_rate_div": 7})
    assert lib.mpu6050_sample_rate_mhz(config) == 1_000_000
    config.dlpf_cfg = 1
    assert lib.mpu6050_sample_rate_mhz(config) == 125_000
    config.sample_rate_div = 2
    assert lib.mpu6050_sample_rate_mhz(config) == 333_333


def test_other_ranges_reach_the_registers(drv):
    r = Rig(drv)
    r.config.mpu.gyro_range = r.lib.MPU6050_GYRO_250DPS
    r.config.mpu.acc_range = r.lib.MPU6050_ACC_16G
    r.config.mpu.dlpf_cfg = 6
    r.config.mpu.sample_rate_div = 199
    r.config.mpu.data_ready_interrupt = 0
    r.config.mag.averaging = r.lib.HMC5883L_AVERAGE_8
    r.config.mag.rate = r.lib.HMC5883L_RATE_15HZ
    r.config.mag.gain = r.lib.HMC5883L_GAIN_230
    assert r.init().result == r.lib.SENSOR_OK
    assert (r.mpu.peek("GYRO_CONFIG"), r.mpu.peek("ACCEL_CONFIG"), r.mpu.peek("CONFIG")) == (0x00, 0x18, 6)
    assert r.mpu.peek("SMPLRT_DIV") == 199 and r.mpu.peek("INT_ENABLE") == 0
    assert (r.hmc.peek("CONFIG_A"), r.hmc.peek("CONFIG_B")) == (0x70, 0xE0)
    assert r.hmc.output_rate_hz == 15.0 and r.hmc.lsb_per_gauss == 230


def test_bypass_can_be_switched_off_again(drv):
    r = ready_rig(drv)
    mpu_state = r.ffi.addressof(r.gy.mpu)
    assert r.lib.mpu6050_set_bypass(mpu_state, 0).result == r.lib.SENSOR_OK
    assert not r.mpu.bypass_enabled and r.mpu.peek("INT_PIN_CFG") == 0x10
    status, raw, _ = r.read()
    assert r.text(status) == "HMC5883L: address not acknowledged" and list(raw.mag) == [111] * 3
    assert r.lib.mpu6050_set_bypass(mpu_state, 1).result == r.lib.SENSOR_OK
    assert r.read()[0].result == r.lib.SENSOR_OK


# =========================================================================== (c) failures


def assert_bounded(r: Rig, max_transfers: int, max_delay_ms: float):
    """The call returned after a bounded amount of bus traffic and waiting."""
    assert len(r.bus.transfers()) <= max_transfers, len(r.bus.transfers())
    assert sum(r.delays()) <= max_delay_ms, sum(r.delays())


def test_absent_mpu6050(drv):
    r = Rig(drv, mpu=False, hmc=False)
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_I2C and status.chip == r.lib.SENSOR_CHIP_MPU6050
    assert status.i2c == r.lib.I2C_ERR_NACK_ADDRESS
    assert r.text(status) == "MPU6050: address not acknowledged"
    assert_bounded(r, 1, 0)


def test_wrong_who_am_i_writes_nothing(drv):
    r = Rig(drv, mpu=MPU6050(who_am_i=0x70))
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_IDENTITY and status.count == 1 and status.got[0] == 0x70
    assert r.text(status) == "MPU6050: wrong identity 0x70 (expected 0x68)"
    assert r.bus.register_writes(MPU_ADDRESS) == []


def test_wrong_hmc5883l_identity(drv):
    r = Rig(drv, hmc=HMC5883L(identity=b"H4\x00"))
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_IDENTITY and status.chip == r.lib.SENSOR_CHIP_HMC5883L
    assert list(status.got) == [0x48, 0x34, 0x00] and status.count == 3
    assert r.text(status) == "HMC5883L: wrong identity 0x48 0x34 0x00 (expected H43)"
    assert r.bus.register_writes(HMC_ADDRESS) == []


def test_hmc5883l_is_unreachable_without_the_bypass(drv):
    r = Rig(drv)
    lib, ffi = r.lib, r.ffi
    mpu_state = ffi.addressof(r.gy.mpu)
    assert lib.mpu6050_init(mpu_state, r.c_bus, MPU_ADDRESS, ffi.addressof(r.config.mpu)).result == lib.SENSOR_OK
    mag_state = ffi.addressof(r.gy.mag)
    status = lib.hmc5883l_init(mag_state, r.c_bus, HMC_ADDRESS, ffi.addressof(r.config.mag))
    assert r.text(status) == "HMC5883L: address not acknowledged"
    assert lib.mpu6050_set_bypass(mpu_state, 1).result == lib.SENSOR_OK
    assert lib.hmc5883l_init(mag_state, r.c_bus, HMC_ADDRESS, ffi.addressof(r.config.mag)).result == lib.SENSOR_OK


def test_bypass_that_does_not_close(drv):
    """A chip whose I2C master stays enabled (USER_CTRL.I2C_MST_EN stuck at 1)."""
    r = Rig(drv, mpu=MPU6050(stuck_bits={0x6A: 0x20}))
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_READBACK and status.reg == 0x6A
    assert r.text(status) == "MPU6050: register 0x6A reads 0x20 after writing 0x00"
    assert r.bus.transfers(HMC_ADDRESS) == []


@pytest.mark.parametrize("register,text", [
    (0x1B, "MPU6050: register 0x1B reads 0x00 after writing 0x18"),
    (0x19, "MPU6050: register 0x19 reads 0x00 after writing 0x09"),
    (0x37, "MPU6050: register 0x37 reads 0x00 after writing 0x10"),
])
def test_mpu6050_configuration_that_does_not_read_back(drv, register, text):
    r = Rig(drv, mpu=MPU6050(ignore_writes={register}))
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_READBACK and status.reg == register
    assert r.text(status) == text


def test_hmc5883l_configuration_that_does_not_read_back(drv):
    r = Rig(drv, hmc=HMC5883L(ignore_writes={0x01}))
    r.config.mag.gain = r.lib.HMC5883L_GAIN_820
    status = r.init()
    assert (status.result, status.reg, status.wrote, status.got[0]) == (r.lib.SENSOR_ERR_READBACK, 0x01, 0x40, 0x20)
    assert r.text(status) == "HMC5883L: register 0x01 reads 0x20 after writing 0x40"


def test_reset_that_never_completes(drv):
    r = Rig(drv, mpu=MPU6050(reset_ms=None))
    status = r.init()
    assert status.result == r.lib.SENSOR_ERR_RESET and status.got[0] == 0xC0
    assert r.text(status) == "MPU6050: reset did not complete (register 0x6B reads 0xC0)"
    polls = [t for t in r.bus.transfers(MPU_ADDRESS) if t.kind == "write_read" and t.data == b"\x6b"]
    assert len(polls) == 10
    assert_bounded(r, 12, 100 + 9 * 10)


def test_slow_reset_is_waited_for(drv):
    r = Rig(drv, mpu=MPU6050(reset_ms=135))
    assert r.init().result == r.lib.SENSOR_OK
    polls = [t for t in r.bus.transfers(MPU_ADDRESS) if t.kind == "write_read" and t.data == b"\x6b"]
    # 100 ms, then polls 10 ms apart until DEVICE_RESET reads 0 (at 140 ms); the last is the read-back after waking
    assert [p.result for p in polls] == [b"\xc0"] * 4 + [b"\x40"] + [b"\x01"]


def test_chip_silent_while_resetting(drv):
    # WHO_AM_I and the reset write go through; the first two polls are not acknowledged
    r = Rig(drv)
    r.bus.inject("NACK_ADDRESS", MPU_ADDRESS, after=2, count=2)
    assert r.init().result == r.lib.SENSOR_OK
    # a chip that never answers again: the poll gives up after its bound, with the I2C error
    r = Rig(drv)
    r.bus.inject("NACK_ADDRESS", MPU_ADDRESS, after=2, count=None)
    status = r.init()
    assert r.text(status) == "MPU6050: address not acknowledged"
    assert_bounded(r, 12, 100 + 9 * 10)


def test_nack_on_data(drv):
    r = Rig(drv)
    r.bus.inject("NACK_DATA", MPU_ADDRESS)
    status = r.init()
    assert status.i2c == r.lib.I2C_ERR_NACK_DATA and status.reg == 0x75
    assert r.text(status) == "MPU6050: data not acknowledged at register 0x75"
    r = ready_rig(drv)
    r.bus.inject("NACK_DATA", HMC_ADDRESS)
    status, raw, temperature = r.read()
    assert r.text(status) == "HMC5883L: data not acknowledged at register 0x03"
    assert list(raw.acc) == [111] * 3 and list(raw.mag) == [111] * 3 and temperature == 111


@pytest.mark.parametrize("failure,text", [
    ("TIMEOUT", "MPU6050: timeout at register 0x3B"),
    ("BUS", "MPU6050: bus error at register 0x3B"),
    ("ARBITRATION", "MPU6050: arbitration lost at register 0x3B"),
])
def test_transfer_failures_during_reads(drv, failure, text):
    r = ready_rig(drv)
    r.bus.inject(failure, MPU_ADDRESS)
    start = len(r.bus.transfers())
    status, raw, temperature = r.read()
    assert status.result == r.lib.SENSOR_ERR_I2C and status.i2c == STATUS_CODES[failure]
    assert r.text(status) == text
    assert list(raw.gyr) == [111] * 3 and temperature == 111
    assert len(r.bus.transfers()) - start == 1  # no retries, no waiting: it returned
    assert r.read()[0].result == r.lib.SENSOR_OK  # and the next read works again


def test_bus_stuck_during_init_returns_at_once(drv):
    r = Rig(drv)
    r.bus.inject("TIMEOUT", count=None)
    status = r.init()
    assert r.text(status) == "MPU6050: timeout at register 0x75"
    assert_bounded(r, 1, 0)


@pytest.mark.parametrize("address,text", [
    (MPU_ADDRESS, "MPU6050: address not acknowledged"),
    (HMC_ADDRESS, "HMC5883L: address not acknowledged"),
])
def test_sensor_stops_answering_mid_run(drv, address, text):
    r = ready_rig(drv)
    r.bus.inject("NACK_ADDRESS", address, after=3, count=None)  # 3 reads of each chip go through
    results = []
    delays_before = len(r.delays())
    for _ in range(6):
        start = len(r.bus.transfers())
        status, raw, _ = r.read()
        results.append(r.text(status))
        assert len(r.bus.transfers()) - start <= 2  # one burst per chip, no retry loop
    assert results == ["HMC5883L: OK"] * 3 + [text] * 3
    assert len(r.delays()) == delays_before  # reads never wait


def test_hmc5883l_overflow_is_flagged_and_kept(drv):
    r = ready_rig(drv)
    r.hmc.set_field(4000, -7, -3000)
    r.bus.delay_ms(20)
    status, raw, _ = r.read()
    assert status.result == r.lib.SENSOR_MAG_OVERFLOW and status.chip == r.lib.SENSOR_CHIP_HMC5883L
    assert status.channels == r.lib.SENSOR_CHANNEL_X | r.lib.SENSOR_CHANNEL_Z
    assert r.text(status) == "HMC5883L: overflow on x z"
    assert list(raw.mag) == [r.lib.HMC5883L_OVERFLOW, -7, r.lib.HMC5883L_OVERFLOW]
    # the sample is delivered, and the core flags the field clipped
    assert list(raw.acc) != [111] * 3
    settings = r.ffi.new("imu_sensor_settings_t *")
    r.lib.gy86_sensor_settings(r.config, settings)
    out, sat = r.ffi.new("imu_sample_t *"), r.ffi.new("uint32_t *")
    r.lib.imu_sample_from_raw(settings, raw, out, sat)
    assert out.clipped & r.lib.IMU_CLIPPED_MAG


def test_invalid_configuration_sends_nothing(drv):
    for chip, field, value, text in [
        ("mpu", "gyro_range", 4, "MPU6050: configuration not supported (register 0x1B)"),
        ("mpu", "acc_range", 7, "MPU6050: configuration not supported (register 0x1C)"),
        ("mpu", "dlpf_cfg", 7, "MPU6050: configuration not supported (register 0x1A)"),
        ("mag", "rate", 7, "HMC5883L: configuration not supported (register 0x00)"),
        ("mag", "gain", 8, "HMC5883L: configuration not supported (register 0x01)"),
    ]:
        r = Rig(drv)
        setattr(getattr(r.config, chip), field, value)
        status = r.init()
        assert status.result == r.lib.SENSOR_ERR_CONFIG and r.text(status) == text
        assert r.bus.transfers(MPU_ADDRESS if chip == "mpu" else HMC_ADDRESS) == []


def test_status_text_fits_and_truncates(drv):
    r = Rig(drv, hmc=HMC5883L(identity=b"\xff\xff\xff"))
    status = r.init()
    full = r.text(status)
    assert full == "HMC5883L: wrong identity 0xFF 0xFF 0xFF (expected H43)"
    assert len(full) < r.lib.SENSOR_STATUS_TEXT_SIZE
    small = r.ffi.new("char[]", 12)
    assert r.ffi.string(r.lib.sensor_status_text(r.ffi.addressof(status), small, 12)) == full[:11].encode()
    assert r.ffi.string(r.lib.sensor_status_text(r.ffi.addressof(status), r.ffi.NULL, 0)) == b""


# =========================================================================== (d) builds


def run(*cmd, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=120)


def assert_ok(proc: subprocess.CompletedProcess, what: str):
    assert proc.returncode == 0, f"{what} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"


def compile_drivers(compiler, tmp_path: Path, *flags) -> list[Path]:
    objects = []
    for src in DRIVER_SOURCES:
        obj = tmp_path / (src.stem + ".o")
        assert_ok(run(compiler, *flags, f"-I{DRIVERS}", f"-I{CORE}", "-c", src, "-o", obj), f"{src.name} {flags}")
        objects.append(obj)
    return objects


def test_driver_sources_exist():
    names = {p.name for p in DRIVER_SOURCES}
    assert {"i2c.c", "mpu6050.c", "hmc5883l.c", "gy86.c"} <= names


@pytest.mark.skipif(GCC is None, reason="gcc not found")
@pytest.mark.parametrize("opt", ["-O0", "-O2"])
@pytest.mark.parametrize("arith", ["IMU_FIXED", "IMU_FLOAT"])
def test_drivers_strict_warnings(arith, opt, tmp_path):
    assert len(compile_drivers(GCC, tmp_path, *STRICT, opt, f"-D{arith}")) == len(DRIVER_SOURCES)


@pytest.mark.skipif(GCC is None, reason="gcc not found")
def test_driver_headers_are_self_contained(tmp_path):
    for header in DRIVER_HEADERS:
        unit = tmp_path / f"only_{header.stem}.c"
        unit.write_text(f'#include "{header.name}"\ntypedef int translation_unit_not_empty;\n')
        assert_ok(run(GCC, *STRICT, "-DIMU_FIXED", f"-I{DRIVERS}", f"-I{CORE}", "-fsyntax-only", unit), header.name)


_INCLUDE = re.compile(r'^\s*#\s*include\s*([<"])([^>"]+)[>"]', re.M)


def test_drivers_include_no_platform_header():
    local = {p.name for p in DRIVER_HEADERS} | {p.name for p in CORE.glob("*.h")}
    found = [(path.name, delim, header) for path in DRIVER_SOURCES + DRIVER_HEADERS
             for delim, header in _INCLUDE.findall(path.read_text())]
    assert len(found) >= len(DRIVER_SOURCES)
    bad = [f for f in found if (f[1] == "<" and f[2] not in {"stdint.h", "stddef.h"}) or
           (f[1] == '"' and f[2] not in local)]
    assert not bad, bad
    assert "imu_sensor.h" in {h for _, _, h in found}
    for path in DRIVER_SOURCES:
        assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", path.read_text()), path.name


@pytest.mark.skipif(GCC is None, reason="gcc not found")
def test_drivers_build_freestanding(tmp_path):
    gcc_include = run(GCC, "-print-file-name=include").stdout.strip()
    compile_drivers(GCC, tmp_path, "-std=c99", "-DIMU_FIXED", "-ffreestanding", "-nostdinc", "-isystem", gcc_include)


@pytest.mark.skipif(GCC is None or platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="-mgeneral-regs-only check runs on x86-64 with gcc")
@pytest.mark.parametrize("opt", ["-O0", "-O2"])
def test_drivers_use_no_floating_point_x86(opt, tmp_path):
    compile_drivers(GCC, tmp_path, "-std=c99", "-DIMU_FIXED", "-mgeneral-regs-only", opt)


#: Soft-float helpers of the ARM run-time ABI (double/float arithmetic, conversions, compares).
_SOFT_FLOAT = re.compile(r"^__aeabi_(d|f|cd|cf|[iu]?l?2[df])")


def arm_defined_symbols(objects: list[Path]) -> set[str]:
    proc = run(ARM_NM, "--defined-only", "-g", *objects)
    assert_ok(proc, "arm-none-eabi-nm")
    return {line.split()[-1] for line in proc.stdout.splitlines() if len(line.split()) == 3}


def arm_undefined_symbols(objects: list[Path]) -> set[str]:
    proc = run(ARM_NM, "-u", *objects)
    assert_ok(proc, "arm-none-eabi-nm")
    return {line.split()[-1] for line in proc.stdout.splitlines() if line.strip().startswith("U ")}


def test_drivers_build_for_cortex_m4_without_floating_point(tmp_path):
    """The ARM target build (required: no skip when the toolchain is missing).

    Soft-float ABI: any run-time floating point would call an __aeabi_d*/f* helper.
    The control snippet shows that the check sees one.
    """
    assert shutil.which(ARM_GCC) and shutil.which(ARM_NM), "arm-none-eabi-gcc / -nm not installed"
    flags = [*STRICT, "-mcpu=cortex-m4", "-mthumb", "-O2", "-DIMU_FIXED", "-ffreestanding"]
    objects = compile_drivers(ARM_GCC, tmp_path, *flags, "-mfloat-abi=soft")
    undefined = arm_undefined_symbols(objects)
    defined = arm_defined_symbols(objects)
    assert {"gy86_init", "gy86_read", "mpu6050_init", "hmc5883l_read", "i2c_status_text"} <= defined
    assert not {s for s in undefined if _SOFT_FLOAT.match(s)}, undefined
    # also with the hardware FPU ABI of the reference board (STM32F4): must compile cleanly
    compile_drivers(ARM_GCC, tmp_path, *flags, "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16")
    snippet = tmp_path / "fp.c"
    snippet.write_text("int f(int a) { double x = a; x *= 1.5; return (int)x; }\n")
    assert_ok(run(ARM_GCC, *flags, "-mfloat-abi=soft", "-c", snippet, "-o", tmp_path / "fp.o"), "control")
    assert {s for s in arm_undefined_symbols([tmp_path / "fp.o"]) if _SOFT_FLOAT.match(s)}
