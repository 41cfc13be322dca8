"""Many recordings at once: `imulink compare` over files, directories and glob patterns, in
worker processes.

Each worker loads and compares one recording at a time and hands back a few numbers (the
verdict, the counts, the first difference), so a worker's memory is that of the largest
recording, whatever the number of files, and the parent keeps one small row per file.
"""
from __future__ import annotations

import glob
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from imulink.errors import ImulinkError
from imulink.hil.common import rows_in_order, verdict_mark
from imulink.hil.comparison import MIN_VERIFIED, compare
from imulink.io.recording import load_recording

#: Characters that make an argument a glob pattern rather than a path.
GLOB_CHARACTERS = "*?["


class BatchError(ImulinkError):
    """An argument that names no recording."""


def is_pattern(argument: str) -> bool:
    """A glob pattern: it has a pattern character and is not itself an existing path."""
    return any(c in argument for c in GLOB_CHARACTERS) and not os.path.exists(argument)


def expand(arguments: Sequence[str]) -> list[Path]:
    """The recordings the arguments name, in their order: a file as it is, a directory's
    regular files (sorted, not its subdirectories), a glob pattern's matches (sorted);
    each file once. BatchError for a path that does not exist, a pattern or a directory
    that names no file."""
    found: dict[Path, None] = {}
    for argument in arguments:
        if is_pattern(argument):
            matches = [Path(m) for m in sorted(glob.glob(argument)) if Path(m).is_file()]
            if not matches:
                raise BatchError(f"no recording matches {argument!r}")
        elif os.path.isdir(argument):
            matches = sorted(p for p in Path(argument).iterdir() if p.is_file())
            if not matches:
                raise BatchError(f"the directory {argument} holds no file")
        elif os.path.exists(argument):
            matches = [Path(argument)]
        else:
            raise BatchError(f"no such file or directory: {argument}")
        found.update(dict.fromkeys(matches))
    return list(found)


def compare_one(path: Path | str, min_verified: float = MIN_VERIFIED) -> dict:
    """One recording's row: {"recording", "board", "samples", "recorded", "verified",
    "identical", "passed", "verdict" (the verdict line), "first_difference" (text or None),
    "error" (None, or why the file could not be compared: it then fails)}."""
    row: dict = {"recording": str(path), "board": None, "samples": 0, "recorded": 0, "verified": 0,
                 "identical": 0, "passed": False, "verdict": None, "first_difference": None, "error": None}
    try:
        recording = load_recording(path)
        comparison = compare(recording, min_verified=min_verified)
    except (ImulinkError, OSError) as exc:
        row["error"] = str(exc)
        return row
    verdict = comparison.verdict
    hello = recording.hello or {}
    row.update(board=hello.get("board"), samples=len(recording.samples), recorded=verdict.total,
               verified=verdict.verified, identical=verdict.identical, passed=verdict.passed,
               verdict=str(verdict),
               first_difference=None if comparison.first_difference is None else str(comparison.first_difference))
    return row


def compare_many(paths: Sequence[Path], min_verified: float = MIN_VERIFIED, jobs: int = 1,
                 progress: Callable[[int, dict], None] | None = None) -> list[dict]:
    """compare_one for every path, `jobs` worker processes at a time (1: in this process);
    rows in the order of `paths`; `progress(done, row)` after each."""
    rows: list[dict | None] = [None] * len(paths)
    if jobs <= 1 or len(paths) <= 1:
        for k, path in enumerate(paths):
            rows[k] = compare_one(path, min_verified)
            if progress:
                progress(k + 1, rows[k])  # type: ignore[arg-type]
        return rows  # type: ignore[return-value]
    return rows_in_order(ProcessPoolExecutor(max_workers=min(jobs, len(paths))), compare_one, paths, progress,
                         min_verified=min_verified)


def format_table(rows: Sequence[dict]) -> str:
    """One line per recording and a summary: file, board, samples, recorded estimates,
    verified, identical, bit-exact, and the first difference, the verdict or the error."""
    width = max([len("recording"), *(len(r["recording"]) for r in rows)])
    lines = [f"{'recording':{width}s}  {'board':14s} {'samples':>8s} {'recorded':>8s} {'verified':>8s} "
             f"{'identical':>9s}  bit-exact  detail"]
    for r in rows:
        detail = r["error"] or r["first_difference"] or ("" if r["passed"] else r["verdict"])
        lines.append(f"{r['recording']:{width}s}  {str(r['board'] or '-'):14s} {r['samples']:8d} {r['recorded']:8d} "
                     f"{r['verified']:8d} {r['identical']:9d}  {verdict_mark(r):9s}  {detail}".rstrip())
    passed = sum(r["passed"] for r in rows)
    errors = sum(r["error"] is not None for r in rows)
    lines.append(f"{len(rows)} recordings: {passed} bit-exact, {len(rows) - passed - errors} not, "
                 f"{errors} could not be read")
    return "\n".join(lines)


def batch_json(rows: Sequence[dict]) -> dict:
    """What `imulink compare --json` prints for more than one recording."""
    passed = sum(r["passed"] for r in rows)
    errors = sum(r["error"] is not None for r in rows)
    return {"recordings": list(rows), "count": len(rows), "passed": passed, "failed": len(rows) - passed - errors,
            "errors": errors}
