"""`imulink plot RECORDING -o FILE`: a recording as one figure, its events marked."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from imulink import hil
from imulink.board.emulator import EmulatedBoard
from imulink.board.proxy import FaultConfig
from imulink.cli import main
from imulink.io.recording import load_recording, sample_times

pytest.importorskip("matplotlib", reason="the plot extra (matplotlib) is not installed")


@pytest.fixture(scope="module")
def faulty_recording(tmp_path_factory):
    """A recording over a link that drops bytes, without RESEND and checkpoints: lost samples and filter restarts."""
    path = tmp_path_factory.mktemp("plot") / "faulty.imulog"
    with EmulatedBoard(front="tcp", duration_s=5.0, rate_hz=200.0, realtime=True,
                       faults=FaultConfig(drop_byte=3e-4, seed=8)) as board:
        hil.record(board.address, path, duration_s=2.0, resend=False, checkpoint_s=0.0)
    return path


def test_plot_marks_restarts_and_lost_samples(faulty_recording, tmp_path, capsys):
    recording = load_recording(faulty_recording)
    s = recording.samples
    runs = int(np.count_nonzero(np.diff(s.segment) != 0)) + 1
    lost = int(np.count_nonzero((np.diff(s.segment) == 0) & (np.diff(s.index) > 1)))
    assert runs > 1 and lost > 0  # the faults did their part
    svg = tmp_path / "faulty.svg"
    code = main(["plot", str(faulty_recording), "-o", str(svg)])
    out = capsys.readouterr().out
    verdict = next(line for line in hil.format_comparison(recording, hil.compare(recording)).splitlines()
                   if line.startswith("bit-exact"))
    assert code == 0 and verdict in out
    text = svg.read_text()
    assert f"{len(s)} samples, {runs} filter run(s), {lost} lost sample(s), 0 recovered" in text
    # the title as matplotlib keeps it in an SVG comment, which holds no "--": the verdict up to its parenthesis
    assert verdict.split(" (")[0] in text and "lost sample" in text and "not verifiable" in text


def test_plot_marks_recovered_samples(tmp_path, capsys):
    path = tmp_path / "recovered.imulog"
    with EmulatedBoard(duration_s=2.0, faults=FaultConfig(drop_samples=(50, 120))) as board:
        hil.record(board.address, path)
    svg = tmp_path / "recovered.svg"
    assert main(["plot", str(path), "-o", str(svg)]) == 0
    assert "bit-exact: yes (200 of 200" in capsys.readouterr().out
    text = svg.read_text()
    assert "200 samples, 1 filter run(s), 0 lost sample(s), 2 recovered" in text and "recovered sample" in text


def test_plot_png_and_refusals(faulty_recording, tmp_path, capsys, monkeypatch):
    png = tmp_path / "faulty.png"
    assert main(["plot", str(faulty_recording), "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main(["plot", str(faulty_recording), "-o", str(tmp_path / "x.jpg")]) == 2
    assert "cannot tell the plot format" in capsys.readouterr().err and not (tmp_path / "x.jpg").exists()
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["plot", str(faulty_recording), "-o", str(tmp_path / "y.png")]) == 2
    assert "pip install 'imulink[plot]'" in capsys.readouterr().err and not (tmp_path / "y.png").exists()


def test_sample_times_follow_the_board_s_rate_and_keep_gaps(faulty_recording):
    recording = load_recording(faulty_recording)
    t, s = sample_times(recording), recording.samples
    rate = recording.status["sample_rate_mhz"] / 1000.0
    same_run = np.diff(s.segment) == 0
    np.testing.assert_allclose(np.diff(t)[same_run], np.diff(s.index)[same_run] / rate)
    np.testing.assert_allclose(np.diff(t)[~same_run], 1.0 / rate)


def test_replay_csv_has_a_strictly_increasing_time_column(faulty_recording, tmp_path):
    """PlotJuggler's CSV loader wants a strictly increasing time axis: time_s, the first column."""
    csv = tmp_path / "faulty.csv"
    passed = hil.compare(load_recording(faulty_recording)).verdict.passed  # replay's exit status says it
    assert main(["replay", str(faulty_recording), "--csv", str(csv)]) == (0 if passed else 1)
    header = csv.read_text().splitlines()[0].split(",")
    time_s = np.genfromtxt(csv, delimiter=",", skip_header=1, usecols=0)
    assert header[0] == "time_s" and np.all(np.diff(time_s) > 0)
    np.testing.assert_array_equal(time_s, sample_times(load_recording(faulty_recording)))

