"""Cortex-M4 build of the core in the unicorn emulator (tools/bench_arm.py), a short run.

(a) on 300 samples of simulated random motion the ARM build's outputs (quaternion,
    Euler angles, gyro bias, saturation count, ESKF covariance diagonal) equal the host
    fixed build's on every sample and field, for each filter configuration;
(b) the block-hook instruction counter the benchmark uses equals a per-instruction
    counter;
(c) the mean costs of imu_filter_update_raw and imu_filter_get stay under a ceiling per
    configuration, and so does the SAMPLE + ESTIMATE encoding;
(d) the ELF links no floating-point routine and holds no VFP instruction (and the check
    does catch both).
Plus the frame codec's encoded bytes and decoded frames on a few samples.

Needs arm-none-eabi-gcc (with newlib) and the Python package unicorn: without them the
tests fail with a message saying what to install; they do not skip (CI installs both).
"""
from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from imulink import sim

ROOT = Path(__file__).resolve().parents[1]


def _load_tool():
    spec = importlib.util.spec_from_file_location("bench_arm", ROOT / "tools" / "bench_arm.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file executes
    spec.loader.exec_module(module)
    return module


bench_arm = _load_tool()

SAMPLES = 300

#: Ceilings on the mean instructions of imu_filter_update_raw over the 300 samples of
#: this test (arm-none-eabi-gcc 12.2.1 (12.2.rel1), -O2, unicorn 2.1.4): measured at
#: EECF 2 897, KF1D 3 447 and ESKF 6 states 10 470, plus about 10 %; the 9-state one's is
#: issue 41's 10 000 per sample with get (about 500) instead. (The 6-state ESKF was 6 361
#: until the low-pass's error became three states of its covariance: a second time update
#: over nine states, docs/filters.md.)
#: Instruction counts from an emulator are deterministic for a given
#: compiler: a failure means the code got slower (or the compiler changed; then measure
#: again with `tools/bench_arm.py --samples 300` and update these, with the reason in the
#: commit message). How the counts came down: docs/performance-log.md.
UPDATE_CEILING = {
    "eecf": 3_190,
    "kf1d": 3_790,
    "eskf": 11_500,
    "eskf9": 9_500,
}

#: Ceilings on the mean instructions of imu_filter_get over the same samples: measured
#: at EECF 520, KF1D 39, ESKF 507 (6 and 9 states) with the tables' atan2 (the EECF and
#: the ESKF convert their quaternion to Euler angles every call, from the up row and the
#: y axis of its matrix), plus about 10 %.
GET_CEILING = {
    "eecf": 570,
    "kf1d": 43,
    "eskf": 560,
    "eskf9": 560,
}

#: Ceilings on the deepest stack imu_filter_update_raw used (bytes, painted stack) over the
#: same samples: measured at EECF 428 and KF1D 388, plus about 5 %; the ESKF's is the
#: issue's target, 1 KiB (measured at 960 with 6 and 9 states).
STACK_CEILING = {
    "eecf": 460,
    "kf1d": 410,
    "eskf": 1_024,
    "eskf9": 1_024,
}

#: Ceiling on the mean instructions to encode one SAMPLE and one ESTIMATE frame (in-place
#: COBS, table CRC-32): measured at 1 406 over 300 samples and 1 442 over the 20 of this
#: test, plus about 10 %.
ENCODE_CEILING = 1_590


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    return bench_arm.build_arm(tmp_path_factory.mktemp("arm_bench"))


@pytest.fixture(scope="module")
def data():
    return bench_arm.simulated_data(SAMPLES)


def test_toolchain_and_emulator_are_installed():
    assert shutil.which(bench_arm.CC), (
        f"{bench_arm.CC} not found: install the GNU Arm Embedded toolchain with newlib "
        "(Debian/Ubuntu: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    assert bench_arm.unicorn is not None, "the Python package unicorn is missing: .venv/bin/pip install unicorn"


# --------------------------------------------------------------------------- (d) no floating point


def test_elf_uses_no_floating_point(build):
    assert bench_arm.float_problems(build) == []


def _tiny_elf(tmp_path: Path, name: str, source: str, flags: list[str]) -> bench_arm.ArmBuild:
    src = tmp_path / f"{name}.c"
    src.write_text(source)
    elf = tmp_path / f"{name}.elf"
    proc = subprocess.run([bench_arm.CC, *flags, "-O2", "-nostartfiles", "-e", "f", str(src), "-o", str(elf), "-lgcc"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return bench_arm.ArmBuild(tmp_path, elf, {}, bench_arm.read_symbols(elf), "")


def test_float_check_finds_soft_float_calls_and_vfp_instructions(tmp_path):
    source = "double f(double a, double b) { return a * b + 1.0; }\n"
    soft = _tiny_elf(tmp_path, "soft", source, bench_arm.TARGET_FLAGS)
    assert any("__aeabi_d" in p for p in bench_arm.float_problems(soft))
    hard = _tiny_elf(tmp_path, "hard", "float f(float a, float b) { return a * b + 1.0f; }\n",
                     ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"])
    assert any("VFP instruction" in p for p in bench_arm.float_problems(hard))


def test_default_flags_are_the_firmwares_and_optimize_swaps_only_the_level():
    """The benchmark measures the firmware's -O2 (its Makefile's ARM_CFLAGS); --optimize
    changes that one flag and nothing else."""
    makefile = (ROOT / "firmware" / "Makefile").read_text()
    arm_cflags = next(line for line in makefile.splitlines() if line.startswith("ARM_CFLAGS"))
    assert f" {bench_arm.OPTIMIZE} " in arm_cflags
    assert bench_arm.compile_flags() == bench_arm.CFLAGS
    o3 = bench_arm.compile_flags("-O3")
    assert o3 == ["-O3" if flag == bench_arm.OPTIMIZE else flag for flag in bench_arm.CFLAGS]
    assert bench_arm.OPTIMIZE not in o3


def test_scenario_option_chooses_the_simulated_motion():
    """--scenario (default random, the motion of the ceilings below) changes the data and
    the report's description of it together."""
    assert bench_arm.SCENARIO == "random"
    static = bench_arm.simulated_data(30, "static")
    expected = sim.make_scenario("static", 0.3, bench_arm.RATE_HZ, seed=bench_arm.SCENARIO_SEED)
    assert np.array_equal(static.gyr_counts, expected.gyr_counts)
    assert not np.array_equal(static.gyr_counts, bench_arm.simulated_data(30).gyr_counts)
    assert bench_arm.scenario_call(30, "static") == 'sim.make_scenario("static", 0.3, 100, seed=0)'


# --------------------------------------------------------------------------- (b) instruction counter


def test_thumb_instruction_count():
    nop16 = b"\x00\xbf"          # nop
    bl32 = b"\x00\xf0\x00\xf8"   # bl (0b11110 prefix)
    ldrw32 = b"\xd0\xf8\x00\x00"  # ldr.w r0, [r0] (0b11111 prefix)
    strd32 = b"\xc0\xe9\x00\x12"  # strd r1, r2, [r0] (0b11101 prefix)
    assert bench_arm.thumb_instruction_count(nop16 + bl32 + nop16 + ldrw32 + strd32 + nop16) == 6
    assert bench_arm.thumb_instruction_count(b"") == 0


def test_cycle_bounds_of_a_known_run():
    """The Cortex-M4's timings (tools/arm_cycles.py), worked by hand for this run:
    least 2 + 1 + 1 + 4 + 2 + 1 + 1 + 1 + 1 = 14 (the second load pipelines after the first,
    the store takes 1, push 1 + 3, udiv 2, the two instructions under the IT 1 each);
    most 3 + 3 + 3 + 5 + 12 + 1 + 3 + 1 + 1 = 32."""
    run = [("ldr", "r3, [r0]"), ("ldr.w", "r2, [r0, #4]"), ("str", "r3, [r1]"), ("push", "{r4, r5, lr}"),
           ("udiv", "r0, r0, r1"), ("itt", "eq"), ("ldreq", "r0, [r1]"), ("moveq", "r1, #0"), ("adds", "r0, #1")]
    assert bench_arm.arm_cycles.block_cycles(run) == (14, 32)
    assert bench_arm.arm_cycles.block_cycles([("ldrd", "r0, r1, [r2]"), ("pop", "{r4-r7, pc}")]) == (3 + 6, 4 + 7)
    assert bench_arm.arm_cycles.register_count("sp!, {r4-r7, lr}") == 5


def test_cycle_bounds_of_a_filter_run(build, data):
    """With cycles, every call of a run has bounds: at least a cycle per instruction and a
    refill per jump, the most within 12 cycles per instruction; the counts stay the same."""
    plain, _ = bench_arm.run_filter(bench_arm.Emulator(build), bench_arm.CONFIGS["eskf9"], data, 7)
    cost, _ = bench_arm.run_filter(bench_arm.Emulator(build, cycles=True), bench_arm.CONFIGS["eskf9"], data, 7)
    assert (cost.update.mean, cost.get.mean) == (plain.update.mean, plain.get.mean)
    for instructions, (least, most) in [(cost.update.mean, cost.cycles_update), (cost.get.mean, cost.cycles_get),
                                        (cost.update_phases["fusion"].mean, cost.cycles_phases["fusion"])]:
        assert instructions < least < most < 12 * instructions


class _CheckedEmulator(bench_arm.Emulator):
    """Counts every call both ways and keeps the calls where they differ."""

    def __init__(self, build):
        super().__init__(build, count_each_instruction=True)
        self.calls = 0
        self.total = 0
        self.it_skipped_total = 0
        self.mismatches = []

    def call(self, function, *args, **kwargs):
        result = super().call(function, *args, **kwargs)
        self.calls += 1
        self.total += result.instructions
        self.it_skipped_total += result.it_skipped
        if result.instructions != result.instructions_each:
            self.mismatches.append((function, result))
        return result


def test_block_counter_equals_per_instruction_counter(build, data):
    emu = _CheckedEmulator(build)
    # eskf9 from sample 0 to 9: initialisation, propagation, 3 fusions (the low-pass takes its first
    # group at the second, so the gravity updates run from then on)
    for key, samples in (("eecf", 7), ("kf1d", 7), ("eskf9", 10)):
        bench_arm.run_filter(emu, bench_arm.CONFIGS[key], data, samples)
    bench_arm.measure_codec(emu, data, 2)
    assert emu.mismatches == [], f"{len(emu.mismatches)} of {emu.calls} calls differ, first: {emu.mismatches[0]}"
    # enough code covered: 149 163 instructions once the ESKF's fusion step shared its rotation matrix
    # (247 188 after the covariance and math speed-ups); a run that stopped early would be far below
    assert emu.total > 120_000
    # The per-instruction hook misses IT-block instructions whose condition fails; the
    # reference adds them back. The run must contain some, or that path went untested.
    assert emu.it_skipped_total > 0


def test_profile_accounts_for_every_instruction(build, data):
    """--profile splits each measured call's instructions among functions: they add up to the
    call's count, and the work lands where it is done (the EECF's get converts to Euler angles)."""
    emu = bench_arm.Emulator(build, profile=True)
    cost, _ = bench_arm.run_filter(emu, bench_arm.CONFIGS["eecf"], data, 7)
    profile = bench_arm.call_profile(emu)
    assert sum(count for _, count in profile["imu_filter_update_raw"]) == pytest.approx(cost.update.mean)
    assert sum(count for _, count in profile["imu_filter_get"]) == pytest.approx(cost.get.mean)
    get = dict(profile["imu_filter_get"])
    assert get["imu_atan2"] > 0.3 * cost.get.mean and "imu_eecf_update" not in get


def test_line_profile_accounts_for_every_instruction_of_the_same_code(build, data, tmp_path):
    """--lines builds with -g: the code, and so every count, is the one measured without it;
    its lines add up to each call's count, and name where the work is (the EECF's get: atan2)."""
    plain_emu = bench_arm.Emulator(build)
    plain, _ = bench_arm.run_filter(plain_emu, bench_arm.CONFIGS["eecf"], data, 7)
    emu = bench_arm.Emulator(bench_arm.build_arm(tmp_path, debug_info=True), profile_lines=True)
    cost, _ = bench_arm.run_filter(emu, bench_arm.CONFIGS["eecf"], data, 7)
    assert (cost.update.mean, cost.get.mean) == (plain.update.mean, plain.get.mean)
    lines = bench_arm.line_profile(emu, top=100_000)
    assert sum(count for _, count, _ in lines["imu_filter_update_raw"]) == pytest.approx(cost.update.mean)
    assert sum(count for _, count, _ in lines["imu_filter_get"]) == pytest.approx(cost.get.mean)
    in_atan2 = sum(count for where, count, _ in lines["imu_filter_get"] if where.endswith(" in imu_atan2"))
    assert in_atan2 > 0.3 * cost.get.mean
    assert all(":" in where and " in " in where for where, _, _ in lines["imu_filter_update_raw"])
    assert any(text for _, _, text in lines["imu_filter_update_raw"])


# --------------------------------------------------------------------------- (a) bit-exact, (c) ceiling


@pytest.mark.parametrize("key", list(bench_arm.CONFIGS))
def test_arm_build_matches_host_and_stays_under_ceiling(build, data, key):
    config = bench_arm.CONFIGS[key]
    cost, emulated = bench_arm.run_filter(bench_arm.Emulator(build), config, data, SAMPLES)
    difference = bench_arm.first_difference(emulated, bench_arm.host_outputs(config, data, SAMPLES))
    assert difference is None, f"{config.label}: ARM build differs from the host fixed build at {difference}"
    assert cost.update.mean <= UPDATE_CEILING[key], (
        f"{config.label}: imu_filter_update_raw takes {cost.update.mean:.0f} instructions per sample on average, "
        f"over the ceiling {UPDATE_CEILING[key]} (see the comment on UPDATE_CEILING)")
    assert cost.get.mean <= GET_CEILING[key], (
        f"{config.label}: imu_filter_get takes {cost.get.mean:.0f} instructions per call on average, "
        f"over the ceiling {GET_CEILING[key]} (see the comment on GET_CEILING)")
    if config.filter_name == "eskf":
        assert set(cost.update_phases) == {"first sample", "propagation only", "fusion"}
        assert cost.update_phases["fusion"].count == (SAMPLES - 1) // 3
    assert 0 < cost.stack_update <= STACK_CEILING[key], (
        f"{config.label}: imu_filter_update_raw used {cost.stack_update} bytes of stack, over the ceiling "
        f"{STACK_CEILING[key]} (see the comment on STACK_CEILING)")


def test_codec_frames_match_python_codec(build, data):
    codec = bench_arm.measure_codec(bench_arm.Emulator(build), data, 20)
    assert codec.frames == 40
    assert codec.wire_bytes_per_sample > 28 + 102
    assert codec.encode_per_sample.mean <= ENCODE_CEILING, (
        f"SAMPLE + ESTIMATE encoding takes {codec.encode_per_sample.mean:.0f} instructions per sample on average, "
        f"over the ceiling {ENCODE_CEILING} (see the comment on ENCODE_CEILING)")


#: Ceilings on the nav filter's mean instructions (tools/bench_nav.py over the first 3 s of
#: the car drive, at rest: every 50 ms the covariance is propagated and a zero-velocity and
#: zero-rate update and a magnetometer heading are made): per IMU step, measured at 16 623;
#: per GNSS fix (with the covariance brought up to its sample, the velocity gate and the
#: fixes compared with each other), 76 548; per barometer sample (an update once a second),
#: 963; plus about 10 %.
NAV_STEP_CEILING = 18_290
NAV_FIX_CEILING = 84_200
NAV_BARO_CEILING = 1_060


def test_nav_filter_matches_host_and_stays_under_ceiling(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_nav", ROOT / "tools" / "bench_nav.py")
    bench_nav = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench_nav)
    result = bench_nav.arm_cost(3.0, tmp_path)  # raises at the first sample the ARM build differs from x86's
    assert result["samples"] == 299 and result["fixes"] == 2
    assert result["step_mean"] <= NAV_STEP_CEILING, (
        f"imu_navkf_step takes {result['step_mean']:.0f} instructions per step on average, over the "
        f"ceiling {NAV_STEP_CEILING} (see the comment on NAV_STEP_CEILING)")
    assert result["fix_mean"] <= NAV_FIX_CEILING, (
        f"imu_navkf_fix takes {result['fix_mean']:.0f} instructions per fix on average, over the "
        f"ceiling {NAV_FIX_CEILING} (see the comment on NAV_STEP_CEILING)")
    assert result["baro_mean"] <= NAV_BARO_CEILING, (
        f"imu_navkf_baro takes {result['baro_mean']:.0f} instructions per sample on average, over the "
        f"ceiling {NAV_BARO_CEILING} (see the comment on NAV_STEP_CEILING)")
    assert 0 < result["stack_bytes"] < 2048
