#!/usr/bin/env python3
"""Cortex-M4 cost of the fixed-point core: instruction counts, stack and memory.

Builds firmware/core/*.c for the Cortex-M4 with the firmware's flags
(arm-none-eabi-gcc -std=c99 -O2 -mcpu=cortex-m4 -mthumb -mfloat-abi=soft -DIMU_FIXED
-ffunction-sections -fdata-sections) and the harness tools/arm_bench/harness.c into one
ELF, checks that it links no floating-point routine and holds no VFP instruction, then
runs the compiled functions in the unicorn emulator and measures, per filter (EECF,
KF1D, ESKF with 6 and with 9 states, default settings, simulated random motion (by default) at
100 Hz):

- Thumb-2 instructions executed by imu_filter_update_raw and imu_filter_get per
  sample (mean and max), split by phase where the cost differs: the EECF's alignment
  and filtering, the ESKF's first sample, propagation-only samples and fusion samples
  (every third sample runs the covariance and measurement updates);
- that every output matches the host fixed build bit for bit on every sample
  (quaternion Q30, Euler Q29, gyro bias Q24, saturation count, ESKF covariance
  diagonal): the benchmark fails at the first difference;
- the frame codec: SAMPLE + ESTIMATE encoding per sample (bytes checked against
  imulink.protocol) and imu_proto_decoder_push per byte over the resulting stream
  (decoded frames checked);
- the deepest stack each measured function used (painted stack), next to the static
  estimate from -fstack-usage / -fcallgraph-info;
- flash (code + rodata) and RAM (data + bss) of each filter's objects, of the shared
  math and of the codec, and the state sizes (sizeof on the target);
- with --profile, where the instructions go: per measured call (update_raw, get, the
  two encoders), the instructions executed inside each function (its own, callees
  apart), per call;
- with --lines N, the N source lines of each filter's update_raw and get that executed
  the most instructions per call (inlined code counted at its own line, with the
  function it was compiled into), from a build with -g (the same code);
- with --optimize O3 (or Os), the same at another optimisation level than the
  firmware's -O2: what another level would give;
- with --scenario static (or rests, turntable), the same on another simulated motion:
  the ESKF's costliest fusion steps are at rest, where it also runs the rest updates;
- with --cycles, bounds on the cycles of each filter's update and get at zero wait
  states, from the instructions executed and the Cortex-M4's instruction timings
  (tools/arm_cycles.py).

Instructions are not cycles: on a Cortex-M4 most take one cycle, loads and stores
two, divisions 2-12; the DWT cycle counter on a board is the cycle truth.

    .venv/bin/python tools/bench_arm.py [--samples 4000] [--filters eecf,kf1d,eskf,eskf9] [--profile] [--lines N]
                                        [--optimize O2|O3|Os] [--scenario random|static|rests|turntable]
                                        [--cycles] [--json]

Needs arm-none-eabi-gcc (with newlib) on the PATH and the Python package unicorn.
The full run takes a few minutes (every instruction is emulated).
"""
from __future__ import annotations

import argparse
import bisect
import collections
import datetime
import json
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from cobs import cobs

sys.path.insert(0, str(Path(__file__).resolve().parent))
import arm_cycles  # noqa: E402  (tools/arm_cycles.py)
from imulink import core, protocol, sim
from imulink.core.counts import DEFAULT_PROFILE

try:
    import unicorn
    from unicorn import arm_const
except ImportError:  # reported when an emulator is made, so --help and the build still work
    unicorn = None

ROOT = Path(__file__).resolve().parents[1]
CORE_DIR = ROOT / "firmware" / "core"
HARNESS_DIR = ROOT / "tools" / "arm_bench"
HARNESS = HARNESS_DIR / "harness.c"
LINKER_SCRIPT = HARNESS_DIR / "bench.ld"

CC = "arm-none-eabi-gcc"
TARGET_FLAGS = ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=soft"]
#: The firmware's optimisation level and compile flags: the code measured here is the code the board runs.
OPTIMIZE = "-O2"
CFLAGS = ["-std=c99", OPTIMIZE, *TARGET_FLAGS, "-DIMU_FIXED", "-ffunction-sections", "-fdata-sections"]
#: Levels --optimize may try instead (what-if measurements: the firmware stays at OPTIMIZE).
OPTIMIZE_LEVELS = ("-O2", "-O3", "-Os")
#: Analysis outputs only (.su, .ci files): they do not change the generated code.
ANALYSIS_FLAGS = ["-fstack-usage", "-fcallgraph-info=su"]
LDFLAGS = [*TARGET_FLAGS, "-nostartfiles", "-Wl,--gc-sections"]


def compile_flags(optimize: str = OPTIMIZE) -> list[str]:
    """CFLAGS with another optimisation level."""
    return [optimize if flag == OPTIMIZE else flag for flag in CFLAGS]


# Memory map (tools/arm_bench/bench.ld).
FLASH_BASE, FLASH_SIZE = 0x0800_0000, 1024 * 1024
RAM_BASE, RAM_SIZE = 0x2000_0000, 128 * 1024
#: Bytes below the stack top painted to find the deepest stack use (far more than any call needs).
STACK_WINDOW = 16 * 1024
STACK_PAINT = 0xC5A5_5A3C  # a word no register or pointer of this code is likely to hold

RATE_HZ = 100.0
SCENARIO = "random"
SCENARIO_SEED = 0
#: MPU6050 temperature register at 25 degC ((25 - 36.53) * 340): SAMPLE carries it.
TEMPERATURE_COUNTS = -3920


class BenchError(RuntimeError):
    """The toolchain or emulator is missing, or a check of the benchmark failed."""


@dataclass(frozen=True)
class FilterConfig:
    key: str
    filter_name: str
    settings: dict
    label: str


CONFIGS = {
    "eecf": FilterConfig("eecf", "eecf", {}, "EECF"),
    "kf1d": FilterConfig("kf1d", "kf1d", {}, "KF1D"),
    "eskf": FilterConfig("eskf", "eskf", {}, "ESKF 6 states"),
    "eskf9": FilterConfig("eskf9", "eskf", {"estimate_acc_bias": 1.0}, "ESKF 9 states"),
}

#: Objects whose sizes are reported, per row of the memory part of the table.
SIZE_GROUPS = {
    "eecf": ["imu_eecf"],
    "kf1d": ["imu_kf1d"],
    "eskf": ["imu_eskf", "imu_cov"],
    "shared": ["imu_math", "imu_sensor", "imu_filter"],
    "codec": ["imu_proto", "imu_proto_gen"],
}

# ============================================================================ build


@dataclass
class Symbol:
    address: int
    size: int
    kind: str  # nm's letter: T/t code, R/r rodata, D/d data, B/b bss


@dataclass
class ArmBuild:
    directory: Path
    elf: Path
    objects: dict[str, Path]  # stem -> object file
    symbols: dict[str, Symbol]
    compiler: str  # first line of `arm-none-eabi-gcc --version`
    _listing: str | None = field(default=None, repr=False)

    def disassembly(self) -> str:
        """`arm-none-eabi-objdump -d` of the ELF (run once)."""
        if self._listing is None:
            self._listing = _run([_tool("arm-none-eabi-objdump"), "-d", "--no-show-raw-insn", self.elf],
                                 "arm-none-eabi-objdump")
        return self._listing

    def address(self, name: str) -> int:
        try:
            return self.symbols[name].address
        except KeyError:
            raise BenchError(f"symbol {name!r} is not in {self.elf}") from None


def _tool(name: str) -> str:
    """Full name of a binutils/gcc program of the Arm toolchain, found next to the compiler."""
    path = shutil.which(CC)
    if path is None:
        raise BenchError(f"{CC} not found on PATH: install the GNU Arm Embedded toolchain with newlib "
                         "(Debian/Ubuntu: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    sibling = Path(path).with_name(name)
    return str(sibling) if sibling.exists() else name


def _run(cmd: list, what: str, cwd: Path | None = None) -> str:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BenchError(f"{what} failed ({proc.returncode}):\n$ {' '.join(map(str, cmd))}\n{proc.stdout}{proc.stderr}")
    return proc.stdout


def core_sources() -> list[Path]:
    return sorted(CORE_DIR.glob("*.c"))


def build_arm(directory: Path, debug_info: bool = False, optimize: str = OPTIMIZE) -> ArmBuild:
    """Compile the core and the harness for the Cortex-M4 and link them into bench.elf in `directory`;
    with `debug_info`, also with -g (line tables for the line profile: the same code); `optimize`
    replaces the firmware's -O2."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    gcc = _tool(CC)
    compiler = _run([gcc, "--version"], "arm-none-eabi-gcc --version").splitlines()[0]
    objects = {}
    for src in [*core_sources(), HARNESS]:
        obj = directory / (src.stem + ".o")
        # Run in `directory` so the .su and .ci files land next to the objects.
        debug = ["-g"] if debug_info else []
        _run([gcc, *compile_flags(optimize), *ANALYSIS_FLAGS, *debug, f"-I{CORE_DIR}", "-c", src, "-o", obj],
             f"compiling {src.name}", cwd=directory)
        objects[src.stem] = obj
    elf = directory / "bench.elf"
    _run([gcc, *LDFLAGS, "-T", LINKER_SCRIPT, f"-Wl,-Map={directory / 'bench.map'}", *objects.values(),
          "-o", elf], "linking bench.elf")
    return ArmBuild(directory, elf, objects, read_symbols(elf), compiler)


def read_symbols(elf: Path) -> dict[str, Symbol]:
    out = _run([_tool("arm-none-eabi-nm"), "-S", "--defined-only", elf], "arm-none-eabi-nm")
    symbols = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4:
            symbols[parts[3]] = Symbol(int(parts[0], 16), int(parts[1], 16), parts[2])
        elif len(parts) == 3:
            symbols[parts[2]] = Symbol(int(parts[0], 16), 0, parts[1])
    return symbols


def function_ranges(elf: Path) -> tuple[list[int], list[str]]:
    """Start addresses (sorted) and names of the ELF's functions, static ones included; a
    static function whose name another function shares is named with its source file."""
    out = _run([_tool("arm-none-eabi-readelf"), "-sW", elf], "arm-none-eabi-readelf")
    functions = []  # (address, name, file of a local symbol)
    source = ""
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 8 and parts[3] == "FILE":
            source = parts[7]
        elif len(parts) == 8 and parts[3] == "FUNC":
            functions.append((int(parts[1], 16) & ~1, parts[7], source if parts[4] == "LOCAL" else ""))
    counts = collections.Counter(name for _, name, _ in functions)
    functions.sort()
    return ([address for address, _, _ in functions],
            [f"{name} ({source})" if counts[name] > 1 and source else name for _, name, source in functions])


# ============================================================================ no floating point

#: Soft-float helpers of libgcc (AEABI names and the generic ones they alias) and the libm
#: functions the twin build uses: none may be linked into the fixed build.
FLOAT_SYMBOL = re.compile(r"^(__aeabi_[fd]\w*|__\w*[sd]f\d?|__(float|fix)\w*|__(un)?ord[sd]f2|"
                          r"(sqrt|sin|cos|tan|asin|acos|atan|atan2|exp|log|pow|fabs|floor|ceil|fmod|hypot)f?)$")


def float_problems(build: ArmBuild) -> list[str]:
    """Floating-point symbols and VFP instructions in the ELF (empty: integer only)."""
    problems = [f"symbol {name}" for name in sorted(build.symbols) if FLOAT_SYMBOL.match(name)]
    listing = build.disassembly()
    function = "?"
    for line in listing.splitlines():
        header = re.match(r"^[0-9a-f]+ <(.+)>:$", line)
        if header:
            function = header.group(1)
            continue
        parts = line.split("\t")
        if len(parts) < 2 or not re.match(r"^\s*[0-9a-f]+:$", parts[0]):
            continue
        mnemonic = parts[1].strip().split(" ")[0]
        operands = parts[2] if len(parts) > 2 else ""
        # The Cortex-M4 has no Advanced SIMD: every v-mnemonic is a VFP instruction; coprocessors
        # 10 and 11 are the FPU (raw mrc/mcr/ldc/stc forms of the same).
        if mnemonic.startswith("v") or (re.match(r"^(mrc|mcr|mrrc|mcrr|ldc|stc|cdp)", mnemonic)
                                        and re.search(r"\bp1[01]\b", operands)):
            problems.append(f"VFP instruction in {function}: {parts[0].strip()} {mnemonic} {operands.strip()}")
    return problems


def instruction_listing(build: ArmBuild) -> dict[int, tuple[str, str]]:
    """Every instruction of the ELF by address: (mnemonic, operands) as objdump prints them."""
    listing = {}
    for line in build.disassembly().splitlines():
        parts = line.split("\t")
        address = re.match(r"^\s*([0-9a-f]+):$", parts[0])
        if address and len(parts) >= 2:
            listing[int(address.group(1), 16)] = (parts[1].strip(), parts[2].strip() if len(parts) > 2 else "")
    return listing


def check_no_float(build: ArmBuild) -> None:
    problems = float_problems(build)
    if problems:
        raise BenchError("the fixed-point ELF uses floating point:\n  " + "\n  ".join(problems[:40]))


# ============================================================================ memory and static stack


def object_sizes(build: ArmBuild) -> dict[str, dict[str, int]]:
    """Berkeley sizes of each object: text (code + rodata), data, bss."""
    out = _run([_tool("arm-none-eabi-size"), "-B", *build.objects.values()], "arm-none-eabi-size")
    sizes = {}
    for line in out.splitlines()[1:]:
        text, data, bss, _dec, _hex, name = line.split()
        sizes[Path(name).stem] = {"text": int(text), "data": int(data), "bss": int(bss)}
    return sizes


def library_sizes(build: ArmBuild) -> dict[str, int]:
    """Bytes the link took from libgcc / libc (64-bit division, memcpy, ...), per archive member."""
    text = (build.directory / "bench.map").read_text()
    text = text[text.index("Linker script and memory map"):]
    sizes: dict[str, int] = {}
    # An input section: name (possibly alone on its line), address, size, file.
    for match in re.finditer(r"^ (\.(?:text|rodata|data|bss)\S*)\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)\s+(\S+)$", text,
                             re.MULTILINE):
        member = re.search(r"\(([^)]+)\)$", match.group(4))
        if member:
            sizes[member.group(1)] = sizes.get(member.group(1), 0) + int(match.group(3), 16)
    return sizes


@dataclass
class _CallGraph:
    frames: dict[tuple[str, str], int] = field(default_factory=dict)  # (file, function) -> bytes
    edges: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    by_name: dict[str, list[tuple[str, str]]] = field(default_factory=dict)


def _read_call_graph(build: ArmBuild) -> _CallGraph:
    graph = _CallGraph()
    for ci in sorted(build.directory.glob("*.ci")):
        text = ci.read_text()
        for title, label in re.findall(r'node: \{ title: "([^"]+)" label: "([^"]*)"', text):
            size = re.search(r"\\n(\d+) bytes \((?:static|dynamic|bounded)", label)
            if size:
                key = (ci.stem, title)
                graph.frames[key] = int(size.group(1))
                graph.by_name.setdefault(title, []).append(key)
        for source, target in re.findall(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', text):
            graph.edges.setdefault((ci.stem, source), []).append(target)
    return graph


def _disassembled_frames(build: ArmBuild) -> dict[str, tuple[int, list[str]]]:
    """Stack frame and callees of every function of the ELF, read from its instructions: for
    libgcc's and newlib's assembly helpers, which have no .su data. The frame is the sum of
    every push, stmdb sp!, pre-indexed store to sp and sub sp in the function (an upper bound
    when they sit on different paths); callees are bl targets and tail calls (b to another
    function)."""
    listing = build.disassembly()
    functions: dict[str, tuple[int, list[str]]] = {}
    name, frame, callees = None, 0, []
    for line in listing.splitlines() + ["00000000 <end>:"]:
        header = re.match(r"^[0-9a-f]+ <(.+)>:$", line)
        if header:
            if name is not None:
                functions[name] = (frame, callees)
            name, frame, callees = header.group(1), 0, []
            continue
        parts = line.split("\t")
        if len(parts) < 3:
            continue
        mnemonic, operands = parts[1].strip(), parts[2].strip()
        if mnemonic in ("push", "push.w") or (mnemonic.startswith("stmdb") and operands.startswith("sp!")):
            frame += 4 * arm_cycles.register_count(operands)
        elif re.match(r"^subs?(\.w)?$", mnemonic) and re.match(r"^sp, (sp, )?#\d+$", operands):
            frame += int(operands.rsplit("#", 1)[1])
        elif mnemonic.startswith("str") and re.search(r"\[sp, #-(\d+)\]!", operands):
            frame += int(re.search(r"\[sp, #-(\d+)\]!", operands).group(1))
        target = re.search(r"<([^+>]+)>$", operands)
        if target and (mnemonic.startswith("bl") or (mnemonic in ("b", "b.w", "b.n") and target.group(1) != name)):
            callees.append(target.group(1))
    return functions


def static_stack(build: ArmBuild, root: str, exclude: frozenset = frozenset(),
                 indirect: tuple[str, ...] = ()) -> tuple[int, list[str]]:
    """Deepest stack of `root` from the compiler's frame sizes and call graph (no recursion in
    the core); library helpers without .su data get their frames from the disassembly. A call
    through a pointer (the filter table's) may reach the functions `indirect`.
    Returns (bytes, functions on the way whose frames are unknown)."""
    graph = _read_call_graph(build)
    for name, (frame, callees) in _disassembled_frames(build).items():
        if name not in graph.by_name:
            graph.frames[("elf", name)] = frame
            graph.by_name[name] = [("elf", name)]
            graph.edges[("elf", name)] = callees
    unknown: set[str] = set()
    memo: dict[tuple[str, str], int] = {}

    def resolve(file: str, name: str) -> list[tuple[str, str]]:
        if name == "__indirect_call":
            return [key for target in indirect for key in resolve(file, target)]
        if (file, name) in graph.frames:  # a static function of the same file first
            return [(file, name)]
        return graph.by_name.get(name, [])

    def depth(key: tuple[str, str]) -> int:
        if key not in memo:
            deepest = 0
            for target in graph.edges.get(key, []):
                if target in exclude:
                    continue
                callees = resolve(key[0], target)
                if not callees:
                    unknown.add(target)
                for callee in callees:
                    deepest = max(deepest, depth(callee))
            memo[key] = graph.frames[key] + deepest
        return memo[key]

    roots = graph.by_name.get(root)
    if not roots:
        raise BenchError(f"no stack usage of {root} in the .ci files")
    return max(depth(r) for r in roots), sorted(unknown)


# ============================================================================ emulator


def thumb_instruction_offsets(code: bytes) -> list[int]:
    """Offsets of the Thumb-2 instructions in `code`, which starts on an instruction: a
    halfword whose top five bits are 0b11101, 0b11110 or 0b11111 starts a 32-bit instruction."""
    offsets = []
    i = 0
    end = len(code) - 1
    while i < end:
        offsets.append(i)
        top = code[i + 1] >> 3  # little-endian halfword: bits 15..11 are in the second byte
        i += 4 if top >= 0b11101 else 2
    return offsets


def thumb_instruction_count(code: bytes) -> int:
    """Number of Thumb-2 instructions in `code` (see thumb_instruction_offsets)."""
    return len(thumb_instruction_offsets(code))


@dataclass
class CallResult:
    value: int          # r0
    instructions: int   # Thumb-2 instructions executed (block-hook count)
    stack: int          # deepest stack use in bytes below the SP at the call (0 when not measured)
    instructions_each: int | None = None  # reference count of the per-instruction hook, when enabled
    it_skipped: int | None = None  # of those, IT-block instructions whose condition failed
    cycles: tuple[int, int] | None = None  # (least, most) cycles at zero wait states (arm_cycles), when enabled


class Emulator:
    """The benchmark ELF in a unicorn Cortex-M4, ready to have its functions called.

    Instructions are counted by a block hook (one Python call per translated-block
    execution, the instructions of each block counted once and cached); with
    `count_each_instruction` a per-instruction hook counts as well, to check the former.
    """

    def __init__(self, build: ArmBuild, count_each_instruction: bool = False, profile: bool = False,
                 profile_lines: bool = False, cycles: bool = False):
        if unicorn is None:
            raise BenchError("the Python package unicorn is missing: .venv/bin/pip install unicorn")
        self.build = build
        self.uc = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
        self.uc.ctl_set_cpu_model(arm_const.UC_CPU_ARM_CORTEX_M4)
        self.uc.mem_map(FLASH_BASE, FLASH_SIZE, unicorn.UC_PROT_READ | unicorn.UC_PROT_EXEC)
        self.uc.mem_map(RAM_BASE, RAM_SIZE, unicorn.UC_PROT_READ | unicorn.UC_PROT_WRITE)
        for address, data in load_segments(build.elf.read_bytes()):
            self.uc.mem_write(address, data)
        self.halt = build.address("bench_halt")
        self.stack_top = build.address("__stack_top")
        self.stack_bottom = self.stack_top - STACK_WINDOW
        if build.address("__bss_end__") > self.stack_bottom:
            raise BenchError("the harness data overlaps the painted stack window")
        self._paint = struct.pack("<I", STACK_PAINT) * (STACK_WINDOW // 4)
        self.uc.mem_write(self.stack_bottom, self._paint)
        self._block_instructions: dict[tuple[int, int], int] = {}
        self.instructions = 0
        self.uc.hook_add(unicorn.UC_HOOK_BLOCK, self._on_block)
        self.count_each_instruction = count_each_instruction
        self.instructions_each = 0
        self.it_skipped = 0
        self._it_pending: list[int] = []
        self._decoded: dict[int, tuple[int, list[int]]] = {}  # address -> (size by the halfword rule, IT block)
        if count_each_instruction:
            self.uc.hook_add(unicorn.UC_HOOK_CODE, self._on_instruction)
        self._functions: dict[str, int] = {}
        #: With `profile`: instructions per (called function, function executing), and calls per called function.
        self.profile: collections.Counter | None = collections.Counter() if profile else None
        self.profile_calls: collections.Counter = collections.Counter()
        self._calling = ""
        self._function_starts, self._function_names = (function_ranges(build.elf) if profile or profile_lines
                                                       else ([], []))
        #: With `profile_lines`: executions per (called function, block address, block size).
        self.block_counts: collections.Counter | None = collections.Counter() if profile_lines else None
        #: With `cycles`: the instructions by address, each block's (least, most) cycles, the sums of a call
        #: and the refills (execution jumped: a taken branch or another write of the PC).
        self._listing = instruction_listing(build) if cycles else None
        self.counts_cycles = cycles
        self._block_cycles: dict[tuple[int, int], tuple[int, int]] = {}
        self.cycles_least = self.cycles_most = self.refills = 0
        self._block_end: int | None = None

    def _on_block(self, uc, address, size, _user):
        key = (address, size)
        n = self._block_instructions.get(key)
        if n is None:
            n = self._block_instructions[key] = thumb_instruction_count(bytes(uc.mem_read(address, size)))
        self.instructions += n
        if self.profile is not None:
            self.profile[self._calling, self.function_at(address)] += n
        if self.block_counts is not None:
            self.block_counts[self._calling, address, size] += 1
        if self.counts_cycles:
            self._count_cycles(key)

    def _count_cycles(self, block: tuple[int, int]) -> None:
        address, size = block
        cost = self._block_cycles.get(block)
        if cost is None:
            cost = self._block_cycles[block] = arm_cycles.block_cycles(
                [self._listing[address + offset] for offset in thumb_instruction_offsets(self.read(address, size))])
        self.cycles_least += cost[0]
        self.cycles_most += cost[1]
        if self._block_end is not None and address != self._block_end:
            self.refills += 1
        self._block_end = address + size

    def function_at(self, address: int) -> str:
        """The function whose code holds `address` (an emulator made with profile or profile_lines)."""
        return self._function_names[bisect.bisect_right(self._function_starts, address) - 1]

    def _on_instruction(self, uc, address, size, _user):
        """Reference count, one call per instruction. unicorn does not call this hook for an
        instruction of an IT block whose condition fails, although the core issues it (and
        the block count includes it): those are counted from the IT instruction's mask."""
        self.instructions_each += 1
        if self._it_pending:
            if address in self._it_pending:
                done = self._it_pending.index(address)
                self.it_skipped += done
                del self._it_pending[: done + 1]
            else:
                self.it_skipped += len(self._it_pending)
                self._it_pending.clear()
        decoded = self._decoded.get(address)
        if decoded is None:
            decoded = self._decoded[address] = self._decode(address)
        if decoded[0] != size:
            raise BenchError(f"instruction at 0x{address:08x}: unicorn says {size} bytes, the halfword rule "
                             f"{decoded[0]}")
        if decoded[1]:
            self._it_pending = list(decoded[1])

    def _decode(self, address: int) -> tuple[int, list[int]]:
        """(size, addresses of the instructions an IT instruction at `address` covers)."""
        code = bytes(self.uc.mem_read(address, 2))
        size = 4 if code[1] >> 3 >= 0b11101 else 2
        mask = code[0] & 0xF
        if code[1] != 0xBF or mask == 0:  # not IT (0xBFxx with mask 0 is a hint: NOP, WFI, ...)
            return size, []
        covered = 4 - ((mask & -mask).bit_length() - 1)  # the lowest set bit of the mask ends the block
        block, next_address = [], address + 2
        for _ in range(covered):
            block.append(next_address)
            next_address += 4 if self.uc.mem_read(next_address + 1, 1)[0] >> 3 >= 0b11101 else 2
        return size, block

    def address(self, name: str) -> int:
        return self.build.address(name)

    def read(self, name_or_address, size: int) -> bytes:
        address = self.address(name_or_address) if isinstance(name_or_address, str) else name_or_address
        return bytes(self.uc.mem_read(address, size))

    def write(self, name_or_address, data: bytes) -> None:
        address = self.address(name_or_address) if isinstance(name_or_address, str) else name_or_address
        self.uc.mem_write(address, bytes(data))

    def call(self, function: str, *args: int, measure_stack: bool = True) -> CallResult:
        """Call a C function per the AAPCS: first four arguments in r0-r3, the rest on the
        stack; LR is bench_halt, where the emulator stops. With `measure_stack` the painted
        stack is scanned (and repainted) afterwards; otherwise see take_stack_depth()."""
        entry = self._functions.get(function)
        if entry is None:
            entry = self._functions[function] = self.address(function)
        sp = self.stack_top
        if len(args) > 4:
            extra = args[4:]
            sp = (sp - 4 * len(extra)) & ~7  # 8-byte aligned at a public interface
            self.uc.mem_write(sp, struct.pack(f"<{len(extra)}I", *(a & 0xFFFF_FFFF for a in extra)))
        for register, value in zip((arm_const.UC_ARM_REG_R0, arm_const.UC_ARM_REG_R1,
                                    arm_const.UC_ARM_REG_R2, arm_const.UC_ARM_REG_R3), args):
            self.uc.reg_write(register, value & 0xFFFF_FFFF)
        self.uc.reg_write(arm_const.UC_ARM_REG_SP, sp)
        self.uc.reg_write(arm_const.UC_ARM_REG_LR, self.halt | 1)  # Thumb return address
        self.instructions = 0
        self.instructions_each = 0
        self.it_skipped = 0
        self.cycles_least = self.cycles_most = self.refills = 0
        self._block_end = None
        self._calling = function
        self.profile_calls[function] += 1
        try:
            self.uc.emu_start(entry | 1, self.halt)
        except unicorn.UcError as exc:
            pc = self.uc.reg_read(arm_const.UC_ARM_REG_PC)
            raise BenchError(f"{function} stopped in the emulator at pc=0x{pc:08x}: {exc}") from None
        value = self.uc.reg_read(arm_const.UC_ARM_REG_R0)
        stack = self.take_stack_depth(sp) if measure_stack else 0
        cycles = None
        if self.counts_cycles:
            refills = self.refills + 1  # the return to bench_halt, where the emulator stops before a block
            least_refill, most_refill = arm_cycles.REFILL
            cycles = (self.cycles_least + refills * least_refill, self.cycles_most + refills * most_refill)
        if not self.count_each_instruction:
            return CallResult(value, self.instructions, stack, cycles=cycles)
        self.it_skipped += len(self._it_pending)  # an IT block at the very end of the call
        self._it_pending.clear()
        return CallResult(value, self.instructions, stack, self.instructions_each + self.it_skipped, self.it_skipped,
                          cycles)

    def take_stack_depth(self, sp: int | None = None) -> int:
        """Bytes below `sp` (default: the stack top) written since the last scan; repaints them."""
        sp = self.stack_top if sp is None else sp
        words = np.frombuffer(self.uc.mem_read(self.stack_bottom, STACK_WINDOW), dtype="<u4")
        written = np.flatnonzero(words != STACK_PAINT)
        if written.size == 0:
            return 0
        if written[0] == 0:
            raise BenchError(f"the stack reached the bottom of the {STACK_WINDOW}-byte painted window")
        lowest = self.stack_bottom + 4 * int(written[0])
        self.uc.mem_write(lowest, self._paint[: self.stack_top - lowest])
        return max(0, sp - lowest)


def load_segments(elf: bytes) -> list[tuple[int, bytes]]:
    """(run address, bytes) of each loadable segment of a little-endian ELF32 file. .data is
    loaded at its RAM address directly: no start-up code copies it."""
    if elf[:4] != b"\x7fELF" or elf[4] != 1 or elf[5] != 1:
        raise BenchError("not a little-endian ELF32 file")
    phoff = struct.unpack_from("<I", elf, 0x1C)[0]
    phentsize, phnum = struct.unpack_from("<HH", elf, 0x2A)
    segments = []
    for i in range(phnum):
        p_type, offset, vaddr, _paddr, filesz, _memsz, _flags, _align = struct.unpack_from(
            "<8I", elf, phoff + i * phentsize)
        if p_type == 1 and filesz:  # PT_LOAD; .bss is zero in freshly mapped memory
            segments.append((vaddr, elf[offset:offset + filesz]))
    return segments


# ============================================================================ filters


def scenario_seconds(samples: int) -> float:
    """Duration (s) of the simulated motion that holds `samples` samples at RATE_HZ (at least one)."""
    return max(samples, 1) / RATE_HZ


def scenario_call(samples: int, scenario: str = SCENARIO) -> str:
    """The simulator call of the benchmark's data, as the report shows it."""
    return f'sim.make_scenario("{scenario}", {scenario_seconds(samples):g}, {RATE_HZ:g}, seed={SCENARIO_SEED})'


def simulated_data(samples: int, scenario: str = SCENARIO):
    """A simulated motion at 100 Hz (int16 counts), at least `samples` long (scenario_call)."""
    return sim.make_scenario(scenario, scenario_seconds(samples), RATE_HZ, seed=SCENARIO_SEED)


#: Per-sample outputs compared between the emulated ELF and the host build, in this order.
OUTPUT_FIELDS = ("quat", "euler", "gyro_bias", "saturations", "cov_mantissa", "cov_exponent", "weights")


@dataclass
class Outputs:
    """Integer outputs after every sample: (N, k) int64 arrays."""

    quat: np.ndarray
    euler: np.ndarray
    gyro_bias: np.ndarray
    saturations: np.ndarray
    cov_mantissa: np.ndarray
    cov_exponent: np.ndarray
    weights: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "Outputs":
        return cls(*(np.zeros((n, k), np.int64) for k in (4, 3, 3, 1, 9, 9, 2)))


def host_outputs(config: FilterConfig, data, n: int) -> Outputs:
    """Outputs of the host fixed build (imulink.core.Filter), one sample at a time."""
    filt = core.Filter(config.filter_name, RATE_HZ, "fixed", config.settings)
    out = Outputs.empty(n)
    for i in range(n):
        r = filt.run_counts(data.gyr_counts[i:i + 1], data.acc_counts[i:i + 1], data.mag_counts[i:i + 1])
        out.quat[i] = r.raw["quat"][0]
        out.euler[i] = r.raw["euler"][0]
        out.gyro_bias[i] = r.raw["gyro_bias"][0]
        out.saturations[i] = r.saturations
        if config.filter_name == "eskf":
            out.cov_mantissa[i], out.cov_exponent[i] = filt.covariance_diagonal_raw()
            out.weights[i] = filt.measurement_weights_raw()
    return out


def first_difference(emulated: Outputs, host: Outputs) -> str | None:
    """The first sample (and its first field) where the two differ, None when identical."""
    first = None
    for name in OUTPUT_FIELDS:
        a, b = getattr(emulated, name), getattr(host, name)
        rows = np.flatnonzero(np.any(a != b, axis=1))
        if rows.size and (first is None or rows[0] < first[0]):
            first = (int(rows[0]), name)
    if first is None:
        return None
    i, name = first
    a, b = getattr(emulated, name)[i], getattr(host, name)[i]
    k = int(np.flatnonzero(a != b)[0])
    return f"sample {i}, {name}[{k}]: ARM {int(a[k])}, host {int(b[k])}"


def settings_bytes(config: FilterConfig) -> tuple[bytes, bytes]:
    """(sensor settings, filter settings) exactly as imulink.core.Filter builds them."""
    mod = core._core_fixed
    sensor = core.sensor_struct(mod, "fixed", DEFAULT_PROFILE)
    values = core.resolve_settings(config.filter_name, RATE_HZ, config.settings)
    filter_settings = core._settings_struct(mod, "fixed", config.filter_name, values)
    return bytes(mod.ffi.buffer(sensor)), bytes(mod.ffi.buffer(filter_settings))


_STATE = struct.Struct("<I3i9i9i2i")  # struct bench_state in harness.c
_OUTPUT = struct.Struct("<10i")     # imu_output_t: quat[4], euler[3], gyro_bias[3]
_RAW = struct.Struct("<9h")         # imu_raw_sample_t: gyr[3], acc[3], mag[3]
_SIZES = struct.Struct("<8I")       # struct bench_sizes in harness.c
_FRAME = struct.Struct("<BxHII")    # imu_proto_frame_t on the target: msg_id, seq, payload, payload_len

#: Phases of a filter update whose costs differ, told apart by the state before the update.
PHASES = {
    "eecf": ("alignment", "filtering"),
    "eskf": ("first sample", "propagation only", "fusion"),
}


def target_sizes(emu: Emulator) -> dict[str, int]:
    names = ("filter", "eecf", "kf1d", "eskf", "cov", "decoder", "decoder_buf", "frame")
    return dict(zip(names, _SIZES.unpack(emu.read("bench_sizes", _SIZES.size))))


@dataclass
class Stat:
    count: int
    mean: float
    max: int

    @classmethod
    def of(cls, values) -> "Stat | None":
        values = np.asarray(values)
        return cls(int(values.size), float(values.mean()), int(values.max())) if values.size else None


@dataclass
class FilterCost:
    key: str
    label: str
    samples: int
    update: Stat
    get: Stat
    update_phases: dict[str, Stat]
    stack_update: int
    stack_get: int
    stack_update_static: int | None = None
    stack_get_static: int | None = None
    static_unknown: list[str] = field(default_factory=list)
    #: With --cycles: mean (least, most) cycles at zero wait states of the update, per phase too, and of the get.
    cycles_update: tuple[float, float] | None = None
    cycles_phases: dict[str, tuple[float, float]] = field(default_factory=dict)
    cycles_get: tuple[float, float] | None = None


def run_filter(emu: Emulator, config: FilterConfig, data, n: int) -> tuple[FilterCost, Outputs]:
    """Run n samples through the emulated ELF, one imu_filter_update_raw and one imu_filter_get
    call each, and read every output back. Returns the costs and the outputs."""
    sensor, settings = settings_bytes(config)
    # Every field (int32 settings and scales, int16 limits) has the same size and alignment on both
    # sides, so the host's bytes are the target's structs.
    symbols = emu.build.symbols
    if len(sensor) != symbols["bench_sensor"].size or len(settings) > symbols["bench_settings"].size:
        raise BenchError("the host's settings structs do not have the target's sizes")
    emu.write("bench_sensor", sensor)
    emu.write("bench_settings", settings)
    filter_id, _ = core.FILTERS[config.filter_name]
    status = emu.call("bench_setup", filter_id).value
    if status != 0:
        raise BenchError(f"{config.key}: bench_setup returned {status - (1 << 32) if status >> 31 else status}")
    emu.call("bench_read_state")
    state = _STATE.unpack(emu.read("bench_state", _STATE.size))

    filt, raw, out = emu.address("bench_filter"), emu.address("bench_raw"), emu.address("bench_out")
    update = np.zeros(n, np.int64)
    get = np.zeros(n, np.int64)
    update_cycles = np.zeros((n, 2), np.int64)
    get_cycles = np.zeros((n, 2), np.int64)
    phase = [""] * n
    stack_update = stack_get = 0
    outputs = Outputs.empty(n)
    counts = np.concatenate([data.gyr_counts[:n], data.acc_counts[:n], data.mag_counts[:n]], axis=1)
    for i in range(n):
        _sat, eskf_initialised, eskf_in_group, eecf_aligning = state[:4]
        if config.filter_name == "eecf":
            phase[i] = "alignment" if eecf_aligning else "filtering"
        elif config.filter_name == "eskf":
            phase[i] = ("first sample" if not eskf_initialised
                        else "fusion" if eskf_in_group == 2 else "propagation only")
        emu.write(raw, _RAW.pack(*(int(v) for v in counts[i])))
        u = emu.call("imu_filter_update_raw", filt, raw)
        g = emu.call("imu_filter_get", filt, out)
        emu.call("bench_read_state")
        update[i], get[i] = u.instructions, g.instructions
        if u.cycles is not None:
            update_cycles[i], get_cycles[i] = u.cycles, g.cycles
        stack_update, stack_get = max(stack_update, u.stack), max(stack_get, g.stack)
        values = _OUTPUT.unpack(emu.read(out, _OUTPUT.size))
        state = _STATE.unpack(emu.read("bench_state", _STATE.size))
        outputs.quat[i], outputs.euler[i], outputs.gyro_bias[i] = values[0:4], values[4:7], values[7:10]
        outputs.saturations[i] = state[0]
        outputs.cov_mantissa[i], outputs.cov_exponent[i] = state[4:13], state[13:22]
        outputs.weights[i] = state[22:24]
    phases = {}
    for name in PHASES.get(config.filter_name, ()):
        stat = Stat.of([c for c, p in zip(update, phase) if p == name])
        if stat is not None:
            phases[name] = stat
    cost = FilterCost(config.key, config.label, n, Stat.of(update), Stat.of(get), phases, stack_update, stack_get)
    if emu.counts_cycles:
        cost.cycles_update = tuple(update_cycles.mean(axis=0))
        cost.cycles_get = tuple(get_cycles.mean(axis=0))
        for name in phases:
            cost.cycles_phases[name] = tuple(update_cycles[[p == name for p in phase]].mean(axis=0))
    return cost, outputs


def measure_filter(emu: Emulator, config: FilterConfig, data, n: int) -> FilterCost:
    """run_filter, then the bit-exactness check against the host fixed build."""
    cost, emulated = run_filter(emu, config, data, n)
    difference = first_difference(emulated, host_outputs(config, data, n))
    if difference is not None:
        raise BenchError(f"{config.key}: the Cortex-M4 build differs from the host fixed build at {difference}")
    return cost


def add_static_stack(build: ArmBuild, cost: FilterCost, config: FilterConfig) -> None:
    """Static worst case of update and get for this filter: the filter table's calls reach its
    adapters in imu_filter.c (named after the filter), not the other filters'."""
    name = config.filter_name
    cost.stack_update_static, unknown_u = static_stack(build, "imu_filter_update_raw", indirect=(f"{name}_update",))
    cost.stack_get_static, unknown_g = static_stack(build, "imu_filter_get", indirect=(f"{name}_get",))
    cost.static_unknown = sorted(set(unknown_u) | set(unknown_g))


# ============================================================================ codec


@dataclass
class CodecCost:
    samples: int
    encode_sample: Stat          # imu_proto_sample_encode per call
    encode_estimate: Stat        # imu_proto_estimate_encode per call
    encode_per_sample: Stat      # both, per sensor sample
    wire_bytes_per_sample: float
    decode_bytes: int
    decode_per_byte: Stat        # imu_proto_decoder_push, every byte
    decode_data_byte: Stat       # bytes other than delimiters
    decode_delimiter: Stat       # delimiters (CRC check, frame completed)
    decode_per_pair: Stat        # all pushes of one SAMPLE + ESTIMATE pair
    frames: int
    stack_encode: int
    stack_decode: int
    payload_bytes: dict[str, int]  # SAMPLE and ESTIMATE payload lengths, as encoded
    stack_encode_static: int | None = None
    stack_decode_static: int | None = None


def estimate_fields(i: int, filter_id: int, outputs: Outputs) -> dict:
    return dict(index=i, filter_id=filter_id, quat=tuple(map(int, outputs.quat[i])),
                gyro_bias=tuple(map(int, outputs.gyro_bias[i])), euler=tuple(map(int, outputs.euler[i])),
                cov_mantissa=tuple(map(int, outputs.cov_mantissa[i])),
                cov_exponent=tuple(map(int, outputs.cov_exponent[i])), saturations=int(outputs.saturations[i, 0]),
                weights=tuple(map(int, outputs.weights[i])))


def measure_codec(emu: Emulator, data, n: int, decode_samples: int | None = None) -> CodecCost:
    """Encode one SAMPLE + ESTIMATE pair per sample (ESTIMATE values from the host fixed ESKF),
    check the bytes against imulink.protocol, then push the stream byte by byte into the C
    decoder and check every frame it reports."""
    if target_sizes(emu)["frame"] != _FRAME.size:
        raise BenchError("imu_proto_frame_t on the target does not have the layout this tool reads")
    config = CONFIGS["eskf"]
    outputs = host_outputs(config, data, n)
    filter_id = protocol.FILTER_IDS["ESKF"]
    period_us = int(round(1e6 / RATE_HZ))
    wire_cap = emu.build.symbols["bench_wire"].size  # IMU_PROTO_MAX_WIRE
    sample_msg, estimate_msg, wire = (emu.address(s) for s in ("bench_sample_msg", "bench_estimate_msg", "bench_wire"))
    enc_sample, enc_estimate = np.zeros(n, np.int64), np.zeros(n, np.int64)
    stack_encode = 0
    stream = bytearray()
    frames = []  # (msg_id, seq, payload) in stream order
    counts = np.concatenate([data.gyr_counts[:n], data.acc_counts[:n], data.mag_counts[:n]], axis=1)
    for i in range(n):
        emu.write("bench_raw", _RAW.pack(*(int(v) for v in counts[i])))
        emu.write("bench_out", _OUTPUT.pack(*outputs.quat[i], *outputs.euler[i], *outputs.gyro_bias[i]))
        emu.write("bench_state", _STATE.pack(int(outputs.saturations[i, 0]), 0, 0, 0, *outputs.cov_mantissa[i],
                                             *outputs.cov_exponent[i], *outputs.weights[i]))
        emu.call("bench_fill_messages", i, i * period_us, TEMPERATURE_COUNTS, filter_id)
        sample = dict(timestamp_us=i * period_us, index=i, gyr=tuple(map(int, data.gyr_counts[i])),
                      acc=tuple(map(int, data.acc_counts[i])), mag=tuple(map(int, data.mag_counts[i])),
                      temperature=TEMPERATURE_COUNTS)
        for name, message, fields, costs in (("SAMPLE", sample_msg, sample, enc_sample),
                                             ("ESTIMATE", estimate_msg, estimate_fields(i, filter_id, outputs),
                                              enc_estimate)):
            seq = len(frames) & 0xFFFF
            result = emu.call(f"imu_proto_{name.lower()}_encode", message, seq, wire, wire_cap)
            costs[i] = result.instructions
            stack_encode = max(stack_encode, result.stack)
            got = emu.read(wire, result.value)
            expected = protocol.encode(name, seq, **fields)
            if got != expected:
                raise BenchError(f"codec: sample {i}: the Cortex-M4 {name} frame differs from imulink.protocol:\n"
                                 f"  ARM  {got.hex()}\n  host {expected.hex()}")
            stream += got
            body = cobs.decode(got[:-1])
            frames.append((body[0], seq, body[3:-4]))

    # Decoder: every byte of the first decode_samples pairs.
    m = n if decode_samples is None else min(n, decode_samples)
    frame_count = 2 * m
    end = int(np.flatnonzero(np.frombuffer(bytes(stream), np.uint8) == 0)[frame_count - 1]) + 1
    emu.call("bench_decoder_init")
    decoder, frame_out = emu.address("bench_decoder"), emu.address("bench_frame")
    per_byte = np.zeros(end, np.int64)
    decoded = []
    for k in range(end):
        result = emu.call("imu_proto_decoder_push", decoder, stream[k], frame_out, measure_stack=False)
        per_byte[k] = result.instructions
        if result.value == 1:
            msg_id, seq, payload, length = _FRAME.unpack(emu.read(frame_out, _FRAME.size))
            decoded.append((msg_id, seq, emu.read(payload, length)))
        elif result.value != 0:
            raise BenchError(f"codec: imu_proto_decoder_push returned {result.value} at byte {k}")
    stack_decode = emu.take_stack_depth()
    for j, (got, expected) in enumerate(zip(decoded, frames)):
        if got != expected:
            raise BenchError(f"codec: decoded frame {j} differs: ARM {got[0]}/{got[1]}/{got[2].hex()}, "
                             f"expected {expected[0]}/{expected[1]}/{expected[2].hex()}")
    if len(decoded) != frame_count:
        raise BenchError(f"codec: the C decoder reported {len(decoded)} frames, the stream holds {frame_count}")
    delimiters = np.frombuffer(bytes(stream[:end]), np.uint8) == 0
    pair_ends = np.flatnonzero(delimiters)[1::2]  # each pair ends with the ESTIMATE's delimiter
    per_pair = np.diff(np.concatenate([[0], np.cumsum(per_byte)[pair_ends]]))
    return CodecCost(
        samples=n, encode_sample=Stat.of(enc_sample), encode_estimate=Stat.of(enc_estimate),
        encode_per_sample=Stat.of(enc_sample + enc_estimate), wire_bytes_per_sample=len(stream) / n,
        decode_bytes=end, decode_per_byte=Stat.of(per_byte), decode_data_byte=Stat.of(per_byte[~delimiters]),
        decode_delimiter=Stat.of(per_byte[delimiters]), decode_per_pair=Stat.of(per_pair),
        frames=len(decoded), stack_encode=stack_encode, stack_decode=stack_decode,
        payload_bytes={"SAMPLE": len(frames[0][2]), "ESTIMATE": len(frames[1][2])})


def add_codec_static_stack(build: ArmBuild, cost: CodecCost) -> None:
    cost.stack_encode_static = max(static_stack(build, f"imu_proto_{m}_encode")[0] for m in ("sample", "estimate"))
    cost.stack_decode_static = static_stack(build, "imu_proto_decoder_push")[0]


# ============================================================================ the whole benchmark


@dataclass
class Results:
    compiler: str
    cflags: list[str]
    ldflags: list[str]
    samples: int
    scenario: str
    filters: dict[str, FilterCost]
    codec: CodecCost | None
    object_sizes: dict[str, dict[str, int]]
    library_sizes: dict[str, int]
    target_sizes: dict[str, int]
    date: str
    seconds: float = 0.0
    #: With --profile: per measured row (label), per call measured, [function, instructions per call].
    profiles: dict[str, dict[str, list[tuple[str, float]]]] = field(default_factory=dict)
    #: With --lines: per measured row, per call measured, the busiest source lines:
    #: [location ("file:line in function"), instructions per call, the line's text].
    line_profiles: dict[str, dict[str, list[tuple[str, float, str]]]] = field(default_factory=dict)


#: The calls whose profile is reported (the others, set-up and read-back, are the harness's).
PROFILED_CALLS = ("imu_filter_update_raw", "imu_filter_get", "imu_proto_sample_encode", "imu_proto_estimate_encode")


def call_profile(emu: Emulator) -> dict[str, list[tuple[str, float]]]:
    """Instructions per call spent in each function, per profiled call, largest first."""
    result = {}
    for call in PROFILED_CALLS:
        calls = emu.profile_calls.get(call, 0)
        if calls:
            rows = [(inside, count / calls) for (calling, inside), count in emu.profile.items() if calling == call]
            result[call] = sorted(rows, key=lambda row: -row[1])
    return result


def line_profile(emu: Emulator, top: int) -> dict[str, list[tuple[str, float, str]]]:
    """Per profiled call, the `top` source lines that executed most instructions per call
    (the innermost line of inlined code, addr2line on an ELF built with debug_info), with the
    function they were compiled into and the line's text."""
    per_address: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for (calling, address, size), executions in emu.block_counts.items():
        if calling in PROFILED_CALLS:
            for offset in thumb_instruction_offsets(emu.read(address, size)):
                per_address[calling][address + offset] += executions
    addresses = sorted({a for counts in per_address.values() for a in counts})
    if not addresses:
        return {}
    out = _run([_tool("arm-none-eabi-addr2line"), "-e", emu.build.elf, *(hex(a) for a in addresses)],
               "arm-none-eabi-addr2line").splitlines()
    where = {}
    for a, location in zip(addresses, out):
        path, _, line = location.split(" (")[0].rpartition(":")
        where[a] = (path, line, emu.function_at(a))
    texts: dict[tuple[str, str], str] = {}

    def text(path: str, line: str) -> str:
        if (path, line) not in texts:
            try:
                source = Path(path).read_text().splitlines()
                texts[path, line] = " ".join(source[int(line) - 1].split())[:70]
            except (OSError, ValueError, IndexError):
                texts[path, line] = ""
        return texts[path, line]

    result = {}
    for call, counts in per_address.items():
        calls = emu.profile_calls.get(call, 0)
        lines: collections.Counter = collections.Counter()
        for a, executions in counts.items():
            lines[where[a]] += executions
        result[call] = [(f"{Path(path).name}:{line} in {function}", count / calls, text(path, line))
                        for (path, line, function), count in lines.most_common(top)]
    return result


def run_benchmark(samples: int, filter_keys: list[str], build_dir: Path, codec: bool = True,
                  decode_samples: int | None = None, progress=lambda _msg: None, profile: bool = False,
                  lines: int = 0, optimize: str = OPTIMIZE, scenario: str = SCENARIO, cycles: bool = False) -> Results:
    """Build, check and measure everything; raises BenchError when a check fails. With
    `lines`, also the busiest source lines of each profiled call (a -g build: the same code);
    with `cycles`, the filters' cycle bounds at zero wait states (tools/arm_cycles.py)."""
    start = time.perf_counter()
    build = build_arm(build_dir, debug_info=lines > 0, optimize=optimize)
    check_no_float(build)
    progress(f"built {build.elf} ({build.compiler}); no floating point")
    data = simulated_data(samples, scenario)
    filters = {}
    profiles = {}
    line_profiles = {}
    for key in filter_keys:
        config = CONFIGS[key]
        t0 = time.perf_counter()
        emu = Emulator(build, profile=profile, profile_lines=lines > 0, cycles=cycles)
        cost = measure_filter(emu, config, data, samples)
        add_static_stack(build, cost, config)
        filters[key] = cost
        if profile:
            profiles[config.label] = call_profile(emu)
        if lines:
            line_profiles[config.label] = line_profile(emu, lines)
        progress(f"{config.label}: {samples} samples bit-exact, {time.perf_counter() - t0:.0f} s")
    codec_cost = None
    if codec:
        t0 = time.perf_counter()
        emu = Emulator(build, profile=profile)
        codec_cost = measure_codec(emu, data, samples, decode_samples)
        add_codec_static_stack(build, codec_cost)
        if profile:
            profiles["codec"] = call_profile(emu)
        progress(f"codec: {codec_cost.frames} frames encoded and decoded, {time.perf_counter() - t0:.0f} s")
    linked = ["-nostartfiles", "-Wl,--gc-sections", f"-T {LINKER_SCRIPT.name}"]
    results = Results(build.compiler, compile_flags(optimize), linked,
                      samples, scenario_call(samples, scenario),
                      filters, codec_cost, object_sizes(build), library_sizes(build),
                      target_sizes(Emulator(build)), datetime.date.today().isoformat(), profiles=profiles,
                      line_profiles=line_profiles)
    results.seconds = time.perf_counter() - start
    return results


def _n(value: float | int | None, decimals: int = 0) -> str:
    """A number with a space every three digits (as in docs/performance.md)."""
    if value is None:
        return ""
    return f"{value:,.{decimals}f}".replace(",", " ")


def _stack(measured: int, static: int | None) -> str:
    return f"{_n(measured)} ({_n(static)})" if static is not None else _n(measured)


def markdown_table(r: Results) -> str:
    sizes = r.object_sizes

    def memory(group: str) -> tuple[str, str, str]:
        objects = SIZE_GROUPS[group]
        flash = sum(sizes[o]["text"] + sizes[o]["data"] for o in objects)
        ram = sum(sizes[o]["data"] + sizes[o]["bss"] for o in objects)
        return _n(flash), _n(ram), " + ".join(f"{o}.o" for o in objects)

    rows = []

    def row(what, stat: Stat | None = None, stack="", flash="", ram="", state="", calls=None, decimals=0):
        rows.append([what, _n(calls if calls is not None else stat.count if stat else None),
                     _n(stat.mean, decimals) if stat else "", _n(stat.max) if stat else "", stack, flash, ram, state])

    state_size = {"eecf": "eecf", "kf1d": "kf1d", "eskf": "eskf", "eskf9": "eskf"}
    for key, cost in r.filters.items():
        group = "eskf" if key.startswith("eskf") else key
        flash, ram, objects = memory(group)
        row(f"**{cost.label}** update_raw, every sample", cost.update,
            _stack(cost.stack_update, cost.stack_update_static), f"{flash} ({objects})", ram,
            _n(r.target_sizes[state_size[key]]))
        for phase, stat in cost.update_phases.items():
            row(f"{cost.label} update_raw, {phase}", stat)
        row(f"{cost.label} get", cost.get, _stack(cost.stack_get, cost.stack_get_static))
    flash, ram, objects = memory("shared")
    row("**shared** math, sensor scaling, filter dispatch", flash=f"{flash} ({objects})", ram=ram)
    row("imu_filter_t, the handle of any filter", state=_n(r.target_sizes["filter"]))
    if r.codec:
        c = r.codec
        flash, ram, objects = memory("codec")
        row(f"**codec** SAMPLE + ESTIMATE encode, per sample ({c.wire_bytes_per_sample:g} wire bytes)",
            c.encode_per_sample, _stack(c.stack_encode, c.stack_encode_static), f"{flash} ({objects})", ram,
            f"{_n(r.target_sizes['decoder'])} + {_n(r.target_sizes['decoder_buf'])} (decoder + buffer)")
        row(f"codec SAMPLE encode ({c.payload_bytes['SAMPLE']}-byte payload)", c.encode_sample)
        row(f"codec ESTIMATE encode ({c.payload_bytes['ESTIMATE']}-byte payload)", c.encode_estimate)
        row("codec decoder_push, per byte", c.decode_per_byte, _stack(c.stack_decode, c.stack_decode_static),
            decimals=1)
        row("codec decoder_push, data byte", c.decode_data_byte, decimals=1)
        row("codec decoder_push, delimiter (CRC check, frame out)", c.decode_delimiter)
        row("codec decoder_push, all bytes of one SAMPLE + ESTIMATE pair", c.decode_per_pair)
    library = sum(r.library_sizes.values())
    members = ", ".join(sorted(re.sub(r"^lib_a-|\.o$", "", m) for m in r.library_sizes))
    row(f"runtime library linked in ({members})", flash=_n(library), ram="0")

    header = ["measured", "calls", "instructions mean", "instructions max", "stack B (static)", "flash B",
              "RAM B", "state B"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return "\n".join(lines)


def profile_table(r: Results, top: int = 8) -> str:
    """Per measured call, the functions that executed most of its instructions."""
    lines = ["| measured call | function: instructions per call (share) |", "|---|---|"]
    for label, calls in r.profiles.items():
        for call, rows in calls.items():
            total = sum(count for _, count in rows)
            shown = "; ".join(f"{name} {_n(count)} ({100 * count / total:.0f} %)" for name, count in rows[:top])
            rest = sum(count for _, count in rows[top:])
            if rest:
                shown += f"; others {_n(rest)}"
            lines.append(f"| {label} {call} ({_n(total)}) | {shown} |")
    return "\n".join(lines)


def line_profile_table(r: Results) -> str:
    """Per filter's measured call, its busiest source lines."""
    lines = ["| measured call | source line (in the function it was compiled into) | instructions per call | "
             "share | text |", "|---|---|---:|---:|---|"]
    costs = {cost.label: cost for cost in r.filters.values()}
    for label, calls in r.line_profiles.items():
        for call, rows in calls.items():
            mean = costs[label].update.mean if call == "imu_filter_update_raw" else costs[label].get.mean
            for location, count, text in rows:
                code = f"`{text.replace('|', '&#124;')}`" if text else ""
                lines.append(f"| {label} {call} | {location} | {_n(count, 1)} | {100 * count / mean:.1f} % | {code} |")
    return "\n".join(lines)


def cycles_table(r: Results) -> str:
    """Per filter's update (and its phases) and get: instructions and the cycle bounds."""
    lines = ["| measured | instructions mean | cycles mean, least - most | cycles per instruction |",
             "|---|---:|---:|---:|"]

    def row(what: str, instructions: float, bounds: tuple[float, float]) -> None:
        least, most = bounds
        lines.append(f"| {what} | {_n(instructions)} | {_n(least)} - {_n(most)} | "
                     f"{least / instructions:.2f} - {most / instructions:.2f} |")

    for cost in r.filters.values():
        if cost.cycles_update is None:
            continue
        row(f"**{cost.label}** update_raw, every sample", cost.update.mean, cost.cycles_update)
        for name, bounds in cost.cycles_phases.items():
            row(f"{cost.label} update_raw, {name}", cost.update_phases[name].mean, bounds)
        row(f"{cost.label} get", cost.get.mean, cost.cycles_get)
    return "\n".join(lines)


def report(r: Results) -> str:
    notes = [
        f"Cortex-M4 build: {r.compiler}",
        f"compiled with: {' '.join(r.cflags)}; linked with: {' '.join(r.ldflags)}",
        f"data: {r.samples} samples, {r.scenario}; every output identical to the host fixed build on every "
        "sample; no floating-point routine or VFP instruction in the ELF",
        "",
        markdown_table(r),
        "",
        "instructions: Thumb-2 instructions executed (IT-skipped ones included), counted in the unicorn emulator; "
        "not cycles.",
        "stack B: deepest stack use measured by painting (static worst case from -fstack-usage and the call graph, "
        "library helpers' frames from their instructions). flash B: code + rodata + data of the objects "
        "(arm-none-eabi-size, before --gc-sections); RAM B: their data + bss; state B: sizeof on the target.",
        f"runtime: {r.seconds:.0f} s",
    ]
    if any(cost.cycles_update is not None for cost in r.filters.values()):
        notes += ["", "Cycles at zero wait states, bounds from the Cortex-M4's instruction timings "
                  "(tools/arm_cycles.py: least with every load and store pipelined where it can be, divisions 2, "
                  "branch refills 1; most with an address stall for every load and store, divisions 12, refills 3; "
                  "flash wait states not included):", "", cycles_table(r)]
    if r.profiles:
        notes += ["", "Where the instructions go (each function's own instructions, callees apart, per call; "
                  "static functions the compiler inlined count in their caller):", "", profile_table(r)]
    if r.line_profiles:
        notes += ["", "By source line (the line an instruction was compiled from, inlined code at its own "
                  "line; per call of the filter):", "", line_profile_table(r)]
    return "\n".join(notes)


def to_json(r: Results) -> str:
    return json.dumps(asdict(r), indent=2)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=4000, help="samples per filter (default 4000 = 40 s at 100 Hz)")
    parser.add_argument("--filters", default=",".join(CONFIGS),
                        help=f"comma-separated filter configurations among {', '.join(CONFIGS)} "
                             "(eskf: default 6 states; eskf9: estimate_acc_bias = 1)")
    parser.add_argument("--decode-samples", type=int, default=None,
                        help="sample pairs whose frames the decoder is timed on (default: all)")
    parser.add_argument("--no-codec", action="store_true", help="skip the frame encoder and decoder")
    parser.add_argument("--build-dir", type=Path, default=None,
                        help="keep the objects, .su/.ci files, map and ELF here (default: a temporary directory)")
    parser.add_argument("--profile", action="store_true",
                        help="also report, per measured call, the instructions spent in each function "
                             "(the run takes about twice as long)")
    parser.add_argument("--lines", type=int, default=0, metavar="N",
                        help="also report, per filter's update and get, the N source lines that executed the "
                             "most instructions (builds with -g, which leaves the code as it is)")
    parser.add_argument("--optimize", choices=[level[1:] for level in OPTIMIZE_LEVELS], default=OPTIMIZE[1:],
                        help=f"optimisation level to measure (default {OPTIMIZE[1:]}, the firmware's; the others "
                             "answer what another level would give)")
    parser.add_argument("--scenario", choices=sim.SCENARIOS, default=SCENARIO,
                        help=f"simulated motion (default {SCENARIO}; static: the board at rest, where the ESKF "
                             "also runs its rest updates)")
    parser.add_argument("--cycles", action="store_true",
                        help="also bound each filter's cycles at zero wait states from the instructions executed "
                             "and the Cortex-M4's instruction timings (tools/arm_cycles.py)")
    parser.add_argument("--json", action="store_true", help="print machine-readable results instead of the table")
    args = parser.parse_args()
    keys = [k.strip() for k in args.filters.split(",") if k.strip()]
    unknown = [k for k in keys if k not in CONFIGS]
    if unknown:
        parser.error(f"unknown filter configuration(s) {', '.join(unknown)}; choose among {', '.join(CONFIGS)}")
    if args.samples < 3:
        parser.error("--samples must be at least 3 (one ESKF fusion step)")
    if args.lines < 0:
        parser.error("--lines must be 0 or more")

    def progress(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    try:
        if args.build_dir is not None:
            results = run_benchmark(args.samples, keys, args.build_dir, not args.no_codec, args.decode_samples,
                                    progress, args.profile, args.lines, "-" + args.optimize, args.scenario,
                                    args.cycles)
        else:
            with tempfile.TemporaryDirectory(prefix="bench_arm.") as tmp:
                results = run_benchmark(args.samples, keys, Path(tmp), not args.no_codec, args.decode_samples,
                                        progress, args.profile, args.lines, "-" + args.optimize, args.scenario,
                                        args.cycles)
    except BenchError as exc:
        print(f"FAIL: {exc}", file=sys.stderr)
        return 1
    print(to_json(results) if args.json else report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
