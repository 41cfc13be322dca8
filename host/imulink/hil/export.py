"""The replay of a recording as columns, CSV or NumPy arrays."""
from __future__ import annotations

import json

import numpy as np

from imulink import core, protocol
from imulink.analysis.attitude import angle_difference
from imulink.hil.common import ESTIMATE_FRAC_BITS
from imulink.hil.comparison import Comparison, HostRun, nav_state_position
from imulink.io.recording import Estimates, Recording, sample_rows, sample_times


def replay_columns(recording: Recording, run: HostRun, comparison: Comparison) -> dict[str, np.ndarray]:
    """One row per recorded sample: its time (recording.sample_times), inputs in SI, the
    board's estimate (NaN where its ESTIMATE was lost), the host fixed build and the float
    twin, and whether the board's estimate was identical (1), different (0) or not
    verifiable (NaN). Keys are CSV
    column names that carry their units."""
    s, e, p = recording.samples, recording.estimates, recording.profile
    n = len(s)
    estimate_of = np.full(n, -1)
    has_sample = comparison.sample_row >= 0
    estimate_of[comparison.sample_row[has_sample]] = np.flatnonzero(has_sample)
    have = estimate_of >= 0

    def board(values: np.ndarray, frac_bits: int) -> np.ndarray:
        out = np.full((n,) + values.shape[1:], np.nan)
        out[have] = values[estimate_of[have]] * 2.0**-frac_bits
        return out

    # time_s first: strictly increasing (the sample index at the board's rate), the axis a plotting tool wants
    columns = {"time_s": sample_times(recording), "host_time_s": s.host_time, "timestamp_us": s.timestamp_us,
               "segment": s.segment, "index": s.index, "recovered": s.recovered.astype(int),
               "verifiable": run.verifiable.astype(int)}
    axes = ("x", "y", "z")
    for name, counts, scale, unit in (("gyr", s.gyr, p.gyro_scale, "rad_s"), ("acc", s.acc, p.acc_scale, "m_s2"),
                                      ("mag", s.mag, p.mag_scale, "uT")):
        for k, axis in enumerate(axes):
            columns[f"{name}_{axis}_{unit}"] = counts[:, k] * scale
    fixed_quat = run.fixed["quat"] * 2.0**-ESTIMATE_FRAC_BITS["quat"]
    sources = {"board": (board(e.quat, ESTIMATE_FRAC_BITS["quat"]), board(e.euler, ESTIMATE_FRAC_BITS["euler"]),
                         board(e.gyro_bias, ESTIMATE_FRAC_BITS["gyro_bias"])),
               "fixed": (fixed_quat, run.fixed["euler"] * 2.0**-ESTIMATE_FRAC_BITS["euler"],
                         run.fixed["gyro_bias"] * 2.0**-ESTIMATE_FRAC_BITS["gyro_bias"]),
               "float": (run.float_quat, run.float_euler, run.float_gyro_bias)}
    for source, (quat, euler, bias) in sources.items():
        for k, part in enumerate("wxyz"):
            columns[f"{source}_q{part}"] = quat[:, k]
        for k, angle in enumerate(("roll", "pitch", "heading")):
            columns[f"{source}_{angle}_deg"] = np.degrees(euler[:, k])
        for k, axis in enumerate(axes):
            columns[f"{source}_gyro_bias_{axis}_rad_s"] = bias[:, k]
    weights = board(e.weights, 30)  # zero but for the ESKF
    columns["board_gravity_weight"], columns["board_heading_weight"] = weights[:, 0], weights[:, 1]
    if run.nav is not None:
        columns.update(_nav_columns(recording, run))
    columns["baro_pa"], columns["baro_temp_c"] = _baro_columns(recording)
    columns.update(_gnss_columns(recording))
    identical = np.full(n, np.nan)
    checked = have.copy()
    checked[have] = comparison.verified[estimate_of[have]]
    identical[checked] = comparison.identical[estimate_of[checked]]
    columns["identical"] = identical
    columns["fixed_float_angle_deg"] = angle_difference(fixed_quat, run.float_quat)
    return columns


def _nav_columns(recording: Recording, run: HostRun) -> dict[str, np.ndarray]:
    """The nav filter's position and velocity per sample: the board's (its NAV_STATE), the
    host fixed build's and the float twin's (position only); NaN without a position."""
    nav, nav_rows, float_position = run.nav, run.nav_rows, run.float_position
    # host_run sets the three together, where the nav filter ran (replay_columns calls this only then)
    assert nav is not None and nav_rows is not None and float_position is not None
    n = len(recording.samples)
    states = recording.nav_states.fields
    rows = sample_rows(recording, recording.nav_states.segment, recording.nav_states.index)
    board = {name: np.zeros((n,) + values.shape[1:], np.int64) for name, values in states.items()}
    board_mode = np.zeros(n, np.int64)
    for name, values in states.items():
        board[name][rows[rows >= 0]] = values[rows >= 0]
    board_mode[rows[rows >= 0]] = states["mode"][rows >= 0]
    columns = {}
    for source, fields, positioned in (("board", board, board_mode == 2),
                                       ("fixed", nav, nav_rows & (nav["mode"] == 2))):
        def masked(values: np.ndarray) -> np.ndarray:
            return np.where(positioned, values, np.nan)

        lat, lon, height = nav_state_position(fields)
        columns[f"{source}_lat_deg"], columns[f"{source}_lon_deg"] = masked(lat), masked(lon)
        columns[f"{source}_height_m"] = masked(height)
        for k, axis in enumerate(("e", "n", "u")):
            columns[f"{source}_vel_{axis}_m_s"] = masked(fields["vel"][:, k] * core.NAV_VEL_SCALE)
    for k, name in enumerate(("lat_deg", "lon_deg", "height_m")):
        columns[f"float_{name}"] = float_position[:, k]
    return columns


def _gnss_columns(recording: Recording) -> dict[str, np.ndarray]:
    """The receiver's fixes in the rows of the samples they arrived with, empty elsewhere, in
    SI units under `imulink nav`'s input names (velocity east, north, up), with gnss_time_ms,
    the time each is valid for (the receiver's clock: its latency is the difference)."""
    g, n = recording.gnss, len(recording.samples)
    rows = sample_rows(recording, g.segment, g.index)
    have = rows >= 0
    def si(name: str):  # the real value of a GNSS field in its unit (deg, m, m/s)
        return getattr(g, name) * protocol.field_format("GNSS", name).scale

    values = {"gnss_time_ms": g.time_ms, "gnss_lat_deg": si("lat_1e7deg"), "gnss_lon_deg": si("lon_1e7deg"),
              "gnss_height_m": si("height_mm"), "gnss_vel_e_m_s": si("vel_ned_mm_s")[:, 1],
              "gnss_vel_n_m_s": si("vel_ned_mm_s")[:, 0], "gnss_vel_u_m_s": -si("vel_ned_mm_s")[:, 2],
              "gnss_h_acc_m": si("h_acc_mm"), "gnss_v_acc_m": si("v_acc_mm"), "gnss_s_acc_m_s": si("s_acc_mm_s")}
    columns = {}
    for name, value in values.items():
        column = np.full(n, np.nan)
        if name.startswith("gnss_vel") or name == "gnss_s_acc_m_s":
            ok = have & (g.has_velocity != 0)
        else:
            ok = have
        column[rows[ok]] = value[ok]
        columns[name] = column
    return columns


def _baro_columns(recording: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The barometer's pressure (Pa) and temperature (degC) in the rows of the samples they
    were read with (by segment and index), empty elsewhere: the columns `imulink nav`'s input
    names so."""
    b, n = recording.baro, len(recording.samples)
    rows = sample_rows(recording, b.segment, b.index)
    have = rows >= 0
    pressure, temperature = np.full(n, np.nan), np.full(n, np.nan)
    pressure[rows[have]] = b.pressure_pa[have]
    temperature[rows[have]] = b.temperature_cdeg[have] / 100.0
    return pressure, temperature


#: Replay columns that hold integers (a float column only where some rows have no value).
_INTEGER_COLUMNS = ("timestamp_us", "segment", "index", "recovered", "verifiable", "identical", "gnss_time_ms")


def export_csv(columns: dict[str, np.ndarray], path) -> None:
    """Write replay columns as CSV (empty cells where a value is missing). Every number
    reads back as the value it was: integers as integers, floats in Python's shortest
    round-trip form (a Unix host time keeps its microseconds, not nine digits)."""
    names = list(columns)

    def cells(name: str) -> list[str]:
        values = np.asarray(columns[name])
        if name in _INTEGER_COLUMNS or np.issubdtype(values.dtype, np.integer):
            return ["" if v != v else str(int(v)) for v in values.tolist()]  # v != v: NaN
        return ["" if v != v else repr(v) for v in values.astype(np.float64).tolist()]

    with open(path, "w", encoding="utf-8") as out:
        out.write(",".join(names) + "\n")
        for row in zip(*(cells(name) for name in names)):
            out.write(",".join(row) + "\n")


def export_npz(recording: Recording, run: HostRun, columns: dict[str, np.ndarray], path) -> None:
    """Write the replay as .npz: the CSV columns, the raw integers (sensor counts, the
    board's and the host's ESTIMATE fields) and the recording's metadata as JSON."""
    raw = {f"samples_{k}": getattr(recording.samples, k) for k in
           ("gyr", "acc", "mag", "temperature", "timestamp_us", "index", "segment", "host_time", "recovered")}
    raw.update({f"board_{k}": getattr(recording.estimates, k) for k in
                ("index", "segment", "host_time") + Estimates.COMPARED})
    raw.update({f"host_fixed_{k}": v for k, v in run.fixed.items()})
    meta = {"header": recording.header, "hello": recording.hello, "status": recording.status,
            "counters": recording.counters, "events": recording.events}
    with open(path, "wb") as out:  # a file object: numpy would add ".npz" to a path without it
        # numpy's stub declares allow_pickle: bool beside **kwds, and mypy matches **columns against it
        np.savez_compressed(out, **columns, **raw,  # type: ignore[arg-type]
                            metadata=np.array(json.dumps(meta, default=str)))
