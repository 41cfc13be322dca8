"""`imulink nav --start` and `imulink nav --help`: a navigation CSV without any fix (25 s
of the simulator's foot walk, no GNSS) started at a place given on the command line, which
is the same run as the CSV with a marker's fix in its first row; bad --start values refused
in one line; the help listing every column the CSV reader takes."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from imulink.analysis import nav
from imulink.cli import main
from imulink.io import nav_input
from imulink.sim import navigation as nv
from imulink.sim import simulate
from test_navkf import nav_cli  # the `imulink nav` runner the offline tests share

RATE = 100.0
ACCURACY_M = 0.5


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """The walk without any fix, the same with a marker's fix in its first row (every value
    written as Python reads it back exactly), and the start place as --start gives it."""
    traj = nv.foot_walk(25.0, RATE, seed=1)
    imu = simulate(traj, nv.datasheet_sensors(RATE), seed=1)
    folder = tmp_path_factory.mktemp("navstart")
    no_fix = folder / "walk.csv"
    nav_input.write_nav_csv(no_fix, imu)
    lat, lon, height = (float(traj.lat_deg[0]) + 1e-5, float(traj.lon_deg[0]) - 2e-5,
                        float(traj.height_m[0]) + 3.0)  # not the truth
    lines = no_fix.read_text().splitlines()
    first = [repr(float(v)) for v in (lat, lon, height, ACCURACY_M * math.sqrt(2.0), ACCURACY_M)]
    marked = folder / "walk_marker.csv"
    marked.write_text("\n".join([lines[0] + "," + ",".join(nav_input.GNSS_POSITION), lines[1] + "," + ",".join(first)]
                                + [line + ",,,,," for line in lines[2:]]) + "\n")
    start = f"{lat!r},{lon!r},{height!r},{ACCURACY_M!r}"
    return traj, no_fix, marked, start, (lat, lon, height)


def test_start_runs_from_the_first_sample_at_the_place(walk, tmp_path, capsys):
    traj, no_fix, _, start, (lat, lon, height) = walk
    out = tmp_path / "estimate.csv"
    code, stdout, err = nav_cli(capsys, no_fix, "--csv", out, "--start", start, "--json")
    assert code == 0, err
    report = json.loads(stdout)
    assert report["start_sample"] == 0 and report["rows_written"] == report["samples"] == len(traj)
    assert report["fixes"] == report["fixes_used"] == 1 and report["saturations"] == 0
    assert report["start_marker"] == {"lat_deg": lat, "lon_deg": lon, "height_m": height, "accuracy_m": ACCURACY_M}
    estimate = np.genfromtxt(out, delimiter=",", names=True)
    assert len(estimate) == len(traj)
    d = nv.local_offsets(estimate["lat_deg"][:1], estimate["lon_deg"][:1], estimate["height_m"][:1], lat, lon,
                         height)
    assert np.abs(d).max() < 0.01  # Q29 rad is 1.2 cm
    assert estimate["sd_up_m"][0] == pytest.approx(ACCURACY_M, rel=1e-3)
    assert estimate["sd_east_m"][0] == pytest.approx(ACCURACY_M, rel=1e-3)
    code, stdout, _ = nav_cli(capsys, no_fix, "--csv", tmp_path / "text.csv", "--start", start)
    assert code == 0 and "from line 2, the --start marker" in stdout


@pytest.mark.parametrize("arithmetic", ["fixed", "float"])
def test_start_is_a_marker_in_the_first_row(walk, tmp_path, capsys, arithmetic):
    _, no_fix, marked, start, _ = walk
    given, in_csv = tmp_path / "given.csv", tmp_path / "in_csv.csv"
    assert nav_cli(capsys, no_fix, "--csv", given, "--start", start, "--arith", arithmetic)[0] == 0
    assert nav_cli(capsys, marked, "--csv", in_csv, "--arith", arithmetic)[0] == 0
    assert given.read_bytes() == in_csv.read_bytes()


def test_start_with_a_fix_in_the_first_row_uses_both(walk, tmp_path, capsys):
    """The start marker anchors the first sample; the row's own fix follows right after the
    second sample, one sample interval old, trusted as a marker's too."""
    _, _, marked, start, (lat, lon, height) = walk
    inp = nav_input.read_nav_csv(marked)
    elsewhere = nav.with_start(inp, lat + 1e-5, lon, height, 2.0)
    np.testing.assert_array_equal(elsewhere.fix_index, [0, 1])
    np.testing.assert_allclose(elsewhere.fix_age_s, [0.0, 1.0 / RATE])
    np.testing.assert_array_equal(elsewhere.fix_is_marker, [True, True])
    result = nav.run(elsewhere)
    assert result.fix_accepted.all() and result.start == 0
    north = nv.local_offsets(result.lat_deg[:2], result.lon_deg[:2], result.height_m[:2], lat, lon, height)[:, 1]
    assert north[0] == pytest.approx(1.11, abs=0.02)  # the start marker, 1e-5 deg north
    assert 0.0 < north[1] < 0.5 * north[0]  # pulled most of the way to the row's own (more accurate) fix
    code, stdout, err = nav_cli(capsys, marked, "--csv", tmp_path / "both.csv", "--start", start, "--json")
    assert code == 0, err
    report = json.loads(stdout)
    assert report["fixes"] == report["fixes_used"] == 2


@pytest.mark.parametrize("value, message", [
    ("85.5,8.5,450", "latitude 85.5 deg is beyond +-85 deg"),
    ("47.4,-180.5,450", "longitude -180.5 deg is beyond +-180 deg"),
    ("47.4,8.5,10001", "height 10001 m is beyond +-10000 m"),
    ("47.4,8.5,-12000", "height -12000 m is beyond +-10000 m"),
    ("47.4,8.5,450,0", "accuracy 0 m is not above 0"),
    ("47.4,8.5,450,-1", "accuracy -1 m is not above 0"),
    ("47.4,8.5,450,nan", "the accuracy nan is not a finite number"),
    ("47.4,inf,450", "the longitude inf is not a finite number"),
    ("47.4,8.5", "is not LAT,LON,HEIGHT[,ACCURACY]"),
    ("47.4,8.5,450,1,2", "is not LAT,LON,HEIGHT[,ACCURACY]"),
    ("47.4,east,450", "is not LAT,LON,HEIGHT[,ACCURACY]"),
])
def test_bad_start_values_are_refused_in_one_line(walk, tmp_path, capsys, value, message):
    _, no_fix, _, _, _ = walk
    out = tmp_path / "estimate.csv"
    with pytest.raises(SystemExit) as exc:
        nav_cli(capsys, no_fix, "--csv", out, f"--start={value}")
    _, err = capsys.readouterr()
    assert exc.value.code == 2
    assert err.startswith("imulink: error: argument --start: ") and err.count("\n") == 1, err
    assert message in err, err
    assert not out.exists()


def test_the_limits_themselves_are_taken(walk, tmp_path, capsys):
    _, no_fix, _, _, _ = walk
    code, _, err = nav_cli(capsys, no_fix, "--csv", tmp_path / "south.csv", "--start=-85,-180,-10000,100000")
    assert code == 0, err
    code, _, err = nav_cli(capsys, no_fix, "--csv", tmp_path / "north.csv", "--start=85,180,10000")
    assert code == 0, err


def test_without_a_fix_or_start_the_error_names_start(walk, tmp_path, capsys):
    _, no_fix, _, _, _ = walk
    out = tmp_path / "estimate.csv"
    code, _, err = nav_cli(capsys, no_fix, "--csv", out)
    assert code == 2 and err.count("\n") == 1
    assert "no GNSS or position fix" in err and "--start LAT,LON,HEIGHT" in err
    assert not out.exists()


def test_help_lists_every_input_column_with_its_unit(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["nav", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0
    columns = (*nav_input.REQUIRED, *nav_input.MAG, *nav_input.BARO, *nav_input.GNSS_POSITION,
               *nav_input.GNSS_VELOCITY)
    assert "baro_pa" in out and "baro_temp_c" in out
    text = " ".join(out.split())
    for name in columns:  # each name, and after it the unit of its group
        after = text.index(name) + len(name)
        assert text[text.index("(", after) + 1:text.index(")", after)] == nav_input.column_unit(name), name
    assert "--start LAT,LON,HEIGHT[,ACCURACY]" in out


def test_settings_tune_the_filter(walk, tmp_path, capsys):
    """--set NAME=VALUE reaches the filter (a tighter rest bound: fewer zero-velocity updates)
    and is echoed in the report; a settings file of the nav filter is read, --set after it."""
    from imulink.io import settings_file

    _, no_fix, _, start, _ = walk
    counts = {}
    for extra in ([], ["--set", "rest_rate=0.01"]):
        code, stdout, err = nav_cli(capsys, no_fix, "--csv", tmp_path / "e.csv", "--start", start, "--json", *extra)
        assert code == 0, err
        report = json.loads(stdout)
        counts[len(extra)] = report["zero_velocity_updates"]
    assert report["settings"] == {"rest_rate": 0.01} and report["resets"] == 0
    assert 0 < counts[2] < counts[0]
    saved = tmp_path / "nav.json"
    settings_file.save(settings_file.FilterSettings("nav", {"rest_rate": 0.01, "gate": 30.0}), saved)
    code, stdout, err = nav_cli(capsys, no_fix, "--csv", tmp_path / "e.csv", "--start", start, "--json",
                                "--settings", saved, "--set", "gate=20")
    assert code == 0, err
    report = json.loads(stdout)
    assert report["settings"] == {"rest_rate": 0.01, "gate": 20.0} and report["zero_velocity_updates"] == counts[2]


@pytest.mark.parametrize("argv,message", [
    (["--set", "gate=1"], "gate=1 is outside 7.81 .. 100\n"),
    (["--set", "reset_time=1e9"], "reset_time=1e+09 is outside 1 .. 600 s"),
    (["--set", "bogus=1"], "unknown setting 'bogus' for filter 'nav'"),
    (["--set", "gate"], "is not NAME=VALUE"),
    (["--set", "gnss_latency=0.2"], "gnss_latency is the board's"),
])
def test_bad_settings_are_one_line(walk, tmp_path, capsys, argv, message):
    _, no_fix, _, start, _ = walk
    out = tmp_path / "e.csv"
    code, _, err = nav_cli(capsys, no_fix, "--csv", out, "--start", start, *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_another_filters_settings_file_is_refused(walk, tmp_path, capsys):
    from imulink.io import settings_file

    _, no_fix, _, start, _ = walk
    saved = tmp_path / "eskf.json"
    settings_file.save(settings_file.FilterSettings("eskf", {"acc_noise": 0.5}), saved)
    code, _, err = nav_cli(capsys, no_fix, "--csv", tmp_path / "e.csv", "--start", start, "--settings", saved)
    assert code == 2 and "the settings are eskf's, the filter is nav" in err
