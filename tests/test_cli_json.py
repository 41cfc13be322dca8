"""`--json` of demo, record, replay, compare, inject, simulate and filters: one JSON object
alone on stdout, whose values are the facts the same command prints without --json (or
that its output files hold). docs/cli.md lists the keys."""
from __future__ import annotations

import csv
import json
import re
import subprocess
import sys

import pytest

from imulink import core, protocol, sim
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.board.emulator import EmulatedBoard
from imulink.cli import main
from imulink.core.counts import BROAD_PROFILE, fixed_scales
from imulink.io.recording import KIND_EVENT, KIND_RECEIVED, RecordingWriter, load_recording, read_records

CLI = [sys.executable, "-c", "import sys; from imulink.cli import main; sys.exit(main())"]


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_json(capsys, *argv) -> tuple[int, dict]:
    """The command with --json: its exit status and the one object that is all of stdout."""
    code, out, _ = run_cli(capsys, *argv, "--json")
    return code, json.loads(out)  # fails on anything else printed to stdout


def line(out: str, prefix: str) -> str:
    [found] = [text for text in out.splitlines() if text.startswith(prefix)]
    return found


# ---------------------------------------------------------------------------- no board


def test_filters_json_lists_what_the_table_shows(capsys):
    code, report = run_json(capsys, "filters")
    assert code == 0
    code, out, _ = run_cli(capsys, "filters")
    table, current = {}, None
    for text in out.splitlines():
        if not text.startswith(" "):
            current = text.rstrip(":")
            table[current] = []
            continue
        name, value, unit, frac_bits = re.fullmatch(r"\s+(\S+)\s+(\S+)\s+(\S+)\s+\(fixed: Q(\d+)\)", text).groups()
        table[current].append((name, float(value), unit, int(frac_bits)))
    assert [f["filter"] for f in report["filters"]] == list(table) == list(core.BOARD_FILTERS)
    for entry in report["filters"]:
        rows = table[entry["filter"]]
        assert [(s["name"], s["unit"], s["frac_bits"]) for s in entry["settings"]] == [(r[0], r[2], r[3]) for r in rows]
        for setting, row in zip(entry["settings"], rows):
            assert setting["default"] == pytest.approx(row[1], rel=1e-5)  # the table shows six digits


def test_simulate_json_holds_the_table_s_numbers(capsys):
    args = ("simulate", "--duration", "15", "--scenario", "turntable", "--filters", "eecf,kf1d", "--seed", "3")
    code, report = run_json(capsys, *args)
    assert code == 0
    code, out, err = run_cli(capsys, *args)
    assert "simulating 'turntable'" in err
    assert report["samples"] == int(re.search(r"samples: (\d+);", out).group(1))
    assert (report["duration_s"], report["rate_hz"], report["seed"], report["settle_s"]) == (15.0, 100.0, 3, 10.0)
    assert [f["filter"] for f in report["filters"]] == ["eecf", "kf1d"]
    for entry in report["filters"]:
        name = entry["filter"]
        for arithmetic in ("fixed", "float"):
            total, heading, inclination, saturations = re.search(
                rf"^{name}\s+{arithmetic}\s+(\S+)\s+(\S+)\s+(\S+)\s+(\d+)", out, re.M).groups()
            mine = entry[arithmetic]
            assert mine["rms_total_deg"] == pytest.approx(float(total), abs=5e-4)
            assert mine["rms_heading_deg"] == pytest.approx(float(heading), abs=5e-4)
            assert mine["rms_inclination_deg"] == pytest.approx(float(inclination), abs=5e-4)
            assert mine["saturations"] == int(saturations) and mine["samples_per_s"] > 0
        maximum, mean = re.search(rf"^{name}\s+fixed vs float: max (\S+) deg, mean (\S+) deg", out, re.M).groups()
        assert entry["fixed_vs_float_max_deg"] == pytest.approx(float(maximum), abs=5e-6)
        assert entry["fixed_vs_float_mean_deg"] == pytest.approx(float(mean), abs=5e-6)


# ---------------------------------------------------------------------------- a board


def _stating_other_scales(source, path) -> None:
    """A copy of recording `source` in which the board's HELLO states gy86-broad's
    sensitivities: a firmware whose sensor scales are not the ones its filter ran with, so
    every estimate differs from the host's."""
    decoder = protocol.FrameDecoder()
    broad = dict(zip(("gyro_scale", "acc_scale", "mag_scale"), fixed_scales(BROAD_PROFILE)))
    with RecordingWriter(path, "test://", None) as writer:
        for record in read_records(source).records:
            if record.kind == KIND_EVENT:
                details = json.loads(record.body)
                writer.event(details.pop("event"), **details)
            elif record.kind == KIND_RECEIVED:
                writer.received(b"".join(protocol.encode(m.name, m.seq, **({**m.fields, **broad} if m.name == "HELLO"
                                                                            else m.fields))
                                         for m in decoder.feed(record.body)), record.time)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two recordings of the same emulated run (`record --json` summaries beside them): one
    as recorded, one whose board states other sensor scales than it ran with (every
    estimate differs)."""
    folder = tmp_path_factory.mktemp("json")
    path = folder / "clean.imulog"
    with EmulatedBoard(duration_s=5.0, filter_name="eecf") as board:
        command = CLI + ["record", board.address, "-o", str(path), "--json"]
        result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    _stating_other_scales(path, folder / "wrong.imulog")
    return folder, summary


def test_record_json_is_the_file_s_summary(recordings):
    folder, summary = recordings
    recording = load_recording(folder / "clean.imulog")
    assert summary["recording"] == str(folder / "clean.imulog")
    assert summary["samples"] == len(recording.samples) == 500
    assert summary["estimates"] == len(recording.estimates)
    assert summary["filter"] == "eecf" and summary["board"]["name"] == recording.hello["board"]
    assert summary["stop_reason"] == "the board stopped streaming" and summary["interrupted"] is False
    assert summary["link"]["frames"] == recording.counters["frames"] and summary["duration_s"] > 0


def _estimates_line(out: str) -> dict:
    counts = re.search(r"estimates: (\d+) received, (\d+) verifiable, (\d+) identical, (\d+) different, "
                       r"(\d+) unverifiable", out).groups()
    return dict(zip(("received", "verifiable", "identical", "different", "unverifiable"), map(int, counts)))


def test_compare_json_holds_the_report_s_facts(recordings, capsys):
    folder, _ = recordings
    for name, passed in (("clean", True), ("wrong", False)):
        path = folder / f"{name}.imulog"
        code, report = run_json(capsys, "compare", path)
        text_code, out, _ = run_cli(capsys, "compare", path)
        assert code == text_code == (0 if passed else 1)
        assert report["verdict"]["passed"] is passed and report["verdict"]["line"] == line(out, "bit-exact: ")
        counts = _estimates_line(out)
        assert {key: report["estimates"][key] for key in counts} == counts
        verdict = report["verdict"]
        assert (verdict["total"], verdict["verified"], verdict["identical"]) == (
            counts["received"], counts["verifiable"], counts["identical"])
        assert verdict["verified_fraction"] == counts["verifiable"] / counts["received"]
        frames, crc = re.search(r"link: (\d+) frames, \d+ bytes, CRC errors (\d+)", out).groups()
        assert (report["link"]["frames"], report["link"]["crc_errors"]) == (int(frames), int(crc))
        assert report["sensor_profile"] in line(out, "board: ")
        maximum = float(re.search(r"fixed vs float: attitude max (\S+) deg", out).group(1))
        assert report["fixed_vs_float"]["angle_max_deg"] == pytest.approx(maximum, abs=5e-6)
        if passed:
            assert report["first_difference"] is None and "first difference" not in out
        else:
            d = report["first_difference"]
            assert line(out, "first difference: ") == (
                f"first difference: estimate #{d['estimate']} (segment {d['segment']}, sample index "
                f"{d['sample_index']}): {d['field']}: board {d['board']}, host {d['host']}")
            assert counts["different"] == counts["verifiable"] > 0  # other scales: every estimate differs


def test_replay_json_is_compare_s_and_names_its_outputs(recordings, capsys, tmp_path):
    folder, _ = recordings
    path = folder / "clean.imulog"
    csv_path, npz_path = tmp_path / "clean.csv", tmp_path / "clean.npz"
    code, out, err = run_cli(capsys, "replay", path, "--csv", csv_path, "--npz", npz_path, "--json")
    report = json.loads(out)
    assert code == 0 and f"CSV: {csv_path}" in err and f"NPZ: {npz_path}" in err
    code, compared = run_json(capsys, "compare", path)
    assert {key: value for key, value in report.items() if key != "outputs"} == compared
    with open(csv_path) as f:
        rows = list(csv.reader(f))
    assert report["outputs"] == {"csv": str(csv_path), "csv_rows": len(rows) - 1, "csv_columns": len(rows[0]),
                                 "npz": str(npz_path)}


def test_inject_json_holds_the_report_s_facts(capsys):
    spec = "sim:rests:12:100:1"  # 1200 samples, the last 200 after the settling time
    with EmulatedBoard(duration_s=1.0) as board:
        code, report = run_json(capsys, "inject", board.address, "--input", spec)
        text_code, out, _ = run_cli(capsys, "inject", board.address, "--input", spec)
    assert code == text_code == 0
    assert report["samples"] == 1200 and report["answered"] + report["unanswered"] == 1200
    answered = int(re.search(r": (\d+) answered, ", out).group(1))
    assert report["answered"] == answered and report["input"] == line(out, "input: ")[len("input: "):]
    assert report["verdict"]["line"] == line(out, "bit-exact: ") and report["verdict"]["passed"] is True
    accuracy = re.search(r"over the (\d+) answered samples\): total (\S+) deg, heading (\S+) deg, "
                         r"inclination (\S+) deg", out).groups()
    assert report["accuracy"]["samples"] == int(accuracy[0]) == 200
    for key, text in zip(("rms_total_deg", "rms_heading_deg", "rms_inclination_deg"), accuracy[1:]):
        assert report["accuracy"][key] == pytest.approx(float(text), abs=5e-4)


def test_demo_json_is_alone_on_stdout_and_matches_its_recording(tmp_path):
    """Through a process of its own: nothing of the emulated board reaches stdout either."""
    path = tmp_path / "demo.imulog"
    result = subprocess.run(CLI + ["demo", "--duration", "20", "-o", str(path), "--json"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    recording = load_recording(path)
    assert report["recording"] == report["record"]["recording"] == str(path)
    assert report["record"]["samples"] == len(recording.samples) == 2000
    assert report["verdict"] == report["compare"]["verdict"] and report["verdict"]["total"] == len(recording.estimates)
    compared = subprocess.run(CLI + ["compare", str(path), "--json"], capture_output=True, text=True, timeout=120)
    assert json.loads(compared.stdout) == report["compare"]
    # the accuracy is the host fixed build's against the truth of the same simulation
    data = sim.make_scenario("rests", 20.0, 100.0, seed=0)
    host = core.run_counts("eskf", data.gyr_counts, data.acc_counts, data.mag_counts, 100.0)
    expected = rmse(attitude_errors(host.quat[1000:], data.quat_true[1000:]))
    assert report["accuracy"]["rms_total_deg"] == pytest.approx(expected["total"], abs=1e-9)
    assert report["accuracy"]["settle_s"] == 10.0
