"""The `board` fixture of imulink.hil.pytest_plugin, as a project's HIL tests use it
(tests/test_farm.py has it on a labgrid place)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: A project's HIL test: the same code for a lab's board and CI's emulated one.
PROJECT_TEST = '''
from imulink import hil

def test_the_board_is_bit_exact(board):
    result = hil.inject(board.url, hil.load_injection_input("sim:rests:1"), baud=board.baud)
    assert result.verdict.passed and result.answered == 100
    print(f"BOARD place={board.place} target={board.target}")
'''


def run_project_tests(directory: Path, *options: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """The project test above, run by pytest with the plugin, in its own directory."""
    (directory / "test_project.py").write_text(PROJECT_TEST)
    command = [sys.executable, "-m", "pytest", "-q", "-s", "-p", "imulink.hil.pytest_plugin", "-p",
               "no:cacheprovider", str(directory / "test_project.py"), *options]
    return subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=directory, env=env)


def test_without_a_lab_the_board_is_the_native_one(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("LG_PLACE", "IMULINK_BOARD")}
    done = run_project_tests(tmp_path, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "BOARD place=None target=native" in done.stdout


def test_a_port_given_is_used_as_it_is(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("LG_PLACE", "IMULINK_BOARD")}
    done = run_project_tests(tmp_path, "--imulink-board", "socket://127.0.0.1:1", env=env)
    assert done.returncode == 1
    assert "connection refused" in done.stdout


def test_an_emulated_board_is_started_with_the_image_given(tmp_path):
    """--imulink-image: an emulated board runs it (here the native board's own build, named);
    an image of another board fails the session's tests in one line, nothing started."""
    from imulink.board.emulator import find_image

    env = {k: v for k, v in os.environ.items() if k not in ("LG_PLACE", "IMULINK_BOARD", "IMULINK_IMAGE")}
    native = str(find_image("native"))
    done = run_project_tests(tmp_path, "--imulink-board", "native", "--imulink-image", native, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "BOARD place=None target=native" in done.stdout
    wrong = run_project_tests(tmp_path, "--imulink-board", "native", env={**env, "IMULINK_IMAGE": str(tmp_path)})
    assert wrong.returncode == 1, wrong.stdout + wrong.stderr
    assert "the board native: " in wrong.stdout and "Traceback" not in wrong.stdout, wrong.stdout
