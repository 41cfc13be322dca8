#!/usr/bin/env python3
"""Generate the golden vectors of the fixed-point C core into shared/vectors/.

Each vector file holds, for one filter and one simulated scenario, the int16
register counts fed to the core, the full settings (SI value and raw int32 per
field), the sensor scales (raw int32) and every integer output of the fixed build
(quaternion Q30, Euler angles Q29, gyro bias Q24) after each sample. The files are
replayed bit for bit by tests/test_vectors.py (through the cffi module) and by
tests/c/vector_driver.c (compiled directly against firmware/core).

Settings are written out in full and chosen here, never taken from the C default
settings, so tuning the defaults does not invalidate the vectors.

Regenerate only on purpose, after an intended change of the fixed-point results,
and give the reason in the commit message:

    .venv/bin/python tools/gen_vectors.py            # rewrite shared/vectors/*.vec
    .venv/bin/python tools/gen_vectors.py --check    # list files that would change

The format is described in shared/vectors/README.md; `write_vector` and
`read_vector` below are its reference writer and reader.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from imulink import core, sim
from imulink.core.counts import BROAD_PROFILE, DEFAULT_PROFILE, SensorProfile

ROOT = Path(__file__).resolve().parents[1]
VECTOR_DIR = ROOT / "shared" / "vectors"

FORMAT_NAME = "imulink-vector"
FORMAT_VERSION = 1

#: Input columns (int16 counts) then output columns (int32 fixed point), in file order.
INPUT_COLUMNS = ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z", "mag_x", "mag_y", "mag_z")
OUTPUT_COLUMNS = ("quat_w", "quat_x", "quat_y", "quat_z", "roll", "pitch", "heading",
                  "bias_x", "bias_y", "bias_z")
COLUMNS = INPUT_COLUMNS + OUTPUT_COLUMNS

#: Sensor scale fields of imu_sensor_settings_t and their Q format (imu_sensor.h).
SENSOR_FIELDS = (("gyro_scale", 40), ("acc_scale", 32), ("mag_scale", 24))

#: Explicit settings sets (SI units). Every field of the filter must be present; the
#: sample rate is filled in per scenario. Deliberately independent of the C defaults.
SETTINGS = {
    "eecf": {
        "standard": {"kp": 1.0, "kp_mag": 1.0, "ki": 0.02, "bias_limit": 0.1745, "align_time": 2.0,
                     "align_tau": 0.5, "ki_mag": 0.02, "rest_time": 1.5, "rest_tau": 0.5, "rest_gyro": 0.05236,
                     "rest_acc": 0.5, "rest_turn": 0.008727, "rest_kp": 4.0, "rest_kp_mag": 0.8,
                     "acc_tolerance": 0.2, "rest_bias_tau": 20.0},
        "tuned": {"kp": 2.5, "kp_mag": 0.4, "ki": 0.08, "bias_limit": 0.05, "align_time": 1.0,
                  "align_tau": 0.2, "ki_mag": 0.04, "rest_time": 1.0, "rest_tau": 0.3, "rest_gyro": 0.03,
                  "rest_acc": 0.3, "rest_turn": 0.005, "rest_kp": 2.0, "rest_kp_mag": 0.5,
                  "acc_tolerance": 0.5, "rest_bias_tau": 5.0},
        # No alignment and no rest detection: the filter starts from the identity quaternion.
        "no_align": {"kp": 5.0, "kp_mag": 3.0, "ki": 0.3, "bias_limit": 0.5, "align_time": 0.0,
                     "align_tau": 0.0, "ki_mag": 0.3, "rest_time": 0.0, "rest_tau": 0.0, "rest_gyro": 0.0,
                     "rest_acc": 1.0, "rest_turn": 0.5, "rest_kp": 5.0, "rest_kp_mag": 3.0,
                     "acc_tolerance": 1.9, "rest_bias_tau": 0.0},
    },
    "kf1d": {
        "standard": {"q_angle": 1e-5, "q_bias": 1e-8, "r_angle": 0.01, "r_heading": 0.01, "acc_tolerance": 0.2},
        "tuned": {"q_angle": 1e-4, "q_bias": 2e-7, "r_angle": 0.003, "r_heading": 0.02, "acc_tolerance": 0.5},
        "no_align": {"q_angle": 5e-4, "q_bias": 4e-6, "r_angle": 2e-6, "r_heading": 0.03, "acc_tolerance": 1.9},
    },
    "eskf": {
        # [seed 000]'s noise terms (docs/filters.md, Bibliography), 9 states, no low-pass: the paths of
        # the source document.
        "standard": {"gyro_arw": 8.7e-4, "gyro_rrw": 4.2e-5, "acc_bias_rw": 1e-4, "acc_noise": 0.05,
                     "mag_noise": 0.3, "init_attitude_std": 0.1, "init_gyro_bias_std": 0.01,
                     "init_acc_bias_std": 0.1, "estimate_acc_bias": 1.0, "gravity": 9.80665,
                     "acc_tolerance": 0.05, "mag_tolerance": 0.05, "dip_tolerance": 0.05, "acc_lowpass": 0.0,
                     "gyro_scale_std": 0.0},
        # As tuned on real data: 6 states, earth-frame low-pass, loose gravity gate, a calibrated
        # gyroscope's scale uncertainty.
        "tuned": {"gyro_arw": 8.7e-4, "gyro_rrw": 1e-5, "acc_bias_rw": 1e-4, "acc_noise": 0.3,
                  "mag_noise": 1.0, "init_attitude_std": 0.1, "init_gyro_bias_std": 0.01,
                  "init_acc_bias_std": 0.1, "estimate_acc_bias": 0.0, "gravity": 9.80665,
                  "acc_tolerance": 0.25, "mag_tolerance": 0.05, "dip_tolerance": 0.02, "acc_lowpass": 3.0,
                  "gyro_scale_std": 0.003},
        # Very uncertain start and loose gates: large gains, the wide-range corners of P (and the
        # largest scale noise).
        "no_align": {"gyro_arw": 0.01, "gyro_rrw": 1e-3, "acc_bias_rw": 0.01, "acc_noise": 0.005,
                     "mag_noise": 0.01, "init_attitude_std": 3.0, "init_gyro_bias_std": 0.5,
                     "init_acc_bias_std": 5.0, "estimate_acc_bias": 1.0, "gravity": 9.81,
                     "acc_tolerance": 1.0, "mag_tolerance": 1.0, "dip_tolerance": 1.5, "acc_lowpass": 0.5,
                     "gyro_scale_std": 0.05},
    },
}


@dataclass(frozen=True)
class Scenario:
    """One simulated run: trajectory, sensor profile, sample rate and settings set."""

    name: str
    description: str
    rate_hz: float
    seed: int
    settings: str
    profile: SensorProfile = DEFAULT_PROFILE

    def simulate(self) -> sim.SimResult:
        rate = self.rate_hz
        if self.name == "static_align":
            traj = sim.static(4.0, rate)
            return sim.simulate(traj, sim.SensorSuite.default(), seed=self.seed)
        if self.name == "random":
            traj = sim.random_motion(12.0, rate, seed=self.seed)
            return sim.simulate(traj, sim.SensorSuite.default(), seed=self.seed)
        if self.name == "rests":
            traj = sim.motion_with_rests(15.0, rate, seed=self.seed, rest_s=(2.0, 4.0), move_s=(3.0, 6.0))
            return sim.simulate(traj, sim.SensorSuite.default(), seed=self.seed)
        if self.name == "turntable":
            traj = sim.turntable(11.0, rate, rate_dps=30.0, settle_s=3.0)
            return sim.simulate(traj, sim.SensorSuite.default(), seed=self.seed)
        if self.name == "rests_250hz":
            traj = sim.motion_with_rests(6.0, rate, seed=self.seed, rest_s=(1.5, 2.5), move_s=(2.0, 3.0),
                                         max_rate_dps=400.0)
            suite = sim.SensorSuite.default()
            suite.profile = self.profile
            return sim.simulate(traj, suite, seed=self.seed)
        if self.name == "disturbed":
            # Fast motion, free fall, saturating taps, a magnetic disturbance and a
            # board starting upside down: the saturation and degenerate paths.
            initial = sim.quat.from_zyx(np.deg2rad(170.0), np.deg2rad(10.0), np.deg2rad(-120.0))
            traj = sim.random_motion(8.0, rate, seed=self.seed, max_rate_dps=900.0, bandwidth_hz=2.0,
                                     accel_std=6.0, initial=initial)
            suite = sim.SensorSuite.default()
            suite.mag.disturbances = [(2.0, 5.0, (30.0, -20.0, 15.0))]
            suite.mag.hard_iron = (4.0, -3.0, 2.0)
            return sim.simulate(traj, suite, seed=self.seed, free_fall=[(3.0, 3.6)],
                                acc_spikes=[(1.0, 120.0), (4.5, 200.0), (6.0, 60.0)])
        if self.name == "extremes":
            return extreme_counts(500, self.seed)
        raise ValueError(f"unknown scenario {self.name!r}")


def extreme_counts(n: int, seed: int) -> SimpleNamespace:
    """Register counts that no motion produces: uniform over the whole int16 range (magnetometer
    over its 12-bit range), with zero accelerometer and magnetometer vectors and gyroscope
    readings at the rails mixed in. Sample 0 has non-zero vectors (a filter starting from a
    zero vector would read its uninitialised state). Pins the saturating and degenerate paths."""
    rng = np.random.default_rng(seed)
    gyr = rng.integers(-(2**15), 2**15, size=(n, 3))
    acc = rng.integers(-(2**15), 2**15, size=(n, 3))
    mag = rng.integers(-2048, 2048, size=(n, 3))
    acc[rng.random(n) < 0.2] = 0
    mag[rng.random(n) < 0.2] = 0
    rails = rng.random(n) < 0.2
    gyr[rails] = rng.choice([-(2**15), 2**15 - 1], size=(int(rails.sum()), 3))
    acc[0] = (100, -200, 4000)
    mag[0] = (150, 200, -400)
    return SimpleNamespace(gyr_counts=gyr.astype(np.int16), acc_counts=acc.astype(np.int16),
                           mag_counts=mag.astype(np.int16))


SCENARIOS = (
    Scenario("static_align", "4 s at rest, the initial alignment/initialisation", 100.0, 1, "standard"),
    Scenario("random", "12 s random motion (200 deg/s, 1 Hz, 1 m/s^2)", 100.0, 11, "standard"),
    Scenario("rests", "15 s random motion with rests, tuned settings", 100.0, 12, "tuned"),
    Scenario("turntable", "3 s rest then 30 deg/s about the vertical", 100.0, 13, "standard"),
    Scenario("rests_250hz", "6 s motion with rests at 250 Hz, +-16 g profile", 250.0, 14, "tuned",
             BROAD_PROFILE),
    Scenario("disturbed", "8 s fast motion, free fall, taps, magnetic disturbance, no alignment", 100.0, 15,
             "no_align"),
    Scenario("extremes", "5 s of random full-range counts with zero vectors and gyro rails", 100.0, 16,
             "standard"),
)


@dataclass
class Vector:
    """The content of one vector file (integers exactly as stored)."""

    name: str
    filter_name: str
    filter_id: int
    scenario: str
    description: str
    seed: int
    rate_hz: float
    sensor: dict = field(default_factory=dict)    # name -> (frac_bits, raw int, SI float)
    settings: dict = field(default_factory=dict)  # name -> (frac_bits, raw int, SI float, unit)
    saturations: int = 0
    inputs: np.ndarray | None = None   # (N, 9) int16: gyr, acc, mag counts
    outputs: np.ndarray | None = None  # (N, 10) int32: quat Q30, euler Q29, gyro bias Q24

    @property
    def samples(self) -> int:
        return 0 if self.inputs is None else int(self.inputs.shape[0])

    def settings_si_exact(self) -> dict[str, float]:
        """SI settings reconstructed from the raw integers (raw / 2^frac_bits, exact in double)."""
        return {name: raw / 2.0**fb for name, (fb, raw, _si, _unit) in self.settings.items()}

    def sensor_exact(self) -> SimpleNamespace:
        """Object with gyro_scale/acc_scale/mag_scale (SI) reconstructed from the raw integers and
        the registers' limits (every profile's are the GY-86's), usable wherever imulink.core
        expects a SensorProfile."""
        return SimpleNamespace(**{name: raw / 2.0**fb for name, (fb, raw, _si) in self.sensor.items()},
                               gyro_limits=DEFAULT_PROFILE.gyro_limits, acc_limits=DEFAULT_PROFILE.acc_limits,
                               mag_limits=DEFAULT_PROFILE.mag_limits)


# --------------------------------------------------------------------------- format


def format_vector(v: Vector) -> str:
    lines = [
        "# imulink golden vector: int16 inputs and int32 outputs of the fixed-point C core.",
        "# Regenerate only on purpose with `python tools/gen_vectors.py` (reason in the commit message).",
        f"format {FORMAT_NAME} {FORMAT_VERSION}",
        f"name {v.name}",
        f"filter {v.filter_name}",
        f"filter_id {v.filter_id}",
        f"scenario {v.scenario}",
        f"description {v.description}",
        f"seed {v.seed}",
        f"rate_hz {v.rate_hz!r}",
    ]
    for name, (fb, raw, si) in v.sensor.items():
        lines.append(f"sensor {name} {fb} {raw} {si!r}")
    for name, (fb, raw, si, unit) in v.settings.items():
        lines.append(f"setting {name} {fb} {raw} {si!r} {unit}")
    lines.append(f"saturations {v.saturations}")
    lines.append(f"samples {v.samples}")
    lines.append("columns " + " ".join(COLUMNS))
    lines.append("data")
    rows = np.concatenate([v.inputs.astype(np.int64), v.outputs.astype(np.int64)], axis=1)
    lines.extend(" ".join(map(str, row)) for row in rows.tolist())
    lines.append("end")
    return "\n".join(lines) + "\n"


def parse_vector(text: str, source: str = "<vector>") -> Vector:
    """Parse the text of a vector file; ValueError (naming the line) on any format error."""
    lines = text.split("\n")
    header: dict = {"sensor": {}, "setting": {}}
    i = 0
    while True:
        if i >= len(lines):
            raise ValueError(f"{source}: no 'data' line")
        line = lines[i]
        i += 1
        if not line or line.startswith("#"):
            continue
        if line == "data":
            break
        key, _, rest = line.partition(" ")
        parts = rest.split(" ")
        try:
            if key == "sensor":
                header["sensor"][parts[0]] = (int(parts[1]), int(parts[2]), float(parts[3]))
            elif key == "setting":
                header["setting"][parts[0]] = (int(parts[1]), int(parts[2]), float(parts[3]), parts[4])
            else:
                header[key] = rest
        except (IndexError, ValueError) as exc:
            raise ValueError(f"{source}:{i}: bad header line {line!r}: {exc}") from None
    if header.get("format") != f"{FORMAT_NAME} {FORMAT_VERSION}":
        raise ValueError(f"{source}: unsupported format {header.get('format')!r}")
    if header.get("columns") != " ".join(COLUMNS):
        raise ValueError(f"{source}: unexpected columns {header.get('columns')!r}")
    n = int(header["samples"])
    body = lines[i:i + n]
    if len(body) != n or i + n >= len(lines) or lines[i + n] != "end":
        raise ValueError(f"{source}: expected {n} data lines followed by 'end'")
    try:
        rows = np.array([[int(x) for x in row.split(" ")] for row in body], dtype=np.int64).reshape(n, len(COLUMNS))
    except ValueError as exc:
        raise ValueError(f"{source}: bad data line: {exc}") from None
    ins, outs = rows[:, :len(INPUT_COLUMNS)], rows[:, len(INPUT_COLUMNS):]
    if ins.min(initial=0) < -(2**15) or ins.max(initial=0) >= 2**15:
        raise ValueError(f"{source}: input count outside int16")
    if outs.min(initial=0) < -(2**31) or outs.max(initial=0) >= 2**31:
        raise ValueError(f"{source}: output outside int32")
    return Vector(
        name=header["name"], filter_name=header["filter"], filter_id=int(header["filter_id"]),
        scenario=header["scenario"], description=header.get("description", ""), seed=int(header["seed"]),
        rate_hz=float(header["rate_hz"]), sensor=header["sensor"], settings=header["setting"],
        saturations=int(header["saturations"]), inputs=ins.astype(np.int16), outputs=outs.astype(np.int32),
    )


def read_vector(path) -> Vector:
    path = Path(path)
    return parse_vector(path.read_text(), str(path))


def vector_files(directory: Path = VECTOR_DIR) -> list[Path]:
    return sorted(Path(directory).glob("*.vec"))


# --------------------------------------------------------------------------- generation


def explicit_settings(filter_name: str, set_name: str, rate_hz: float) -> dict[str, float]:
    """The full settings (SI) of a settings set; every field of the C struct must be named."""
    values = dict(SETTINGS[filter_name][set_name])
    values["sample_rate"] = float(rate_hz)
    names = {f.name for f in core.settings_fields(filter_name)}
    if set(values) != names:
        raise SystemExit(
            f"settings set {filter_name}/{set_name} does not match the C settings struct: "
            f"missing {sorted(names - set(values))}, unknown {sorted(set(values) - names)}; "
            "update SETTINGS in tools/gen_vectors.py"
        )
    return values


def make_vector(filter_name: str, scenario: Scenario) -> Vector:
    filter_id, _ = core.FILTERS[filter_name]
    res = scenario.simulate()
    si = explicit_settings(filter_name, scenario.settings, scenario.rate_hz)
    settings = {}
    for f in core.settings_fields(filter_name):
        raw = core.to_fixed(si[f.name], f.frac_bits, f.name)
        settings[f.name] = (f.frac_bits, raw, float(si[f.name]), f.unit)
    sensor = {}
    for name, fb in SENSOR_FIELDS:
        value = float(getattr(scenario.profile, name))
        sensor[name] = (fb, core.to_fixed(value, fb, name), value)
    v = Vector(
        name=f"{filter_name}_{scenario.name}", filter_name=filter_name, filter_id=filter_id,
        scenario=scenario.name, description=scenario.description, seed=scenario.seed,
        rate_hz=float(scenario.rate_hz), sensor=sensor, settings=settings,
        inputs=np.concatenate([res.gyr_counts, res.acc_counts, res.mag_counts], axis=1).astype(np.int16),
    )
    v.outputs, v.saturations = run_fixed(v)
    return v


def run_fixed(v: Vector) -> tuple[np.ndarray, int]:
    """Run the fixed build on a vector's inputs with the settings and scales rebuilt from
    its raw integers; returns the (N,10) int32 outputs and the saturation count."""
    ins = v.inputs
    r = core.run_counts(v.filter_name, ins[:, 0:3], ins[:, 3:6], ins[:, 6:9], v.rate_hz, "fixed",
                        settings=v.settings_si_exact(), profile=v.sensor_exact())
    out = np.concatenate([r.raw["quat"], r.raw["euler"], r.raw["gyro_bias"]], axis=1).astype(np.int32)
    return out, r.saturations


def generate() -> dict[str, str]:
    """All vectors as {file name: text}."""
    out = {}
    for filter_name in core.FILTERS:
        for scenario in SCENARIOS:
            v = make_vector(filter_name, scenario)
            text = format_vector(v)
            back = parse_vector(text, v.name)  # the writer and the reader agree
            assert np.array_equal(back.inputs, v.inputs) and np.array_equal(back.outputs, v.outputs)
            out[f"{v.name}.vec"] = text
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=VECTOR_DIR, help="output directory (default shared/vectors)")
    parser.add_argument("--check", action="store_true", help="only report which files would change")
    args = parser.parse_args(argv)
    files = generate()
    if args.check:
        changed = [n for n, t in files.items() if not (args.out / n).is_file() or (args.out / n).read_text() != t]
        stale = sorted({p.name for p in vector_files(args.out)} - set(files))
        for n in changed:
            print(f"would change: {n}")
        for n in stale:
            print(f"not generated any more: {n}")
        return 1 if changed or stale else 0
    args.out.mkdir(parents=True, exist_ok=True)
    total = 0
    for n, t in files.items():
        (args.out / n).write_text(t)
        total += len(t)
        print(f"{n}: {t.count(chr(10))} lines, {len(t)} bytes")
    for p in vector_files(args.out):
        if p.name not in files:
            print(f"warning: {p.name} is not generated any more; delete it if intended", file=sys.stderr)
    print(f"total {total} bytes in {len(files)} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
