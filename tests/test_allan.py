"""Allan deviation (imulink.analysis.allan, `imulink allan`): the curve against allantools, the
intervals against their stated confidence, the noise terms against noise of known
coefficients (the simulator's GyroModel among them), the filter settings against the C
core's ranges, and the command line on CSV files, an emulated board's recording and bad
inputs.

The truths are the coefficients the noise was made with, and textbook closed forms
(IEEE Std 952 Annex C; the Allan variance of a first-order Gauss-Markov process), never
values taken from the code under test. Noise terms must lie within three times their
stated uncertainty (half a 68.3 % interval), and that uncertainty must be small enough
for the check to mean something.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from imulink import cli, core
from imulink.analysis import allan
from imulink.analysis.allan import FLOOR_OVER_BIAS_INSTABILITY, AllanError, allan_curve, axis_terms
from imulink.io import sensor_input
from imulink.io.sensor_input import InputError
from imulink.sim.sensors import GyroModel

CLI = [sys.executable, "-c", "import sys\nfrom imulink.cli import main\nsys.exit(main())"]


def within(term, truth: float, factor: float = 3.0) -> bool:
    return term.value is not None and abs(term.value - truth) <= factor * term.uncertainty


# ---------------------------------------------------------------------------- noise of known coefficients


def white(n: int, rate_hz: float, density: float, rng) -> np.ndarray:
    """White noise of ADEV density * tau^-1/2 (IEEE 952's N): per-sample std density * sqrt(rate)."""
    return rng.standard_normal(n) * density * math.sqrt(rate_hz)


def random_walk(n: int, rate_hz: float, k: float, rng) -> np.ndarray:
    """A random walk of ADEV k * sqrt(tau / 3) (IEEE 952's K): steps of std k / sqrt(rate)."""
    return np.cumsum(rng.standard_normal(n)) * k / math.sqrt(rate_hz)


def flicker(n: int, rate_hz: float, b: float, rng, shortest_s: float = 0.02, longest_s: float = 2e4) -> np.ndarray:
    """Flicker noise of bias instability b (ADEV floor 0.664 b) between the time scales given.

    A sum of first-order Gauss-Markov processes whose correlation times are spaced by a
    factor r = 2: each has the one-sided PSD 4 q^2 T / (1 + (2 pi f T)^2), and their sum
    approaches q^2 / (f ln r), which is IEEE 952's flicker PSD b^2 / (pi f) for
    q^2 = b^2 ln r / pi.
    """
    ratio = 2.0
    q = b * math.sqrt(math.log(ratio) / math.pi)
    out = np.zeros(n)
    corr = shortest_s
    while corr <= longest_s:
        phi = math.exp(-1.0 / (rate_hz * corr))
        drive = rng.standard_normal(n) * q * math.sqrt(1.0 - phi**2)
        out += lfilter([1.0], [1.0, -phi], drive, zi=[phi * q * rng.standard_normal()])[0]
        corr *= ratio
    return out


def gauss_markov_avar(tau: np.ndarray, sigma: float, corr_s: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov process of stationary std `sigma` and
    correlation time `corr_s`: 2 s^2 T / tau [1 - T / (2 tau) (3 - 4 e^(-tau/T) + e^(-2 tau/T))]."""
    x = tau / corr_s
    return 2 * sigma**2 * corr_s / tau * (1 - (3 - 4 * np.exp(-x) + np.exp(-2 * x)) / (2 * x))


# ---------------------------------------------------------------------------- the curve


def test_adev_matches_allantools():
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(3)
    rate = 200.0
    y = 0.7 + white(50_000, rate, 1e-3, rng) + random_walk(50_000, rate, 1e-4, rng)  # an offset, two slopes
    tau, adev = allan.overlapping_adev(y, rate)
    assert tau[0] == 1 / rate and len(tau) == 13  # m = 1 .. 4096 <= 50000 / 9
    ref_tau, ref_adev, _, _ = allantools.oadev(y, rate=rate, data_type="freq", taus=tau)
    np.testing.assert_array_equal(ref_tau, tau)
    np.testing.assert_allclose(adev, ref_adev, rtol=1e-9)


def test_adev_keeps_its_precision_on_a_large_offset():
    """4 million samples of 0.01 noise on 9.81 (gravity): at m = 1 the ADEV is the RMS of
    sample-to-sample differences / sqrt(2), computed here without any running sum."""
    rng = np.random.default_rng(4)
    y = 9.80665 + rng.standard_normal(4_000_000) * 0.01
    tau, adev = allan.overlapping_adev(y, 100.0, sizes=np.array([1, 2]))
    assert adev[0] == pytest.approx(math.sqrt(0.5 * np.mean(np.diff(y) ** 2)), rel=1e-9)
    pairs = y[:-1] + y[1:]  # clusters of two, each start
    assert adev[1] == pytest.approx(math.sqrt(0.5 * np.mean(((pairs[2:] - pairs[:-2]) / 2) ** 2)), rel=1e-9)


def test_edf_against_allantools_and_greenhall():
    ci = pytest.importorskip("allantools.ci")
    n = 100_000
    for m in (1, 2, 16, 1024):
        for alpha in (0, -2):
            assert allan.edf(n, m, alpha) == pytest.approx(ci.edf_simple(n + 1, m, alpha), rel=1e-12)
        if m > 1:
            assert allan.edf(n, m, -1) == pytest.approx(ci.edf_simple(n + 1, m, -1), rel=1e-12)
    # flicker at m = 1: allantools' simple form stays below 1; Greenhall's algorithm gives ~0.9 N
    greenhall = ci.edf_greenhall(alpha=-1, d=2, m=1, N=n + 1, overlapping=True, modified=False)
    assert allan.edf(n, 1, -1) == pytest.approx(greenhall, rel=0.1)


def test_intervals_hold_the_truth_about_as_often_as_they_say():
    """300 short records of white noise and of a random walk: how often does each point's
    68.3 % interval hold the true deviation? The EDF is the smallest of three noise types,
    so white noise is covered more often than stated, a random walk about as often."""
    rng = np.random.default_rng(5)
    n, runs = 4000, 300
    inside = np.zeros((2, allan.cluster_sizes(n).size))
    for _ in range(runs):
        c = allan_curve(np.column_stack([rng.standard_normal(n), np.cumsum(rng.standard_normal(n))]), 1.0)
        m = c.tau_s
        truth = np.column_stack([1 / np.sqrt(m), np.sqrt((2 * m**2 + 1) / (6 * m))])  # discrete white, walk
        inside += ((c.low <= truth) & (truth <= c.high)).T
    coverage = inside / runs
    assert np.all(coverage[0] >= 0.62) and np.all(coverage[0] <= 0.9), coverage[0]
    assert np.all(coverage[1] >= 0.58) and np.all(coverage[1] <= 0.85), coverage[1]


def test_too_few_samples_and_constant_signals_are_refused():
    with pytest.raises(AllanError, match="needs at least 72"):
        allan_curve(np.random.default_rng(0).standard_normal(71), 100.0)
    with pytest.raises(AllanError, match="constant"):
        allan_curve(np.ones((100, 3)), 100.0)


# ---------------------------------------------------------------------------- the noise terms


def test_white_noise_gives_its_density_and_nothing_else():
    rng = np.random.default_rng(6)
    rate, n = 100.0, 720_000  # 2 h
    arw, floor, walk = axis_terms(allan_curve(white(n, rate, 1e-3, rng), rate))
    assert within(arw, 1e-3) and arw.uncertainty < 0.01 * 1e-3
    assert floor.value is None and "no floor" in floor.reason and "record longer" in floor.reason
    assert walk.value is None and "no +1/2 slope" in walk.reason


def test_white_noise_shows_no_floor_by_chance():
    """Six minutes of white noise have some 15 points per axis, and their 68 % intervals
    miss each other somewhere now and then: that must not make a floor or a random walk."""
    rng = np.random.default_rng(12)
    for _ in range(40):
        curve = allan_curve(rng.standard_normal((36_000, 3)), 100.0)
        for axis in range(3):
            arw, floor, walk = axis_terms(curve, axis)
            assert arw.value is not None and floor.value is None and walk.value is None


def test_a_random_walk_gives_its_coefficient_and_nothing_else():
    rng = np.random.default_rng(7)
    rate, n = 100.0, 720_000
    arw, floor, walk = axis_terms(allan_curve(random_walk(n, rate, 1e-4, rng), rate))
    assert within(walk, 1e-4) and walk.uncertainty < 0.2 * 1e-4
    assert walk.tau_s[0] >= allan.RANDOM_WALK_MIN_M / rate
    assert arw.value is None and floor.value is None and "rises from its shortest tau" in floor.reason


def test_flicker_floor_gives_the_bias_instability():
    rng = np.random.default_rng(8)
    rate, n = 100.0, 400_000
    b = 1e-3
    arw, floor, walk = axis_terms(allan_curve(white(n, rate, 1e-4, rng) + flicker(n, rate, b, rng), rate))
    assert within(floor, b) and floor.uncertainty < 0.1 * b
    assert floor.tau_s[1] / floor.tau_s[0] >= 16  # the flat part, not a single point
    assert walk.value is None


def test_white_flicker_and_random_walk_each_read_where_they_dominate():
    """24 h at 10 Hz: white noise meets the flicker floor at 1 s, the random walk leaves it
    at 300 s. The floor read is that of the sum, whose minimum lies a little above the
    flicker's own."""
    rng = np.random.default_rng(9)
    rate, n = 10.0, 864_000
    b = 1e-3
    level = FLOOR_OVER_BIAS_INSTABILITY * b
    n_, k = level * math.sqrt(1.0), level * math.sqrt(3 / 300.0)
    y = white(n, rate, n_, rng) + flicker(n, rate, b, rng) + random_walk(n, rate, k, rng)
    curve = allan_curve(y, rate)
    arw, floor, walk = axis_terms(curve)
    assert within(arw, n_) and arw.tau_s[1] < 1.0
    assert within(walk, k) and walk.tau_s[0] > 300.0
    tau = np.geomspace(curve.tau_s[0], curve.tau_s[-1], 1000)
    avar = n_**2 / tau + level**2 + k**2 * tau / 3
    assert within(floor, np.sqrt(avar.min()) / FLOOR_OVER_BIAS_INSTABILITY)
    assert floor.tau_s[0] <= tau[np.argmin(avar)] <= floor.tau_s[1]


def test_gyro_model_seed000():
    """The simulator's gyroscope with [seed 000]'s Table 1 (per axis), eight hours at 50 Hz:
    the angle and rate random walks come back within their uncertainty. The bias
    instability of a Gauss-Markov process has no flat floor: the reading must match the
    minimum of the model's own ADEV (white + Gauss-Markov + random walk) / 0.664."""
    rng = np.random.default_rng(10)
    rate, n = 50.0, 1_440_000
    model = GyroModel.seed000()
    noise, bias = model.sample(n, 1.0 / rate, rng)
    curve = allan_curve(noise + bias, rate)
    for axis in range(3):
        arw, floor, walk = axis_terms(curve, axis)
        assert within(arw, model.arw[axis]) and arw.uncertainty < 0.01 * model.arw[axis], (axis, arw)
        assert within(walk, model.rrw[axis]) and walk.uncertainty < 0.25 * model.rrw[axis], (axis, walk)
        avar = (model.arw[axis] ** 2 / curve.tau_s + model.rrw[axis] ** 2 * curve.tau_s / 3
                + gauss_markov_avar(curve.tau_s, model.bias_instability[axis], model.bias_instability_tau_s))
        expected = np.sqrt(avar.min()) / FLOOR_OVER_BIAS_INSTABILITY
        assert within(floor, expected) and floor.uncertainty < 0.1 * expected, (axis, floor, expected)
        # Table 1's ARW and RRW alone put the floor far above 0.664 x its bias stability:
        # what the method reads here is the crossing of the two slopes, not the Gauss-Markov bias
        assert floor.value > 1.4 * model.bias_instability[axis]


# ---------------------------------------------------------------------------- filter settings


def test_settings_from_terms():
    terms = {"gyro_arw": [1e-3, 2e-3, None], "gyro_rrw": [5e-3, 1e-5, 1e-5], "acc_vrw": [3e-3, 1e-3, 2e-3],
             "acc_rrw": [None, None, None], "sample_rate_hz": 300.0}
    derived = allan.derive_settings(terms, "eskf", sensor_only=True)
    assert derived.values == pytest.approx({"gyro_arw": 2e-3, "gyro_rrw": 1.9e-3,  # clamped to the range
                                            "acc_noise": 3e-3 * math.sqrt(100.0)})  # three samples of 300 Hz
    assert any("gyro_rrw" in note and "clamped" in note for note in derived.notes)
    assert any("acc_bias_rw is left at its default" in note for note in derived.notes)
    core.Filter("eskf", 300.0, "fixed", derived.values)  # the core takes them
    kf1d = allan.settings_from_terms(terms, "kf1d", sensor_only=True)
    assert kf1d == pytest.approx({"q_angle": 4e-6, "q_bias": 5e-6})  # rrw^2 = 2.5e-5 clamped to 5e-6
    with pytest.raises(AllanError, match="eecf"):
        allan.settings_from_terms(terms, "eecf")


def test_settings_for_a_moving_board_add_the_motion_allowance():
    """The white-noise settings add, in variance, what the defaults carry beyond the
    sensor they were tuned on: BROAD's own terms give the defaults back, a noisier sensor
    more, a quieter one hardly less; the sensor's random walks are taken as they are."""
    eskf, kf1d = core.default_settings("eskf"), core.default_settings("kf1d")
    broad = {"gyro_arw": [allan.TUNED_ON_GYRO_ARW] * 3, "gyro_rrw": [None] * 3,
             "acc_vrw": [allan.TUNED_ON_ACC_NOISE / math.sqrt(285.7 / 3.0)] * 3, "acc_rrw": [None] * 3,
             "sample_rate_hz": 285.7}
    assert allan.settings_from_terms(broad, "eskf") == pytest.approx(
        {"gyro_arw": eskf["gyro_arw"], "acc_noise": eskf["acc_noise"]}, rel=1e-12)
    assert allan.settings_from_terms(broad, "kf1d") == pytest.approx({"q_angle": kf1d["q_angle"]}, rel=1e-12)
    noisy = dict(broad, gyro_arw=[4e-3] * 3, gyro_rrw=[2e-5] * 3, acc_vrw=[0.05] * 3)
    settings = allan.settings_from_terms(noisy, "eskf")
    allowance = allan.motion_allowance("eskf")["gyro_arw"]
    assert settings["gyro_arw"] == pytest.approx(math.hypot(4e-3, math.sqrt(allowance)))
    assert settings["gyro_arw"] > 4e-3 and settings["acc_noise"] > 0.05 * math.sqrt(285.7 / 3.0)
    assert settings["gyro_rrw"] == 2e-5
    quiet = dict(broad, gyro_arw=[1e-6] * 3, acc_vrw=[1e-5] * 3)
    assert allan.settings_from_terms(quiet, "eskf")["gyro_arw"] > 0.99 * eskf["gyro_arw"]
    assert any("--sensor-only" in note for note in allan.derive_settings(broad, "eskf").notes)


# ---------------------------------------------------------------------------- inputs


def test_board_timestamps_unwrap():
    stamps = (np.arange(10) * 1_000_000_000 + 2**32 - 3_000_000_000) % 2**32  # wraps after the 3rd
    np.testing.assert_allclose(sensor_input.unwrap_us(stamps), np.arange(10) * 1000.0)
    assert sensor_input.unwrap_us([10, 5])[1] == pytest.approx(-5e-6)  # a step back stays one


def test_rate_gaps_and_order():
    t = np.arange(1000) / 250.0
    assert sensor_input.rate_from_timestamps(t, "x") == pytest.approx(250.0)
    with pytest.raises(InputError, match="gap"):
        sensor_input.rate_from_timestamps(np.delete(t, [500, 501]), "x")
    with pytest.raises(InputError, match="do not increase at sample 11"):
        sensor_input.rate_from_timestamps(np.concatenate([t[:10], t[11:12], t[10:11], t[12:]]), "x")


def test_broad_rest(broad_dir):
    record = allan.load_static(broad_dir / "02_undisturbed_slow_rotation_B.mat")
    assert "longest rest" in record.description and 35 < record.duration_s < 45
    result = allan.analyse(record)
    for sensor, white in (("gyro", "arw"), ("acc", "vrw")):
        terms = result.sensors[sensor].terms
        assert all(t.value is not None for t in terms[white])
        assert all(t.value is None for t in terms["rrw"])  # 40 s show no random walk
    # a MEMS gyro of BROAD's kind: between 0.1 and 10 deg/sqrt(h)
    assert all(0.1 < t.value * 180 / math.pi * 60 < 10 for t in result.sensors["gyro"].terms["arw"])


# ---------------------------------------------------------------------------- the command line


def run_cli(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True, timeout=120, cwd=cwd,
                          stdin=subprocess.DEVNULL)


def assert_error(result: subprocess.CompletedProcess, fragment: str) -> None:
    """Exit status 2 and one line `imulink: error: ...`, the last on stderr (a progress line
    may come before it on a slow machine), no traceback."""
    assert result.returncode == 2, (result.returncode, result.stderr)
    errors = [line for line in result.stderr.splitlines() if line.startswith("imulink: error: ")]
    assert len(errors) == 1 and result.stderr.rstrip().endswith(errors[0]), result.stderr
    assert "Traceback" not in result.stderr and fragment in errors[0], result.stderr


def write_csv(path: Path, n: int = 36_000, rate: float = 100.0, seed: int = 11, start_us: int = 2**32 - 5_000_000,
              gyro_density: float = 1e-3, acc_density: float = 2e-3) -> Path:
    """A CSV with the columns of `imulink replay --csv` that allan reads, board timestamps
    that wrap past 2^32, and white noise of known density on every axis."""
    rng = np.random.default_rng(seed)
    stamps = (start_us + np.round(np.arange(n) * 1e6 / rate).astype(np.int64)) % 2**32
    gyr = white(3 * n, rate, gyro_density, rng).reshape(n, 3)
    acc = white(3 * n, rate, acc_density, rng).reshape(n, 3) + [0.0, 0.0, 9.81]
    with open(path, "w") as out:
        columns = allan.CSV_COLUMNS["gyr"] + allan.CSV_COLUMNS["acc"]
        out.write("host_time_s,timestamp_us,segment,index," + ",".join(columns) + ",mag_x_uT\n")
        for k in range(n):
            out.write(f"{k * 0.001:.3f},{stamps[k]},0,{k}," + ",".join(f"{v:.9g}" for v in (*gyr[k], *acc[k]))
                      + ",20.5\n")
    return path


@pytest.fixture(scope="module")
def csv_file(tmp_path_factory) -> Path:
    return write_csv(tmp_path_factory.mktemp("csv") / "still.csv")


def test_cli_json(csv_file):
    result = run_cli("allan", csv_file, "--json")
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["sample_rate_hz"] == pytest.approx(100.0) and out["samples"] == 36_000
    for key, truth in (("gyro_arw", 1e-3), ("acc_vrw", 2e-3)):
        assert len(out[key]) == 3 and len(out[f"{key}_uncertainty"]) == 3
        for value, uncertainty in zip(out[key], out[f"{key}_uncertainty"]):
            assert abs(value - truth) <= 3 * uncertainty and uncertainty < 0.03 * truth
    for key in ("gyro_bias_instability", "gyro_rrw", "acc_bias_instability", "acc_rrw"):
        assert out[key] == [None] * 3 and all(out[f"{key}_reason"])  # 6 minutes of white noise: no floor
        assert out[f"{key}_uncertainty"] == [None] * 3
    tau = out["tau_s"]
    assert tau[0] == pytest.approx(0.01) and len(out["gyro_adev"]) == len(tau) and len(out["acc_adev"][0]) == 3
    assert out["units"]["gyro_arw"].startswith("rad/s/sqrt(Hz)") and out["units"]["acc_rrw"] == "m/s^2/sqrt(s)"


def test_cli_report_plots_and_settings(csv_file, tmp_path):
    png, svg = tmp_path / "allan.png", tmp_path / "allan.svg"
    def printed_settings(stdout: str) -> dict[str, float]:
        return {name: float(value) for name, value in (line.split("#")[0].strip().split("=")
                for line in stdout.splitlines() if "=" in line.split("#")[0] and not line.startswith(" "))}

    result = run_cli("allan", csv_file, "--plot", png, "--settings", "eskf", "--sensor-only")
    assert result.returncode == 0, result.stderr
    assert "angle random walk" in result.stdout and "deg/sqrt(h)" in result.stdout
    assert "velocity random walk" in result.stdout and "not identified" in result.stdout
    sensor = printed_settings(result.stdout)
    assert sensor["gyro_arw"] == pytest.approx(1e-3, rel=0.05)
    assert sensor["acc_noise"] == pytest.approx(2e-3 * math.sqrt(100 / 3), rel=0.05)
    assert "gyro_rrw" not in sensor and "acc_bias_rw is left at its default" in result.stdout
    moving = printed_settings(run_cli("allan", csv_file, "--settings", "eskf").stdout)  # the default
    allowance = allan.motion_allowance("eskf")
    for name in ("gyro_arw", "acc_noise"):
        assert moving[name] == pytest.approx(math.sqrt(sensor[name] ** 2 + allowance[name]), rel=1e-5)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = run_cli("allan", csv_file, "--plot", svg, "--json")
    assert result.returncode == 0, result.stderr
    json.loads(result.stdout)  # the plot's line went to stderr
    assert b"<svg" in svg.read_bytes()[:1000]


def test_cli_plot_without_matplotlib(csv_file, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    assert cli.main(["allan", str(csv_file), "--plot", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'imulink[plot]'" in err
    assert not (tmp_path / "a.png").exists()


def test_cli_recording_of_an_emulated_board(tmp_path):
    """A static run of the emulated board (the simulator's [seed 000] gyros, 0.02 m/s^2 per
    sample on the accelerometer), recorded as fast as the link goes: its timestamps are the
    host's pace, so the board's declared rate is used."""
    from imulink import hil
    from imulink.board.emulator import EmulatedBoard

    path = tmp_path / "still.imulog"
    with EmulatedBoard(front="tcp", scenario="static", duration_s=120.0, rate_hz=100.0, filter_name="kf1d") as board:
        hil.record(board.address, path)
    result = run_cli("allan", path, "--json", "--settings", "eskf", "--sensor-only")
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["sample_rate_hz"] == 100.0 and out["samples"] == 12_000
    model = GyroModel.seed000()
    for axis in range(3):
        value, uncertainty = out["gyro_arw"][axis], out["gyro_arw_uncertainty"][axis]
        assert abs(value - model.arw[axis]) <= 3 * uncertainty < 0.05 * model.arw[axis]
        value, uncertainty = out["acc_vrw"][axis], out["acc_vrw_uncertainty"][axis]
        assert abs(value - 0.02 / math.sqrt(100.0)) <= 3 * uncertainty < 0.001
    assert out["settings"]["values"]["gyro_arw"] == pytest.approx(max(out["gyro_arw"]))
    assert out["settings"]["units"]["gyro_arw"] == "rad/s^0.5"


def test_cli_bad_inputs(tmp_path, csv_file):
    assert_error(run_cli("allan", tmp_path / "nothing.imulog"), "cannot read")
    assert_error(run_cli("allan", tmp_path / "nothing.csv"), "cannot read")
    short = write_csv(tmp_path / "short.csv", n=50)
    assert_error(run_cli("allan", short), "holds 50 samples: an Allan analysis needs at least 72")
    lines = csv_file.read_text().splitlines()
    (tmp_path / "backwards.csv").write_text("\n".join(lines[:100] + [lines[101], lines[100]] + lines[102:]) + "\n")
    assert_error(run_cli("allan", tmp_path / "backwards.csv"), "do not increase at sample 100")
    (tmp_path / "gap.csv").write_text("\n".join(lines[:100] + lines[110:]) + "\n")
    assert_error(run_cli("allan", tmp_path / "gap.csv"), "gap")
    (tmp_path / "columns.csv").write_text("time_s,x\n0,1\n")
    assert_error(run_cli("allan", tmp_path / "columns.csv"), "gyr_x_rad_s")
    assert_error(run_cli("allan", csv_file, "--plot", tmp_path / "a.pdf"), "name it .png or .svg")
    as_png = tmp_path / "still.png"  # an input named like a plot: --plot must not write over it
    as_png.write_bytes(csv_file.read_bytes())
    assert_error(run_cli("allan", as_png, "--plot", as_png), "is an input of this command")
    (tmp_path / "text.imulog").write_text("hello\n")
    assert_error(run_cli("allan", tmp_path / "text.imulog"), "is not an imulink recording")
