"""Settings files (imulink.io.settings_file): written by `imulink allan --settings F --write`,
taken by core.run, `imulink record`, `inject` and `emulate` (--settings FILE)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from imulink import core, hil, sim
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.cli import main
from imulink.io import settings_file
from imulink.io.recording import load_recording

ESKF = settings_file.FilterSettings("eskf", {"gyro_arw": 0.00095, "gyro_rrw": 4.5e-05, "acc_noise": 0.5})


def board_settings(address: str) -> tuple[str, dict[str, float]]:
    """The active filter of a board and its settings in SI, read over the protocol."""
    with Link(address) as link:
        link.connect()
        filter_id, settings = hil.read_settings(link)
    name = {fid: n for n, (fid, _) in core.FILTERS.items()}[filter_id]
    return name, {s["name"]: s["value"] / 2.0 ** s["frac_bits"] for s in settings.values()}


def test_round_trip_and_what_is_refused(tmp_path):
    path = tmp_path / "eskf.json"
    settings_file.save(ESKF, path)
    data = json.loads(path.read_text())
    assert data["filter"] == "eskf" and data["units"]["gyro_arw"] == "rad/s^0.5"
    assert settings_file.load(path) == ESKF
    bad = {"format": "imulink-settings", "format_version": 1, "filter": "eskf"}
    for settings, fragment in (({"gyro_arw": 0.495}, "out of range"), ({"gyro_arw": 1.0}, "does not fit"),
                               ({"kp": 1.0}, "unknown setting 'kp'"),
                               ({"sample_rate": 100.0}, "sample_rate is not a setting"),
                               ({"acc_noise": "0.3"}, "not a finite number")):
        path.write_text(json.dumps({**bad, "settings": settings}))
        with pytest.raises(settings_file.SettingsFileError, match=fragment):
            settings_file.load(path)
    path.write_text(json.dumps({**bad, "filter": "ukf", "settings": {}}))
    with pytest.raises(settings_file.SettingsFileError, match="unknown filter 'ukf'"):
        settings_file.load(path)
    path.write_text("{")
    with pytest.raises(settings_file.SettingsFileError, match="is not JSON"):
        settings_file.load(path)


def test_core_run_takes_a_settings_file():
    data = sim.make_scenario("rests", 20.0, 100.0, seed=2)
    from_file = core.run("eskf", data.gyr, data.acc, data.mag, 100.0, settings=ESKF)
    from_dict = core.run("eskf", data.gyr, data.acc, data.mag, 100.0, settings=ESKF.values)
    default = core.run("eskf", data.gyr, data.acc, data.mag, 100.0)
    np.testing.assert_array_equal(from_file.raw["quat"], from_dict.raw["quat"])
    assert not np.array_equal(from_file.raw["quat"], default.raw["quat"])
    with pytest.raises(core.SettingsError, match="the settings are eskf's, the filter is eecf"):
        core.run("eecf", data.gyr, data.acc, data.mag, 100.0, settings=ESKF)


def test_allan_writes_the_settings_it_prints(tmp_path, capsys):
    still = sim.make_scenario("static", 200.0, 100.0, seed=3)
    columns = ["time_s", "gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s", "acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]
    np.savetxt(tmp_path / "still.csv", np.column_stack([still.t, still.gyr, still.acc]), delimiter=",",
               header=",".join(columns), comments="", fmt="%.9g")
    out = tmp_path / "eskf.json"
    assert main(["allan", str(tmp_path / "still.csv"), "--settings", "eskf", "--write", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)["settings"]
    written = settings_file.load(out)
    assert written.filter_name == "eskf" and written.values == printed["values"]
    assert set(written.values) >= {"gyro_arw", "acc_noise"}
    assert main(["allan", str(tmp_path / "still.csv"), "--write", str(out)]) == 2
    assert "--write needs --settings FILTER" in capsys.readouterr().err


def test_record_and_inject_give_the_board_the_file(tmp_path, capsys):
    path = tmp_path / "eskf.json"
    settings_file.save(ESKF, path)
    with EmulatedBoard(duration_s=5.0, filter_name="eecf") as board:
        assert main(["record", board.address, "-o", str(tmp_path / "run.imulog"), "--settings", str(path)]) == 0
        recording = load_recording(tmp_path / "run.imulog")
        name, raw = recording.filter_settings(recording.active_filter)
        assert name == "eskf" and all(raw[k] == v for k, v in ESKF.raw().items())
        assert hil.compare(recording).bit_exact
        capsys.readouterr()
        # inject runs with the file's settings and restores the board's
        before = board_settings(board.address)
        assert main(["inject", board.address, "--input", "sim:rests:5", "--settings", str(path)]) == 0
        assert "bit-exact: yes" in capsys.readouterr().out
        assert board_settings(board.address) == before
        assert main(["inject", board.address, "--input", "sim:rests:5", "--settings", str(path),
                     "--filter", "kf1d"]) == 2
        assert "the settings file is for eskf, not kf1d" in capsys.readouterr().err


def test_emulate_starts_the_board_with_the_file(tmp_path):
    path = tmp_path / "eskf.json"
    settings_file.save(ESKF, path)
    process = subprocess.Popen([sys.executable, "-m", "imulink.cli", "emulate", "--tcp", "--fast", "--settings",
                                str(path), "--filter", "kf1d"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        address = process.stdout.readline().strip()
        assert address.startswith("socket://"), process.stderr.read() if process.poll() is not None else address
        name, values = board_settings(address)
        assert name == "eskf"
        for key, value in ESKF.values.items():
            assert values[key] == pytest.approx(value, rel=1e-6, abs=2.0 ** -30)
    finally:
        process.terminate()
        process.wait(timeout=10)
