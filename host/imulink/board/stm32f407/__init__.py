"""The reference board, virtual: the exact STM32F407 image that gets flashed, executed by unicorn's
Cortex-M4 with register-level models of the STM32F407's peripherals (RM0090) and of the GY-86's
chips and a u-blox receiver (imulink.board.chips). docs/firmware.md, "The virtual reference
board", lists what is modelled and what is not."""
from imulink.board.stm32f407.board import BoardServer, ChipFaults, Feed, ReferenceBoard
from imulink.board.stm32f407.core import Fault

__all__ = ["BoardServer", "ChipFaults", "Fault", "Feed", "ReferenceBoard"]
