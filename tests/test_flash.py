"""`imulink flash` over the UART bootloader, against an emulator of the STM32 system
bootloader that follows AN3155 byte for byte (imulink.board.chips.stm32_bootloader), over a pty.

The end-to-end proof: the reference board's image is flashed into the emulator, the
emulator's Go boots the flashed bytes in QEMU (the same chip family), and the flashing
tool checks the firmware's HELLO (board, version, schema hash) against the image's
identification block, over the same port. Then every failure the tool must explain:
no bootloader, a wrong chip, readout protection, a chip that stops answering or resets
midway (and flashing again works), a NACK, an image that does not fit, the wrong image.
"""
from __future__ import annotations

import dataclasses
import os
import re
import select
import socket
import subprocess
import threading
import time
import tty
from pathlib import Path

import pytest

from imulink import protocol
from imulink.board import flash
from imulink.board.chips.stm32_bootloader import BootloaderPort, Stm32Bootloader
from imulink.board.emulator import EmulatedBoard, find_qemu
from imulink.cli import main
from imulink.io.firmware_image import ImageError, load_image

ROOT = Path(__file__).resolve().parents[1]
STM32F407_ELF = ROOT / "firmware" / "build" / "stm32f407" / "imulink-stm32f407-gy86.elf"
QEMU_ELF = ROOT / "firmware" / "build" / "qemu" / "imulink-qemu-netduinoplus2.elf"
FLASH_BASE = 0x0800_0000


@pytest.fixture(scope="module")
def image():
    """The reference board's image, built now (the tests must not skip without the ARM compiler)."""
    build = subprocess.run(["make", "--no-print-directory", "-C", str(ROOT / "firmware"), "stm32f407"],
                           capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stderr
    return load_image(STM32F407_ELF)


def flashed_bytes(chip: Stm32Bootloader, image) -> bytes:
    return bytes(chip.flash[image.start - FLASH_BASE:image.end - FLASH_BASE])


def quiet(line: str) -> None:
    pass


def erased(chip: Stm32Bootloader) -> list[int]:
    """The sectors the chip erased (each once)."""
    assert all(count <= 1 for count in chip.erase_counts)
    return [sector for sector, count in enumerate(chip.erase_counts) if count]


class QemuBoot:
    """What the emulator's Go starts: the flashed bytes as a raw image in QEMU's
    netduinoplus2, its USART1 a socket bridged to the bootloader's pty."""

    def __init__(self, tmp_path: Path):
        self.tmp_path = tmp_path
        self.process: subprocess.Popen | None = None

    def __call__(self, address: int, flash: bytes):
        assert address == FLASH_BASE
        image = self.tmp_path / "flashed.bin"
        image.write_bytes(flash.rstrip(b"\xff"))  # QEMU's -kernel loads a raw image at 0, the flash alias
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        self.process = subprocess.Popen(
            [find_qemu(), "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-kernel", str(image),
             "-serial", f"tcp:127.0.0.1:{port},server=on,wait=on,nodelay=on"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while True:
            try:
                return socket.create_connection(("127.0.0.1", port), timeout=1)
            except OSError:
                assert time.monotonic() < deadline, "QEMU did not listen"
                time.sleep(0.05)

    def stop(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()


#: RM0090 table 5: sectors 0-3 of 16 KiB, 4 of 64 KiB, 5-11 of 128 KiB (ends, offsets from FLASH_BASE).
SECTOR_ENDS = [0x4000, 0x8000, 0xC000, 0x10000, 0x20000] + [0x20000 * k for k in range(2, 9)]


def sectors_under(image):
    """The sectors an image from FLASH_BASE to image.end touches, from RM0090's layout."""
    size = image.end - FLASH_BASE
    return [k for k, end in enumerate(SECTOR_ENDS) if k == 0 or SECTOR_ENDS[k - 1] < size]


def test_flash_boots_the_image_and_its_hello_is_the_images(image, tmp_path):
    boot = QemuBoot(tmp_path)
    chip = Stm32Bootloader()
    try:
        with BootloaderPort(chip, on_go=boot) as port:
            result = flash.flash_uart(image, port.address, log=quiet)
    finally:
        boot.stop()
    assert flashed_bytes(chip, image) == image.bytes_at(image.start, image.end - image.start)
    assert result.sectors == sectors_under(image) and erased(chip) == sectors_under(image)
    assert chip.go_address == FLASH_BASE and result.verified and result.started
    ident = image.identification
    assert (result.hello["board"], result.hello["schema_hash"]) == (ident.board, protocol.SCHEMA_HASH)
    assert (result.hello["firmware_major"], result.hello["firmware_minor"], result.hello["firmware_patch"]) == \
        ident.firmware_version
    commands = [entry.command for entry in chip.log]
    assert commands[:4] == ["Sync", "Get", "Get ID", "Read Memory"]  # the flash size register, before any change
    assert "Write Memory" in commands and commands[-1] == "Go"


def test_flash_the_hex_and_the_bin_writes_the_same_bytes(image, tmp_path):
    for path, address in ((STM32F407_ELF.with_suffix(".hex"), None), (STM32F407_ELF.with_suffix(".bin"), FLASH_BASE)):
        chip = Stm32Bootloader()
        other = load_image(path, address)
        with BootloaderPort(chip) as port:
            flash.flash_uart(other, port.address, start=False, log=quiet)
        assert flashed_bytes(chip, image) == image.bytes_at(image.start, image.end - image.start), path.name
        assert chip.go_address is None  # --no-start: left in the bootloader


def test_only_the_sectors_the_image_needs_are_erased(image):
    chip = Stm32Bootloader(flash=bytes(range(256)) * 4096)  # 1 MiB of old contents
    with BootloaderPort(chip) as port:
        flash.flash_uart(image, port.address, start=False, log=quiet)
    used = sectors_under(image)
    assert erased(chip) == used
    kept = SECTOR_ENDS[used[-1]]  # the first sector the image does not reach kept its contents
    assert bytes(chip.flash[kept:kept + 0x100]) == bytes(range(256))
    assert bytes(chip.flash[image.end - FLASH_BASE:kept]) == b"\xff" * (kept - image.end + FLASH_BASE)


def test_dry_run_writes_nothing(image):
    chip = Stm32Bootloader()
    with BootloaderPort(chip) as port:
        result = flash.flash_uart(image, port.address, dry_run=True, log=quiet)
    assert result.dry_run and result.sectors == sectors_under(image)
    assert chip.flash == bytearray(b"\xff" * len(chip.flash)) and chip.go_address is None
    assert not any(entry.command in ("Write Memory", "Extended Erase") for entry in chip.log)


# ---------------------------------------------------------------------------- failures


def flash_error(image, chip: Stm32Bootloader, **options) -> str:
    with BootloaderPort(chip) as port, pytest.raises(flash.FlashError) as error:
        flash.flash_uart(image, port.address, log=quiet, **options)
    return str(error.value)


def test_no_bootloader_answering(image):
    message = flash_error(image, Stm32Bootloader(silent_after_bytes=0))
    assert "no STM32 bootloader answered the synchronisation byte 0x7F" in message and "BOOT0" in message


def test_a_chip_of_another_family_is_refused(image):
    message = flash_error(image, Stm32Bootloader(device_id=0x419))
    assert "device id 0x419" in message and "does not know" in message


def test_an_image_that_does_not_fit_is_refused(image, tmp_path):
    big = tmp_path / "big.bin"
    big.write_bytes(b"\x00" * (600 * 1024))
    chip = Stm32Bootloader(flash_size=512 * 1024)  # an STM32F407VE
    with BootloaderPort(chip) as port, pytest.raises(flash.FlashError, match=r"outside this chip's flash .*512 KiB"):
        flash.flash_uart(load_image(big, FLASH_BASE), port.address, force=True, log=quiet)
    assert erased(chip) == []


def test_readout_protection_is_explained_and_cleared_on_request(image):
    chip = Stm32Bootloader(read_protected=True, flash=b"\x12" * (1 << 20))
    message = flash_error(image, chip)
    assert "readout protection" in message and "--unprotect" in message and "ERASES THE WHOLE FLASH" in message
    assert chip.flash[0] == 0x12  # nothing changed
    with BootloaderPort(chip) as port:
        flash.flash_uart(image, port.address, unprotect=True, start=False, log=quiet)
    assert not chip.read_protected and flashed_bytes(chip, image) == image.bytes_at(image.start, image.size)
    assert chip.flash[-1] == 0xFF  # the whole flash was erased by the unprotect


def test_a_chip_that_stops_answering_midway_is_left_in_its_bootloader(image):
    chip = Stm32Bootloader(silent_after_bytes=6000)
    message = flash_error(image, chip)
    assert "stopped answering" in message and "run imulink flash again" in message


def test_a_reset_midway_and_flashing_again(image):
    chip = Stm32Bootloader(reset_after_bytes=9000)
    message = flash_error(image, chip, start=False)
    assert "bootloader" in message
    with BootloaderPort(chip) as port:  # the chip is back in its bootloader: the second try works
        flash.flash_uart(image, port.address, start=False, log=quiet)
    assert flashed_bytes(chip, image) == image.bytes_at(image.start, image.end - image.start)


def test_a_refused_write_is_reported(image):
    message = flash_error(image, Stm32Bootloader(nack_commands={0x31}))
    assert "refused the Write Memory command (NACK)" in message


def test_a_board_holding_another_boards_firmware_is_refused(image, tmp_path):
    other = bytearray(image.bytes_at(image.start, image.size))
    at = other.find(b"stm32f407-gy86")
    other[at:at + 14] = b"other-board\0\0\0"
    chip = Stm32Bootloader(flash=bytes(other))
    message = flash_error(image, chip)
    assert "this board holds other-board firmware 0.1.0" in message and "--force" in message
    assert erased(chip) == []


def test_images_the_tool_refuses(image, tmp_path):
    with pytest.raises(flash.FlashError, match="emulated board"):
        flash.check_identification(load_image(QEMU_ELF), force=False)
    bare = tmp_path / "bare.bin"
    bare.write_bytes(b"\x00" * 64)
    with pytest.raises(flash.FlashError, match="no imulink identification block"):
        flash.check_identification(load_image(bare, FLASH_BASE), force=False)
    broken = tmp_path / "broken.hex"
    broken.write_text(STM32F407_ELF.with_suffix(".hex").read_text().replace(":10", ":11", 1))
    with pytest.raises(ImageError, match=r"broken.hex:\d+: not an Intel HEX record"):
        load_image(broken)


def test_cli_flash_and_its_one_line_errors(image, capsys, tmp_path):
    chip = Stm32Bootloader()
    with BootloaderPort(chip) as port:
        code = main(["flash", str(STM32F407_ELF), port.address, "--no-start"])
    out, err = capsys.readouterr()
    flashed = int(re.search(r"flashed (\d+) bytes", out).group(1))
    assert code == 0 and flashed == sum(len(s.data) for s in load_image(STM32F407_ELF).segments) and "verified" in out
    assert "sectors 0, 1, 2" in out
    assert "chip: STM32F405/STM32F407/STM32F415/STM32F417 (device id 0x413), 1024 KiB flash" in err
    for argv, fragment in ((["flash", str(ROOT / "README.md"), "/dev/null"], "not a firmware image"),
                           (["flash", str(STM32F407_ELF), "/dev/imulink-no-such-port"], "cannot open"),
                           (["flash", str(STM32F407_ELF)], "give the serial port"),
                           (["flash", str(STM32F407_ELF), "/dev/imulink-no-such-port", "--enter", "lines"],
                            "--enter lines drives a labgrid place's BOOT0 and reset lines")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.splitlines()[-1].startswith("imulink: error: ") and fragment in err and "Traceback" not in err


class FirmwareThenBootloader:
    """A pty that answers like imulink firmware (HELLO, ACK) until ENTER_BOOTLOADER, then
    like the system bootloader: what --enter command meets on a board."""

    def __init__(self, chip: Stm32Bootloader):
        self.chip = chip
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.address = os.ttyname(self.slave)
        self.entered = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        decoder, seq = protocol.FrameDecoder(), 0
        while not self._stop.is_set():
            if not select.select([self.master], [], [], 0.05)[0]:
                continue
            data = os.read(self.master, 4096)
            if self.entered:
                os.write(self.master, self.chip.receive(data))
                continue
            for message in decoder.feed(data):
                command = protocol.decode_command(message)
                out = b""
                if command.name == "GET_VERSION":
                    out += protocol.encode("HELLO", seq, firmware_major=0, firmware_minor=1, firmware_patch=0,
                                           protocol_version=protocol.PROTOCOL_VERSION,
                                           schema_hash=protocol.SCHEMA_HASH, board="stm32f407-gy86", filters=14,
                                           gyro_scale=1, acc_scale=2, mag_scale=3)
                out += protocol.encode("ACK", seq + 1, command_seq=command.command_seq,
                                       command=protocol.COMMAND_IDS[command.name], reason=0)
                seq += 2
                os.write(self.master, out)
                if command.name == "ENTER_BOOTLOADER":
                    self.entered = True  # the board resets into its bootloader

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        os.close(self.master)
        os.close(self.slave)


def test_enter_by_command_asks_the_running_firmware(image):
    board = FirmwareThenBootloader(Stm32Bootloader())
    try:
        flash.flash_uart(image, board.address, enter="command", start=False, log=quiet)
    finally:
        board.close()
    assert board.entered and flashed_bytes(board.chip, image) == image.bytes_at(image.start, image.size)


def test_enter_by_command_on_a_board_without_a_bootloader(image):
    with EmulatedBoard(duration_s=1.0) as emulated, pytest.raises(flash.FlashError) as error:
        flash.flash_uart(image, emulated.address, enter="command", log=quiet)
    assert "refused ENTER_BOOTLOADER (NOT_SUPPORTED)" in str(error.value) and "--enter manual" in str(error.value)


def foreign_image(tmp_path, name: str, address: int, vector_table: bool = True):
    """A raw image that is not imulink's: a vector table (stack pointer in SRAM, a Thumb reset
    handler just after it) and an endless loop, or the same bytes without the table."""
    words = [0x2002_0000, address + 8 + 1] if vector_table else [0xDEAD_BEEF, 0x0000_0000]
    path = tmp_path / name
    path.write_bytes(b"".join(w.to_bytes(4, "little") for w in words) + b"\xfe\xe7" * 8)  # b . (Thumb)
    return load_image(path, address)


@pytest.mark.parametrize("address", (FLASH_BASE, 0x0800_8000))
def test_a_foreign_image_with_force_is_started_where_it_was_flashed(tmp_path, address):
    """An image without imulink's identification, flashed with --force: started at its own
    vector table (before: Go at the start of flash, the boot loader in front of it) and not
    asked for a HELLO it cannot send (before: "no HELLO from the firmware", exit 2)."""
    image = foreign_image(tmp_path, "foreign.bin", address)
    started = []
    chip = Stm32Bootloader()
    with BootloaderPort(chip, on_go=lambda at, flash_bytes: started.append(at)) as port:
        result = flash.flash_uart(image, port.address, force=True, log=quiet)
    assert result.started and result.started_at == address == chip.go_address and started == [address]
    assert result.hello is None and "no imulink identification" in result.note
    assert flashed_bytes(chip, image) == image.bytes_at(image.start, image.size)


def test_cli_flash_force_of_a_foreign_image_succeeds_and_says_so(tmp_path, capsys):
    image_path = tmp_path / "foreign.bin"
    image_path.write_bytes(foreign_image(tmp_path, "foreign.bin", 0x0800_8000).bytes_at(0x0800_8000, 24))
    with BootloaderPort(Stm32Bootloader()) as port:
        code = main(["flash", str(image_path), port.address, "--address", "0x08008000", "--force"])
    out = capsys.readouterr().out
    assert code == 0 and "started at 0x08008000 (no imulink identification: its HELLO is not asked for)" in out


def test_an_image_without_a_vector_table_is_flashed_and_not_started(tmp_path):
    image = foreign_image(tmp_path, "blob.bin", 0x0800_4000, vector_table=False)
    chip = Stm32Bootloader()
    with BootloaderPort(chip) as port:
        result = flash.flash_uart(image, port.address, force=True, log=quiet)
    assert not result.started and chip.go_address is None and "no vector table at" in result.note
    assert flashed_bytes(chip, image) == image.bytes_at(image.start, image.size)


def test_force_flashes_an_image_of_another_schema(image):
    other = dataclasses.replace(image.identification, schema_hash=protocol.SCHEMA_HASH ^ 1)
    foreign = dataclasses.replace(image, identification=other)
    with pytest.raises(flash.FlashError, match="speaks protocol schema .*--force flashes it anyway"):
        flash.check_identification(foreign, force=False)
    assert flash.check_identification(foreign, force=True) == other
    assert "not this host's" in flash.unasked_hello(other) and flash.unasked_hello(image.identification) == ""
