"""The STM32F405/407 bootloader model (imulink.board.chips.stm32_bootloader) against AN3155.

The expected bytes are written out from AN3155's command descriptions (Rev 20, section
numbers in the docstrings): what the host sends and what the chip answers, checksums
and complements worked out by hand. ACK = 0x79, NACK = 0x1F.

Sections:
  (a) synchronisation and the information commands;
  (b) Read Memory, Write Memory, Go;
  (c) Extended Erase, write protection, read protection;
  (d) chunking, the log and the fault injections;
  (e) BootloaderPort over a real pty with pyserial.
"""
from __future__ import annotations

import random
import socket
import time
from functools import reduce

import pytest
import serial

from imulink.board.chips.stm32_bootloader import BootloaderPort, LogEntry, Stm32Bootloader

A = b"\x79"  # ACK
N = b"\x1f"  # NACK

# Address fields (four bytes MSB first + their XOR), AN3155 §3.4-§3.6.
FLASH_0 = bytes.fromhex("08000000 08")          # 0x08000000, sector 0
SECTOR_1 = bytes.fromhex("08004000 48")         # 0x08004000
SECTOR_5 = bytes.fromhex("08020000 0a")         # 0x08020000
FLASH_END_16 = bytes.fromhex("080ffff0 08")     # 0x080FFFF0: the last 16 bytes
USER_RAM = bytes.fromhex("20003000 10")         # 0x20003000: first byte after the bootloader's 12 KiB
BOOT_RAM = bytes.fromhex("20000000 20")         # 0x20000000: the bootloader's RAM
SYSTEM_MEMORY = bytes.fromhex("1fff0000 e0")    # 0x1FFF0000
OPTION_BYTES = bytes.fromhex("1fffc000 20")     # 0x1FFFC000
OPTION_BYTES_4 = bytes.fromhex("1fffc004 24")   # 0x1FFFC004
EXTERNAL = bytes.fromhex("60000000 60")         # 0x60000000, AN3155 §4 Table 3 (V3.1)

GET_ANSWER = bytes.fromhex("79 0b 31 00 01 02 11 21 31 44 63 73 82 92 79")  # AN3155 §3.1


def checksum(data: bytes) -> int:
    return reduce(lambda a, b: a ^ b, data, 0)


def synced(**kwargs) -> Stm32Bootloader:
    chip = Stm32Bootloader(**kwargs)
    assert chip.receive(b"\x7f") == A
    return chip


def read(chip: Stm32Bootloader, address: bytes, n_minus_1: int) -> bytes:
    """The host side of Read Memory (AN3155 §3.4); returns the data after checking the ACKs."""
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(address) == A
    answer = chip.receive(bytes([n_minus_1, n_minus_1 ^ 0xFF]))
    assert answer[:1] == A and len(answer) == n_minus_1 + 2
    return answer[1:]


def write(chip: Stm32Bootloader, address: bytes, data: bytes) -> bytes:
    """The host side of Write Memory (AN3155 §3.6); returns the final answer byte."""
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(address) == A
    n = len(data) - 1
    return chip.receive(bytes([n]) + data + bytes([checksum(bytes([n]) + data)]))


# --------------------------------------------------------------------------- (a) sync, Get*


def test_the_first_0x7f_is_acked_and_anything_before_it_is_ignored():
    """AN3155 §1: the bootloader waits for 0x7F and answers ACK."""
    chip = Stm32Bootloader()
    assert chip.state == "sync"
    assert chip.receive(b"\x00\x55\xff\x79") == b""
    assert chip.receive(b"\x7f") == A
    assert chip.state == "command"


def test_get_lists_version_3_1_and_its_commands():
    """AN3155 §3.1: ACK, N = 11, version, 00 01 02 11 21 31 44 63 73 82 92, ACK."""
    chip = synced()
    assert chip.receive(b"\x00\xff") == GET_ANSWER


def test_get_version():
    """AN3155 §3.2: ACK, version 0x31, 0x00, 0x00, ACK."""
    assert synced().receive(b"\x01\xfe") == bytes.fromhex("79 31 00 00 79")


def test_get_id_answers_the_device_id_msb_first():
    """AN3155 §3.3: ACK, N = 1, 0x04 0x13, ACK (STM32F40xxx/41xxx: 0x413)."""
    assert synced().receive(b"\x02\xfd") == bytes.fromhex("79 01 04 13 79")


def test_a_wrong_device_id_and_version_are_reported_as_set():
    chip = synced(device_id=0x419, bootloader_version=0x30)
    assert chip.receive(b"\x02\xfd") == bytes.fromhex("79 01 04 19 79")
    assert chip.receive(b"\x01\xfe") == bytes.fromhex("79 30 00 00 79")


def test_a_bad_complement_is_nacked_and_the_chip_waits_for_the_next_command():
    """AN3155 §3 "Communication safety": a command byte and its complement."""
    chip = synced()
    assert chip.receive(b"\x00\x00") == N
    assert chip.receive(b"\x00") == b""  # one byte: the chip waits for its complement
    assert chip.receive(b"\xff") == GET_ANSWER


def test_a_second_0x7f_is_the_first_byte_of_a_command_pair():
    """After sync 0x7F is not special: the next byte makes a pair that is NACKed."""
    chip = synced()
    assert chip.receive(b"\x7f") == b""
    assert chip.receive(b"\x7f") == N  # 0x7F 0x7F: bad complement
    assert chip.receive(b"\x7f\x80") == N  # 0x7F 0x80: no such command
    assert chip.receive(b"\x00\xff") == GET_ANSWER


@pytest.mark.parametrize("pair", [b"\x43\xbc", b"\xa1\x5e", b"\x50\xaf", b"\x51\xae", b"\x03\xfc"])
def test_commands_a_v3_1_bootloader_does_not_have_are_nacked(pair):
    """Erase 0x43 is exclusive with Extended Erase (AN3155 §4 Table 3, V3.0); Get
    Checksum is V3.3, Special / Extended Special later."""
    chip = synced()
    assert chip.receive(pair) == N
    assert chip.receive(b"\x00\xff") == GET_ANSWER


# --------------------------------------------------------------------------- (b) memory


def test_read_memory_of_erased_flash():
    """AN3155 §3.4: 11 EE -> ACK; address + XOR -> ACK; N, ~N -> ACK and N + 1 bytes."""
    chip = synced()
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(b"\x0f\xf0") == A + b"\xff" * 16


def test_read_memory_returns_the_initial_flash_contents():
    image = bytes(range(256))
    chip = synced(flash=image)
    assert read(chip, FLASH_0, 0xFF) == image


@pytest.mark.parametrize("address", [BOOT_RAM, EXTERNAL, bytes.fromhex("08100000 18")])
def test_read_memory_nacks_an_address_it_may_not_read(address):
    """The bootloader's RAM (V2.2), unmapped memory (V3.1 sends the NACK), the end of flash."""
    chip = synced()
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(address) == N
    assert chip.receive(b"\x00\xff") == GET_ANSWER


def test_read_memory_nacks_a_bad_address_checksum_and_a_bad_length_complement():
    chip = synced()
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(bytes.fromhex("08000000 00")) == N
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(b"\x0f\x0f") == N


def test_read_memory_nacks_a_range_that_runs_past_the_flash():
    chip = synced()
    assert read(chip, FLASH_END_16, 0x0F) == b"\xff" * 16
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(FLASH_END_16) == A
    assert chip.receive(b"\x1f\xe0") == N  # 32 bytes from 0x080FFFF0


def test_read_memory_of_system_memory_and_option_bytes():
    chip = synced()
    assert len(read(chip, SYSTEM_MEMORY, 0xFF)) == 256
    option_bytes = read(chip, OPTION_BYTES, 0x0F)
    assert option_bytes[1] == 0xAA  # RDP level 0 (RM0090 §3.6.1)
    assert option_bytes[8:10] == b"\xff\x0f"  # nWRP: no sector protected


def test_write_memory_to_erased_flash():
    """AN3155 §3.6: 31 CE -> ACK; address + XOR -> ACK; N, data, XOR(N, data) -> ACK."""
    chip = synced()
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(bytes.fromhex("03 de ad be ef 21")) == A
    assert chip.flash[:8] == bytes.fromhex("deadbeef ffffffff")
    assert read(chip, FLASH_0, 0x03) == bytes.fromhex("deadbeef")
    assert chip.written_bytes == 4


def test_write_memory_of_256_bytes():
    chip = synced()
    block = bytes((7 * i + 3) & 0xFF for i in range(256))
    assert write(chip, SECTOR_1, block) == A
    assert read(chip, SECTOR_1, 0xFF) == block


def test_write_memory_nacks_a_bad_data_checksum_and_writes_nothing():
    chip = synced()
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(bytes.fromhex("03 de ad be ef 20")) == N
    assert chip.flash[:4] == b"\xff" * 4


def test_write_memory_nacks_a_length_that_is_not_a_multiple_of_4():
    """AN3155 Figures 12/13: N + 1 must be a multiple of 4."""
    chip = synced()
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(bytes.fromhex("02 11 22 33 02")) == N
    assert chip.flash[:3] == b"\xff" * 3


def test_write_over_flash_that_is_not_erased_is_nacked():
    """Programming only clears bits (RM0090 §3.5.3): a write that needs a 0 -> 1 change
    does not read back as sent and the write "was not successful" (AN3155 §3.6)."""
    chip = synced()
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(bytes.fromhex("03 00 00 00 00 03")) == A
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_0) == A
    assert chip.receive(bytes.fromhex("03 ff ff ff ff 03")) == N
    assert chip.flash[:4] == b"\x00" * 4


def test_writes_that_only_clear_bits_are_acked_and_the_others_clear_what_they_can():
    chip = synced(flash=b"\xf0" * 8)
    assert write(chip, FLASH_0, b"\x00\x10\x20\x30") == A  # only 1 -> 0
    assert write(chip, FLASH_0, b"\x00\x10\x20\x30") == A  # the same again
    assert write(chip, bytes.fromhex("08000004 0c"), b"\x0f\x0f\x0f\x0f") == N
    assert chip.flash[:8] == bytes.fromhex("00102030 00000000")


def test_write_memory_nacks_an_address_it_may_not_write():
    for address in (BOOT_RAM, SYSTEM_MEMORY, EXTERNAL, OPTION_BYTES_4):
        chip = synced()
        assert chip.receive(b"\x31\xce") == A
        assert chip.receive(address) == N


def test_write_memory_nacks_a_block_that_runs_past_the_flash():
    chip = synced()
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(FLASH_END_16) == A
    data = bytes(32)
    assert chip.receive(bytes([0x1F]) + data + bytes([0x1F])) == N
    assert chip.flash[-16:] == b"\xff" * 16


def test_write_and_read_the_ram_the_bootloader_does_not_use():
    chip = synced()
    assert write(chip, USER_RAM, b"\x11\x22\x33\x44") == A
    assert chip.ram[0x3000:0x3004] == b"\x11\x22\x33\x44"
    assert read(chip, USER_RAM, 0x03) == b"\x11\x22\x33\x44"


def test_go_to_flash_acks_and_then_the_application_runs():
    """AN3155 §3.5: 21 DE -> ACK; address + XOR -> ACK; then the jump: no more answers."""
    vectors = (0x2002_0000).to_bytes(4, "little") + (0x0800_0199).to_bytes(4, "little")
    chip = synced(flash=vectors)
    assert chip.receive(b"\x21\xde") == A
    assert chip.receive(FLASH_0) == A
    assert chip.go_address == 0x0800_0000
    assert chip.go_vector() == (0x2002_0000, 0x0800_0199)
    assert chip.running and chip.state == "running"
    assert chip.receive(b"\x7f\x00\xff") == b""


def test_go_to_user_ram_is_acked():
    chip = synced()
    assert chip.receive(b"\x21\xde") == A
    assert chip.receive(USER_RAM) == A
    assert chip.go_address == 0x2000_3000


@pytest.mark.parametrize("address", [BOOT_RAM, SYSTEM_MEMORY, OPTION_BYTES, EXTERNAL,
                                     bytes.fromhex("08000000 09")])
def test_go_nacks_an_invalid_address_or_checksum(address):
    """AN3155 §3.5 note: only RAM or flash; V2.1/V2.2: not system memory, option bytes,
    nor the bootloader's RAM."""
    chip = synced()
    assert chip.receive(b"\x21\xde") == A
    assert chip.receive(address) == N
    assert chip.go_address is None
    assert chip.receive(b"\x00\xff") == GET_ANSWER


# --------------------------------------------------------------------------- (c) erase, protection


def test_extended_erase_mass_erase():
    """AN3155 §3.8: 44 BB -> ACK; FF FF 00 -> ACK."""
    chip = synced(flash=b"\x00" * 0x40000)
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(b"\xff\xff\x00") == A
    assert chip.flash == b"\xff" * (1 << 20)
    assert chip.erase_counts == [1] * 12
    assert chip.erased_sectors == 12


def test_extended_erase_of_listed_sectors():
    """AN3155 §3.8: N - 1 on two bytes, the sector numbers on two bytes, MSB first, and
    the XOR of all of them."""
    chip = synced(flash=b"\x00" * (1 << 20))
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(bytes.fromhex("0001 0000 0001 00")) == A  # sectors 0 and 1
    assert chip.flash[:0x8000] == b"\xff" * 0x8000
    assert chip.flash[0x8000:] == b"\x00" * ((1 << 20) - 0x8000)
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(bytes.fromhex("0000 0005 05")) == A  # sector 5: 0x08020000, 128 KiB
    assert chip.flash[0x20000:0x40000] == b"\xff" * 0x20000
    assert chip.flash[0x1FFFF] == 0 and chip.flash[0x40000] == 0
    assert chip.erase_counts == [1, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0]


@pytest.mark.parametrize("tail", [
    "ffff 01",            # mass erase, wrong checksum
    "fffe 01",            # bank 1 erase: the F405/407 has one bank
    "fffd 02",            # bank 2 erase
    "fffc 03",            # reserved
    "0000 0000 01",       # sector 0, wrong checksum
    "0000 000c 0c",       # sector 12 does not exist
    "000c" + "0000" * 13 + "0c",  # 13 sectors: more than the chip has
])
def test_extended_erase_nacks_bad_requests_and_erases_nothing(tail):
    chip = synced(flash=b"\x00" * (1 << 20))
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(bytes.fromhex(tail)) == N
    assert chip.flash == b"\x00" * (1 << 20)
    assert chip.erased_sectors == 0
    assert chip.receive(b"\x00\xff") == GET_ANSWER


def test_a_512k_part_has_8_sectors():
    chip = synced(flash_size=512 * 1024)
    assert len(chip.sectors) == 8
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(bytes.fromhex("0000 0008 08")) == N
    assert chip.receive(b"\x11\xee") == A
    assert chip.receive(bytes.fromhex("08080000 00")) == N


def test_write_protect_resets_and_protected_sectors_ignore_writes_and_erases():
    """AN3155 §3.9: 63 9C -> ACK; N, codes, XOR -> ACK; system reset (F4).
    AN3155 §3.6/§3.8 notes: no error on write-protected sectors."""
    chip = synced()
    assert chip.receive(b"\x63\x9c") == A
    assert chip.receive(bytes.fromhex("00 01 01")) == A  # protect sector 1
    assert chip.state == "sync"
    assert chip.receive(b"\x00\xff") == b""  # reset: waiting for 0x7F again
    assert chip.receive(b"\x7f") == A
    assert chip.write_protected == {1}
    assert write(chip, SECTOR_1, b"\x00\x00\x00\x00") == A
    assert chip.flash[0x4000:0x4004] == b"\xff" * 4
    assert write(chip, FLASH_0, b"\x00\x00\x00\x00") == A
    assert chip.receive(b"\x44\xbb") == A
    assert chip.receive(bytes.fromhex("0001 0000 0001 00")) == A
    assert chip.erase_counts[:2] == [1, 0] and chip.flash[:4] == b"\xff" * 4
    assert chip.receive(b"\x73\x8c") == A + A  # AN3155 §3.10, then a reset
    assert chip.receive(b"\x7f") == A
    assert chip.write_protected == set()
    assert write(chip, SECTOR_1, b"\x00\x00\x00\x00") == A
    assert chip.resets == 2


def test_write_protect_with_a_bad_checksum_is_nacked_without_reset():
    chip = synced()
    assert chip.receive(b"\x63\x9c") == A
    assert chip.receive(bytes.fromhex("00 01 00")) == N
    assert chip.state == "command"
    assert chip.write_protected == set()


def test_readout_protect_resets_and_only_get_get_version_get_id_are_served():
    """AN3155 §3.11: 82 7D -> ACK ACK, system reset; Table 2 note 2: with RDP active
    every other command is NACKed (Readout Unprotect aside)."""
    chip = synced(flash=b"\x12\x34\x56\x78")
    assert chip.receive(b"\x82\x7d") == A + A
    assert chip.read_protected
    assert chip.receive(b"\x7f") == A
    for pair in (b"\x11\xee", b"\x21\xde", b"\x31\xce", b"\x44\xbb", b"\x63\x9c", b"\x73\x8c", b"\x82\x7d"):
        assert chip.receive(pair) == N
    assert chip.receive(b"\x00\xff") == GET_ANSWER
    assert chip.receive(b"\x01\xfe") == bytes.fromhex("79 31 00 00 79")
    assert chip.receive(b"\x02\xfd") == bytes.fromhex("79 01 04 13 79")
    assert chip.flash[:4] == b"\x12\x34\x56\x78"


def test_readout_unprotect_erases_the_flash_clears_rdp_and_resets():
    """AN3155 §3.12: 92 6D -> ACK, mass erase, ACK, system reset."""
    chip = Stm32Bootloader(read_protected=True, flash=b"\x12\x34\x56\x78")
    chip.ram[0x5000] = 0x42
    assert chip.receive(b"\x7f") == A
    assert chip.receive(b"\x11\xee") == N
    assert chip.receive(b"\x92\x6d") == A + A
    assert not chip.read_protected
    assert chip.flash == b"\xff" * (1 << 20)
    assert chip.ram[0x5000] == 0  # V2.2: RAM cleared
    assert chip.state == "sync"
    assert chip.receive(b"\x7f") == A
    assert read(chip, FLASH_0, 0x03) == b"\xff" * 4


def test_a_write_to_the_option_bytes_rewrites_them_all_and_resets():
    """AN3155 §3.6: the start address must be the option bytes' base; they are erased,
    written, and the F4 resets."""
    chip = synced()
    image = bytes([0xEC, 0x55]) + b"\xff" * 6 + bytes([0xFF, 0x0F]) + b"\xff" * 6
    assert chip.receive(b"\x31\xce") == A
    assert chip.receive(OPTION_BYTES) == A
    assert chip.receive(bytes([0x0F]) + image + bytes([0x46])) == A  # XOR(0x0F, image) = 0x46
    assert checksum(bytes([0x0F]) + image) == 0x46
    assert chip.state == "sync" and chip.read_protected  # RDP 0x55: level 1
    assert chip.receive(b"\x7f") == A
    assert chip.receive(b"\x11\xee") == N


# --------------------------------------------------------------------------- (d) chunking, log, faults

SESSION = (
    b"\x7f" + b"\x00\xff" + b"\x01\xfe" + b"\x02\xfd"
    + b"\x44\xbb" + bytes.fromhex("0000 0000 00")
    + b"\x31\xce" + FLASH_0 + bytes.fromhex("03 de ad be ef 21")
    + b"\x11\xee" + FLASH_0 + b"\x03\xfc"
    + b"\x00\x00" + b"\x7f\x80"
    + b"\x31\xce" + FLASH_0 + bytes.fromhex("03 ff ff ff ff 03")
    + b"\x21\xde" + FLASH_0 + b"\x00\xff"
)
SESSION_ANSWER = (
    A + GET_ANSWER + bytes.fromhex("79 31 00 00 79") + bytes.fromhex("79 01 04 13 79")
    + A + A
    + A + A + A
    + A + A + A + bytes.fromhex("deadbeef")
    + N + N
    + A + A + N
    + A + A
)


def test_a_whole_session_at_once_byte_by_byte_and_in_random_chunks_gives_the_same_answers():
    assert Stm32Bootloader().receive(SESSION) == SESSION_ANSWER
    chip = Stm32Bootloader()
    assert b"".join(chip.receive(bytes([b])) for b in SESSION) == SESSION_ANSWER
    rng = random.Random(7)
    for _ in range(5):
        chip, answer, rest = Stm32Bootloader(), b"", SESSION
        while rest:
            size = rng.randint(1, 9)
            answer += chip.receive(rest[:size])
            rest = rest[size:]
        assert answer == SESSION_ANSWER
        assert chip.go_address == 0x0800_0000


def test_the_log_says_what_was_asked_and_answered():
    chip = Stm32Bootloader()
    chip.receive(SESSION)
    assert [entry.command for entry in chip.log] == [
        "Sync", "Get", "Get Version", "Get ID", "Extended Erase", "Write Memory", "Read Memory",
        "Get", "0x7F", "Write Memory", "Go"]
    assert chip.log[4] == LogEntry("Extended Erase", {"sectors": [0]}, "ACK")
    assert chip.log[5] == LogEntry("Write Memory", {"address": 0x0800_0000, "length": 4}, "ACK")
    assert chip.log[7] == LogEntry("Get", {"bytes": (0, 0), "reason": "bad complement"}, "NACK")
    assert chip.log[9].result == "NACK" and chip.log[9].args["reason"] == "flash not erased"
    assert chip.log[10] == LogEntry("Go", {"address": 0x0800_0000}, "ACK")
    assert chip.erased_sectors == 1 and chip.written_bytes == 4


def test_injected_nacks_refuse_a_command_at_its_command_byte():
    chip = synced(nack_commands={0x31, 0x44})
    assert chip.receive(b"\x31\xce") == N
    assert chip.receive(b"\x44\xbb") == N
    assert chip.receive(b"\x00\xff") == GET_ANSWER
    assert chip.log[-2] == LogEntry("Extended Erase", {"reason": "injected"}, "NACK")


def test_a_silent_chip_stops_answering_after_n_bytes():
    chip = Stm32Bootloader(silent_after_bytes=2)
    assert chip.receive(b"\x7f\x00\xff") == A  # 0xFF, the third byte, never arrives
    assert chip.state == "silent"
    assert chip.receive(b"\x7f\x00\xff\x7f") == b""
    assert chip.received_bytes == 7


def test_a_silent_chip_in_the_middle_of_a_write():
    session = b"\x7f" + b"\x31\xce" + FLASH_0 + bytes.fromhex("03 de ad be ef 21")
    chip = Stm32Bootloader(silent_after_bytes=len(session) - 3)
    assert chip.receive(session) == A + A + A
    assert chip.flash[:4] == b"\xff" * 4


def test_a_reset_in_the_middle_of_a_write_loses_the_command_and_keeps_the_flash():
    first = b"\x7f" + b"\x31\xce" + FLASH_0 + bytes.fromhex("03 de ad be ef 21")
    second = b"\x31\xce" + SECTOR_1 + bytes.fromhex("03 01 02 03 04 07")
    chip = Stm32Bootloader(reset_after_bytes=len(first) + 9)  # after its first data byte
    assert chip.receive(first) == A + A + A + A
    assert chip.receive(second) == A + A  # the rest goes to a chip waiting for 0x7F
    assert chip.log[-1] == LogEntry("Reset", {"cause": "injected"}, "reset")
    assert chip.state == "sync"
    assert chip.receive(b"\x7f") == A
    assert read(chip, FLASH_0, 0x03) == bytes.fromhex("deadbeef")
    assert read(chip, SECTOR_1, 0x03) == b"\xff" * 4
    assert chip.resets == 1


def test_reset_after_go_brings_the_bootloader_back():
    chip = synced()
    chip.receive(b"\x21\xde" + FLASH_0)
    assert chip.running
    chip.reset()
    assert chip.state == "sync" and chip.receive(b"\x7f") == A


def test_rdp_level_2_never_answers():
    chip = Stm32Bootloader()
    chip.option_bytes[1] = 0xCC
    assert chip.receive(b"\x7f\x7f\x00\xff") == b""


# --------------------------------------------------------------------------- (e) on a pty


def open_port(address: str, timeout: float = 2.0) -> serial.Serial:
    """8E1 as AN3155 asks. A pty drops PARENB, and some kernels then refuse (EINVAL) a later
    tcsetattr whose only change is PARENB: set everything here, change nothing later."""
    return serial.Serial(address, 115200, parity=serial.PARITY_EVEN, timeout=timeout)


def exchange(port: serial.Serial, data: bytes, n: int) -> bytes:
    port.write(data)
    return port.read(n)


def test_bootloader_port_flashes_reads_back_and_bridges_after_go():
    firmware_side, bridge_side = socket.socketpair()
    calls = []

    def on_go(address, flash):
        calls.append((address, flash[:8]))
        firmware_side.sendall(b"HELLO")  # what the booted firmware says first
        return bridge_side

    image = (0x2002_0000).to_bytes(4, "little") + (0x0800_0199).to_bytes(4, "little")
    with BootloaderPort(on_go=on_go) as port, open_port(port.address) as host:
        assert exchange(host, b"\x7f", 1) == A
        assert exchange(host, b"\x00\xff", 15) == GET_ANSWER
        assert exchange(host, b"\x44\xbb", 1) == A
        assert exchange(host, b"\xff\xff\x00", 1) == A
        assert exchange(host, b"\x31\xce", 1) == A
        assert exchange(host, FLASH_0, 1) == A
        assert exchange(host, bytes([7]) + image + bytes([checksum(bytes([7]) + image)]), 1) == A
        assert exchange(host, b"\x11\xee", 1) == A
        assert exchange(host, FLASH_0, 1) == A
        assert exchange(host, b"\x07\xf8", 9) == A + image
        assert exchange(host, b"\x21\xde", 1) == A
        assert exchange(host, FLASH_0, 1) == A
        assert host.read(5) == b"HELLO"
        host.write(b"ping")
        firmware_side.settimeout(2)
        received = b""
        while len(received) < 4:
            received += firmware_side.recv(16)
        assert received == b"ping"
        assert calls == [(0x0800_0000, image)]
        assert port.bootloader.go_address == 0x0800_0000
        assert port.error is None
    firmware_side.close()


def test_bootloader_port_without_callback_is_silent_after_go():
    with BootloaderPort(Stm32Bootloader(flash=b"\x00" * 8)) as port, open_port(port.address, 0.3) as host:
        assert exchange(host, b"\x7f\x21\xde", 2) == A + A
        assert exchange(host, FLASH_0, 1) == A
        started = time.monotonic()
        assert exchange(host, b"\x7f\x00\xff", 1) == b""
        assert time.monotonic() - started < 1.0
        assert port.bootloader.running and port.bridge is None


def test_the_flash_size_register_tells_the_flash_size_in_kib():
    """RM0090 section 39.2: a read-only u16 at 0x1FFF7A22, the flash size in KiB."""
    for size in (512 * 1024, 1 << 20):
        chip = synced(flash_size=size)
        address = bytes.fromhex("1fff7a22")
        assert read(chip, address + bytes([checksum(address)]), 1) == (size // 1024).to_bytes(2, "little")
