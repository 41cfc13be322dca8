"""Golden vectors: the fixed-point build reproduces shared/vectors/*.vec bit for bit.

Each vector is replayed through imulink.core (the cffi module of the fixed build)
with the settings and sensor scales rebuilt from the raw integers stored in the
file, never from the C default settings. On a mismatch the first differing sample
and output field are reported. The files are regenerated only on purpose with
`python tools/gen_vectors.py` (see shared/vectors/README.md).
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from imulink import core
from imulink.core import _fixed as _core_fixed

ROOT = Path(__file__).resolve().parents[1]
VECTOR_DIR = ROOT / "shared" / "vectors"


def _load_gen_vectors():
    spec = importlib.util.spec_from_file_location("gen_vectors", ROOT / "tools" / "gen_vectors.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["gen_vectors"] = mod  # dataclasses look the module up while it executes
    spec.loader.exec_module(mod)
    return mod


gv = _load_gen_vectors()
VECTOR_FILES = gv.vector_files(VECTOR_DIR)


def first_mismatch(expected: np.ndarray, actual: np.ndarray) -> str | None:
    """Description of the first differing (sample, field) of two (N,10) output arrays, or None."""
    if expected.shape != actual.shape:
        return f"shape differs: expected {expected.shape}, got {actual.shape}"
    diff = np.argwhere(expected != actual)
    if diff.size == 0:
        return None
    i, k = (int(x) for x in diff[0])
    return (f"first mismatch at sample {i}, field {gv.OUTPUT_COLUMNS[k]}: expected {int(expected[i, k])}, "
            f"got {int(actual[i, k])} ({len(np.unique(diff[:, 0]))} samples differ)")


def checked_settings(v) -> dict[str, float]:
    """SI settings rebuilt from the stored raw integers, after checking them against the core's
    descriptors and checking that the SI <-> raw conversions reproduce the raw integers exactly."""
    fields = {f.name: f for f in core.settings_fields(v.filter_name)}
    missing = sorted(set(fields) - set(v.settings))
    unknown = sorted(set(v.settings) - set(fields))
    assert not missing and not unknown, (
        f"{v.name}: settings differ from the C struct (missing {missing}, unknown {unknown}); "
        "the vectors must be regenerated on purpose"
    )
    si = v.settings_si_exact()
    for name, (fb, raw, stored_si, unit) in v.settings.items():
        assert fb == fields[name].frac_bits, f"{v.name}: {name} is Q{fb} in the file, Q{fields[name].frac_bits} in C"
        assert unit == fields[name].unit, f"{v.name}: {name} unit {unit!r} != {fields[name].unit!r}"
        assert -(2**31) <= raw < 2**31
        assert core.to_fixed(si[name], fb, name) == raw, f"{v.name}: raw -> SI -> raw changes {name}"
        assert core.to_fixed(stored_si, fb, name) == raw, f"{v.name}: stored SI of {name} does not give its raw"
    assert si["sample_rate"] == v.rate_hz, f"{v.name}: sample_rate setting differs from rate_hz"
    return si


def checked_sensor(v):
    """Sensor scales rebuilt from the raw integers; core.sensor_struct must reproduce them exactly."""
    assert set(v.sensor) == {name for name, _ in gv.SENSOR_FIELDS}
    profile = v.sensor_exact()
    struct = core.sensor_struct(_core_fixed, "fixed", profile)
    for name, fb in gv.SENSOR_FIELDS:
        file_fb, raw, stored_si = v.sensor[name]
        assert file_fb == fb, f"{v.name}: sensor {name} is Q{file_fb}, the core uses Q{fb}"
        assert getattr(struct, name) == raw, f"{v.name}: raw -> SI -> raw changes {name}"
        assert core.to_fixed(stored_si, fb, name) == raw
    return profile


def test_vector_set_is_complete_and_small():
    assert VECTOR_FILES, f"no vector files in {VECTOR_DIR}; run tools/gen_vectors.py"
    vectors = [gv.read_vector(p) for p in VECTOR_FILES]
    for filter_name in core.FILTERS:
        mine = [v for v in vectors if v.filter_name == filter_name]
        assert len(mine) >= 4, f"too few vectors for {filter_name}"
        assert any(v.rate_hz != 100.0 for v in mine), f"no non-100 Hz vector for {filter_name}"
    for p, v in zip(VECTOR_FILES, vectors):
        assert p.stem == v.name
        assert 300 <= v.samples <= 3000, f"{p.name}: {v.samples} samples"
    total = sum(p.stat().st_size for p in VECTOR_FILES)
    assert total < 3 * 2**20, f"vectors take {total} bytes"


@pytest.mark.parametrize("path", VECTOR_FILES, ids=[p.stem for p in VECTOR_FILES])
def test_fixed_build_reproduces_vector(path):
    v = gv.read_vector(path)
    filter_id, _ = core.FILTERS[v.filter_name]
    assert v.filter_id == filter_id, f"{v.name}: filter_id {v.filter_id} != {filter_id}"
    settings = checked_settings(v)
    profile = checked_sensor(v)
    ins = v.inputs
    r = core.run_counts(v.filter_name, ins[:, 0:3], ins[:, 3:6], ins[:, 6:9], v.rate_hz, "fixed",
                        settings=settings, profile=profile)
    # The settings the core used are exactly those of the file (no default slipped in).
    assert r.settings == settings
    got = np.concatenate([r.raw["quat"], r.raw["euler"], r.raw["gyro_bias"]], axis=1)
    assert got.dtype == np.int32
    problem = first_mismatch(v.outputs, got)
    assert problem is None, f"{path.name}: {problem}"
    assert r.saturations == v.saturations, f"{path.name}: saturations {r.saturations} != {v.saturations}"


@pytest.mark.parametrize("path", VECTOR_FILES[:1], ids=[p.stem for p in VECTOR_FILES[:1]])
def test_reader_and_writer_agree(path):
    """Reading and rewriting a file reproduces it byte for byte (the reader drops nothing)."""
    text = path.read_text()
    assert gv.format_vector(gv.parse_vector(text, path.name)) == text


def test_first_mismatch_names_sample_and_field():
    v = gv.read_vector(VECTOR_FILES[0])
    changed = v.outputs.copy()
    changed[17, 5] += 1  # pitch of sample 17
    changed[40, 0] -= 1
    msg = first_mismatch(v.outputs, changed)
    assert msg is not None and "sample 17" in msg and "field pitch" in msg and "2 samples differ" in msg
    assert first_mismatch(v.outputs, v.outputs.copy()) is None


def test_parse_rejects_damaged_files():
    text = VECTOR_FILES[0].read_text()
    with pytest.raises(ValueError, match="format"):
        gv.parse_vector(text.replace("imulink-vector 1", "imulink-vector 2"))
    lines = text.split("\n")
    data = lines.index("data")
    with pytest.raises(ValueError, match="data lines"):
        gv.parse_vector("\n".join(lines[:data + 5] + lines[data + 6:]))  # one sample missing
    lines[data + 1] = lines[data + 1] + " 7"
    with pytest.raises(ValueError):
        gv.parse_vector("\n".join(lines))
