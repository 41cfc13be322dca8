"""Register-level models of the reference board's chips, from their data sheets.

The firmware's sensor drivers (firmware/drivers) are tested against these models: an
:class:`I2CBus` carries the chips by address and implements the transfers of
firmware/drivers/i2c.h, with failure injection; :class:`MPU6050` and :class:`HMC5883L`
behave like the chips at register level (reset values, identity, auto-increment,
data registers, the MPU6050's bypass switch in front of its auxiliary bus).

The GY-86 module is built like this::

    bus = I2CBus()
    mpu = bus.attach(0x68, MPU6050())
    mag = mpu.aux_bus.attach(0x1E, HMC5883L())   # reachable once the bypass is on

The GY-86's barometer, an MS5611 at 0x77 on the main bus, is :class:`MS5611` (command
level: it has no registers).

Each model's module docstring says what is modelled and what is not.
"""
from imulink.board.chips.hmc5883l import HMC5883L
from imulink.board.chips.i2c import FAILURES, STATUS_CODES, I2CBus, I2CDevice, RegisterDevice
from imulink.board.chips.mpu6050 import MPU6050
from imulink.board.chips.ms5611 import MS5611
from imulink.board.chips.stm32_bootloader import BootloaderPort, Stm32Bootloader  # noqa: F401  (AN3155 bootloader model)

__all__ = ["FAILURES", "HMC5883L", "I2CBus", "I2CDevice", "MPU6050", "MS5611", "RegisterDevice", "STATUS_CODES"]
