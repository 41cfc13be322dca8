"""`imulink settings PORT`: the board's own settings table, set by name, kept in a file;
and `imulink filters`' columns."""
from __future__ import annotations

import json

import pytest

from imulink import core, hil
from imulink.board.emulator import EmulatedBoard
from imulink.board.link import Link
from imulink.cli import main
from imulink.io import settings_file


@pytest.fixture
def board():
    with EmulatedBoard(front="tcp", duration_s=600.0, filter_name="eskf", realtime=True) as emulated:
        yield emulated


def board_settings(address: str) -> tuple[str, dict[str, int]]:
    with Link(address) as link:
        link.connect()
        filter_id, settings = hil.read_settings(link)
    return core.filter_name_of(filter_id), {s["name"]: s["value"] for s in settings.values()}


def test_lists_sets_by_name_and_reads_back(board, capsys):
    assert main(["settings", board.address]) == 0
    out = capsys.readouterr().out.splitlines()
    defaults = core.default_settings("eskf")
    listed = {line.split()[0]: float(line.split()[1]) for line in out[1:]}
    assert list(listed) == [f.name for f in core.settings_fields("eskf")]  # the board's table, in its order
    assert listed == pytest.approx(defaults, rel=1e-5)

    assert main(["settings", board.address, "acc_noise=0.4", "mag_noise=2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    changed = {row["name"]: row["value"] for row in report["settings"] if row["changed"]}
    assert report["filter"] == "eskf" and set(changed) == {"acc_noise", "mag_noise"} and changed["mag_noise"] == 2.0
    name, raw = board_settings(board.address)
    assert name == "eskf" and raw["acc_noise"] == core.to_fixed(0.4, 24) and raw["mag_noise"] == 2 << 16
    assert changed["acc_noise"] == raw["acc_noise"] / 2.0**24  # what is printed is what the board runs with
    # the ranges are the board's own descriptor table (SETTING.min/max): the host build's, as the firmware's C
    ranges = {row["name"]: (row["min"], row["max"]) for row in report["settings"]}
    assert ranges == {f.name: (f.minimum, f.maximum) for f in core.settings_fields("eskf")}
    assert ranges["gyro_rrw"] == (0.0, pytest.approx(1.9e-3, abs=2.0**-40))


def test_save_and_load_carry_a_board_s_settings(board, tmp_path, capsys):
    saved = tmp_path / "eskf.json"
    assert main(["settings", board.address, "gyro_arw=0.002", "--save", str(saved)]) == 0
    kept = settings_file.load(saved)
    assert kept.filter_name == "eskf" and "sample_rate" not in kept.values
    assert kept.values["gyro_arw"] == pytest.approx(0.002, abs=2.0**-32)  # what the board holds, in Q32
    assert main(["settings", board.address, "--filter", "kf1d"]) == 0
    assert board_settings(board.address)[0] == "kf1d"
    assert main(["settings", board.address, "--load", str(saved)]) == 0
    name, raw = board_settings(board.address)
    assert name == "eskf" and raw == {**raw, **settings_file.FilterSettings("eskf", kept.values).raw()}
    capsys.readouterr()


def test_refusals_are_one_line(board, tmp_path, capsys):
    for argv, fragment in (([board.address, "bogus=1"], "has no setting bogus; it has sample_rate, gyro_arw"),
                           ([board.address, "acc_noise"], "'acc_noise' is not NAME=VALUE"),
                           ([board.address, "acc_noise=nan"], "is not NAME=VALUE with a finite number"),
                           ([board.address, "--filter", "kf1d", "q_bias=6e-6"],
                            "q_bias = 6e-06 rad^2/s^3 is outside the board's range [0, 5e-06]; nothing was set"),
                           (["/dev/imulink-no-such-port"], "cannot open")):
        assert main(["settings", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("imulink: error: ") and fragment in err and err.count("\n") == 1, err
    assert board_settings(board.address)[1]["q_bias"] == core.to_fixed(core.default_settings("kf1d")["q_bias"], 48)


def test_filters_columns_line_up_for_long_names(capsys):
    assert main(["filters", "--filters", "eskf"]) == 0
    lines = capsys.readouterr().out.splitlines()[1:]
    starts = {line.index(line.split()[1]) for line in lines}  # where each row's value begins
    assert len(starts) == 1 and "init_gyro_bias_std" in "".join(lines)
