"""Allan deviation of a static recording, and the sensor noise terms read from it.

The board lies still; each axis of the gyroscope (rad/s) and of the accelerometer (m/s^2)
is then noise around a constant. :func:`allan_curve` computes the overlapping Allan
deviation (ADEV) at octave-spaced averaging times tau = m / rate, m = 1, 2, 4, ..., with
a confidence interval per point; :func:`axis_terms` reads the three classic terms off the
curve the way IEEE Std 952-1997 (Annex C) reads them off a log-log plot:

* white noise, N (angle random walk of a gyroscope, velocity random walk of an
  accelerometer): where the curve falls with slope -1/2, sigma(tau) = N / sqrt(tau);
  N is that line's value at tau = 1 s.
* bias instability, B: the floor of the curve; flicker noise gives a flat floor at
  sigma = sqrt(2 ln 2 / pi) B = 0.664 B.
* rate random walk, K (a random walk of the bias): where the curve rises with slope
  +1/2, sigma(tau) = K sqrt(tau / 3); K is that line's value at tau = 3 s.

A term the curve does not show (a record too short for the +1/2 slope, a curve still
falling at its longest tau) is None with the reason, never a guess.

:func:`load_static` reads the inputs (a recording, a replay CSV, a BROAD trial's longest
rest), :func:`analyse` runs both sensors, :func:`settings_from_terms` maps the terms onto a
filter's settings, :func:`plot` draws the curves (matplotlib, optional).
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from scipy.stats import chi2

from imulink import core
from imulink.analysis.plotting import check_plotting, plot_format
from imulink.core.counts import STANDARD_GRAVITY
from imulink.io import sensor_input
from imulink.io.sensor_input import CSV_COLUMNS, InputError, SensorRecord
from imulink.progress import CountProgress

#: Default confidence of the intervals: one standard deviation of a normal distribution.
CONFIDENCE = 0.683
#: The longest averaging time leaves at least this many cluster lengths in the record:
#: beyond it a point has too few degrees of freedom to say much (about 6 for a random walk).
MIN_CLUSTERS = 9
#: Fewest averaging times of an analysis (m = 1, 2, 4, 8).
MIN_POINTS = 4
#: Fewest samples: MIN_POINTS octaves of MIN_CLUSTERS clusters.
MIN_SAMPLES = MIN_CLUSTERS * 2 ** (MIN_POINTS - 1)
#: Floor of flicker noise over its bias-instability coefficient: sqrt(2 ln 2 / pi).
FLOOR_OVER_BIAS_INSTABILITY = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664
#: The +1/2 line is read at this averaging time, s (IEEE Std 952: sigma(3 s) = K).
RANDOM_WALK_TAU_S = 3.0
#: Random-walk points need at least this cluster size: a random walk sampled at the rate
#: has an ADEV above the continuous K sqrt(tau / 3) by sqrt(1 + 1 / (2 m^2)): 22 % at
#: m = 1, 0.1 % at m = 16 (a sensor that averages over its sample period has no excess).
RANDOM_WALK_MIN_M = 16
#: Random-walk points lie at least this factor above the floor: the random walk then makes
#: three quarters of their variance or more, the terms of the floor the rest at most.
RANDOM_WALK_OVER_FLOOR = 2.0
#: The confidence of the intervals that decide whether the curve shows a floor or a random
#: walk (three standard deviations): a white-noise record of a few minutes has dozens of
#: points, and 68 % intervals that do not overlap somewhere among them are no evidence.
DETECTION_CONFIDENCE = 0.997
#: A recording's timestamps give its rate when they agree with the board's declared rate
#: within this fraction.
RATE_TOLERANCE = 0.05
#: Sums run over chunks of this many samples: temporaries of 8 MiB, not of the record.
_CHUNK = 1 << 20

#: The three terms of each sensor, in the order of :func:`axis_terms`.
TERMS = {"gyro": ("arw", "bias_instability", "rrw"), "acc": ("vrw", "bias_instability", "rrw")}
#: SI unit of each sensor's signal and terms.
UNITS = {"gyro": {"adev": "rad/s", "arw": "rad/s/sqrt(Hz) = rad/sqrt(s)", "bias_instability": "rad/s",
                  "rrw": "rad/s/sqrt(s)"},
         "acc": {"adev": "m/s^2", "vrw": "m/s^2/sqrt(Hz) = m/s/sqrt(s)", "bias_instability": "m/s^2",
                 "rrw": "m/s^2/sqrt(s)"}}
TERM_NAMES = {"arw": "angle random walk", "vrw": "velocity random walk", "bias_instability": "bias instability",
              "rrw": "rate random walk"}
AXES = ("x", "y", "z")
_DEG = 180.0 / math.pi
_MICRO_G = 1e6 / STANDARD_GRAVITY


class AllanError(InputError):
    """An input that cannot be analysed (too short, gaps, backwards timestamps, ...)."""




# ---------------------------------------------------------------------------- the curve


def cluster_sizes(samples: int) -> np.ndarray:
    """Octave-spaced cluster sizes m = 1, 2, 4, ... up to samples / MIN_CLUSTERS."""
    if samples < MIN_SAMPLES:
        return np.zeros(0, np.int64)
    return 2 ** np.arange(int(math.log2(samples // MIN_CLUSTERS)) + 1, dtype=np.int64)


def overlapping_adev(rate: np.ndarray, rate_hz: float, sizes: np.ndarray | None = None,
                     progress: CountProgress | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of one axis of a rate signal.

    NIST SP 1065 eq. (11) on the running sum x of the N samples (x_0 = 0,
    x_k = y_0 + ... + y_(k-1)), so that (x_(k+m) - x_k) / m is the mean of a cluster:
    sigma^2(m) = sum_k (x_(k+2m) - 2 x_(k+m) + x_k)^2 / (2 m^2 (N + 1 - 2m)),
    k = 0 .. N - 2m, at tau = m / rate_hz.

    The mean is removed before the running sum (it cancels in the differences): the sum
    then stays near zero and keeps float64's precision over 10^7 samples.

    Args:
        rate: (N,) samples (rad/s, m/s^2: the deviation has the same unit).
        rate_hz: sample rate, Hz.
        sizes: cluster sizes m (default :func:`cluster_sizes`).
        progress: called with (sizes done, sizes) after each size.

    Returns:
        (tau_s, adev), each (len(sizes),).
    """
    y = np.asarray(rate, dtype=np.float64)
    n = y.shape[0]
    sizes = cluster_sizes(n) if sizes is None else np.asarray(sizes, dtype=np.int64)
    x = np.empty(n + 1)  # the only array of the record's length: 8 bytes a sample
    x[0] = 0.0
    x[1:] = y
    x[1:] -= y.mean()
    np.cumsum(x[1:], out=x[1:])
    adev = np.empty(len(sizes))
    for i, m in enumerate(sizes):
        terms = n + 1 - 2 * m
        if m < 1 or terms < 1:
            raise ValueError(f"cluster size {m} does not fit {n} samples")
        total = 0.0
        for start in range(0, terms, _CHUNK):
            stop = min(start + _CHUNK, terms)
            d = x[start + 2 * m:stop + 2 * m] - x[start + m:stop + m]
            d -= x[start + m:stop + m]
            d += x[start:stop]
            total += float(np.dot(d, d))
        adev[i] = math.sqrt(total / (2.0 * terms)) / m
        if progress is not None:
            progress(i + 1, len(sizes))
    return sizes / rate_hz, adev


def edf(samples: int, m: int, alpha: int) -> float:
    """Equivalent degrees of freedom of an overlapping ADEV point, for power-law noise
    S_y(f) ~ f^alpha: the simple approximations of NIST SP 1065 (Riley 2008) Table 5,
    with N = samples + 1 phase points:

    * alpha = +2 (white phase):       (N + 1)(N - 2m) / (2 (N - m))
    * alpha = 0 (white):              (3 (N - 1) / (2m) - 2 (N - 2) / N) 4m^2 / (4m^2 + 5)
    * alpha = -1 (flicker):           2 (N - 2)^2 / (2.3 N - 4.9) at m = 1,
                                      5 N^2 / (4m (N + 3m)) beyond
    * alpha = -2 (random walk):       (N - 2) / (m (N - 3)^2) ((N - 1)^2 - 3m (N - 1) + 4m^2)

    Greenhall's exact algorithm (allantools.ci.edf_greenhall) differs from them by up to
    16 % for m >= 2 and a third for a random walk at m = 1, which changes an interval's
    width by up to 8 % (15 %). (allantools' edf_simple has 2 (N - 2) / (2.3 N - 4.9) for
    flicker at m = 1, which stays below 1 however long the record; Greenhall's algorithm
    gives 0.9 N there, as the squared numerator does.)
    """
    n, mf = float(samples + 1), float(m)
    if alpha == 2:
        return (n + 1) * (n - 2 * mf) / (2 * (n - mf))
    if alpha == 0:
        return (3 * (n - 1) / (2 * mf) - 2 * (n - 2) / n) * 4 * mf**2 / (4 * mf**2 + 5)
    if alpha == -1:
        return 2 * (n - 2) ** 2 / (2.3 * n - 4.9) if mf == 1 else 5 * n**2 / (4 * mf * (n + 3 * mf))
    if alpha == -2:
        return (n - 2) / (mf * (n - 3) ** 2) * ((n - 1) ** 2 - 3 * mf * (n - 1) + 4 * mf**2)
    raise ValueError(f"alpha must be 2, 0, -1 or -2, not {alpha!r}")


def slopes(tau_s: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """Log-log slope of each segment between consecutive points, (K-1,) or (K-1, axes)."""
    ratio = np.log(tau_s[1:] / tau_s[:-1])
    return np.log(adev[1:] / adev[:-1]) / (ratio if adev.ndim == 1 else ratio[:, None])


def local_slopes(tau_s: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """Log-log slope of the curve at each point, (K,) or (K, axes): across the octave on
    either side (half as noisy as one octave), across the one octave at the ends."""
    seg = slopes(tau_s, adev)
    return np.concatenate([seg[:1], (seg[:-1] + seg[1:]) / 2, seg[-1:]])


@dataclass
class AllanCurve:
    """Overlapping Allan deviation of the axes of one sensor.

    tau_s: (K,) averaging times, s. adev: (K, A) deviation in the signal's unit.
    low, high: (K, A) its interval at `confidence`. edf: (K,) equivalent degrees of
    freedom of each point. rate_hz: sample rate, Hz; samples: record length.
    """

    tau_s: np.ndarray
    adev: np.ndarray
    low: np.ndarray
    high: np.ndarray
    edf: np.ndarray
    rate_hz: float
    samples: int
    confidence: float


def allan_curve(data: np.ndarray, rate_hz: float, confidence: float = CONFIDENCE,
                progress: CountProgress | None = None) -> AllanCurve:
    """ADEV of every column of `data` ((N,) or (N, A)) with chi-square intervals
    (:func:`interval`).

    The EDF of a point is the smallest of :func:`edf` for white, flicker
    and random-walk noise, the three a sensor's curve is made of, instead of the EDF of
    a noise type identified from the curve: an identification from the local slope
    trusts the very estimate whose uncertainty it sets (a low stretch of a random walk
    looks flat, is taken for flicker and gets too narrow an interval). The cost: the
    intervals of a white-noise stretch are up to 22 % (short tau) to 45 % (longest tau)
    wider than they need be, never narrower.

    AllanError when there are fewer than MIN_SAMPLES samples or a column is constant.
    """
    data = np.asarray(data, dtype=np.float64)
    data = data[:, None] if data.ndim == 1 else data
    n, axes = data.shape
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie between 0 and 1, not {confidence!r}")
    sizes = cluster_sizes(n)
    if len(sizes) < MIN_POINTS:
        raise AllanError(f"{n} samples are too few: an Allan analysis needs at least {MIN_SAMPLES} "
                         f"({MIN_POINTS} averaging times of {MIN_CLUSTERS} clusters each)")
    adev = np.empty((len(sizes), axes))
    for a in range(axes):
        step = None if progress is None else (lambda done, total, a=a: progress(a * total + done, axes * total))
        tau, adev[:, a] = overlapping_adev(data[:, a], rate_hz, sizes, step)
    if not np.all(adev > 0.0):
        raise AllanError("a signal is constant (or quantised to one value): there is no noise to analyse")
    dof = np.array([min(edf(n, m, alpha) for alpha in (0, -1, -2)) for m in sizes])
    low, high = interval(adev, dof[:, None], confidence)
    return AllanCurve(tau, adev, low, high, dof, float(rate_hz), n, confidence)


def interval(adev: np.ndarray, dof: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square interval of deviations with `dof` degrees of freedom (NIST SP 1065 eq. 45):
    sigma^2 dof / chi2(1 - p, dof) <= true sigma^2 <= sigma^2 dof / chi2(p, dof),
    p = (1 - confidence) / 2."""
    p = (1.0 - confidence) / 2.0
    return adev * np.sqrt(dof / chi2.ppf(1.0 - p, dof)), adev * np.sqrt(dof / chi2.ppf(p, dof))


# ---------------------------------------------------------------------------- the noise terms


@dataclass
class NoiseTerm:
    """One noise term of one axis, in the curve's SI unit.

    value: the reading, or None when the curve does not show the term (`reason` says
    why). low, high: its interval at the curve's confidence. tau_s: (first, last)
    averaging time of the points it was read from.
    """

    value: float | None
    low: float | None = None
    high: float | None = None
    tau_s: tuple[float, float] | None = None
    reason: str = ""

    @property
    def uncertainty(self) -> float | None:
        """Half the width of the interval (about one standard deviation at 68.3 %)."""
        if self.value is None:
            return None
        assert self.low is not None and self.high is not None  # a reading comes with its interval
        return (self.high - self.low) / 2.0


def _slope_kind(slope: float) -> str:
    """The term a point of the curve belongs to: the one whose slope is nearest its own."""
    if -0.75 < slope <= -0.25:
        return "white"
    if -0.25 < slope < 0.25:
        return "flat"
    if 0.25 <= slope < 0.75:
        return "random walk"
    return "other"  # -1 (a sensor's low-pass, quantisation) or +1 (a drift, a temperature ramp)


def _longest_run(flags) -> list[int]:
    """Indices of the longest run of consecutive True values (the earliest of equals)."""
    best: list[int] = []
    run: list[int] = []
    for i, flag in enumerate(flags):
        run = run + [i] if flag else []
        if len(run) > len(best):
            best = run
    return best


def _line_reading(points: list[int], curve: AllanCurve, axis: int, slope: float, tau_read_s: float,
                  by_edf: bool) -> NoiseTerm:
    """Fit the line sigma(tau) = V (tau / tau_read_s)^slope, its slope fixed, to `points`
    and read V: the mean of log(sigma_i (tau_read_s / tau_i)^slope), weighted by the
    points' EDF (`by_edf`: the inverse variances of log sigma_i) or not (each octave
    counts the same).

    The interval combines in quadrature, in log:
    - statistics: the relative interval of the most precise point used (neighbouring
      points of an overlapping ADEV share most of their data: averaging them as if
      independent would overstate the precision);
    - model: the (weighted) RMS scatter of the points about the line, where another term
      or a sensor's low-pass bends the curve away from the slope.
    """
    sigma, low, high = (v[points, axis] for v in (curve.adev, curve.low, curve.high))
    dof, tau = curve.edf[points], curve.tau_s[points]
    logs = np.log(sigma * (tau_read_s / tau) ** slope)
    weights = dof if by_edf else None
    mean = float(np.average(logs, weights=weights))
    scatter = math.sqrt(float(np.average((logs - mean) ** 2, weights=weights)))
    best = int(np.argmax(dof))
    down, up = math.log(sigma[best] / low[best]), math.log(high[best] / sigma[best])
    value = math.exp(mean)
    return NoiseTerm(value, value * math.exp(-math.hypot(down, scatter)), value * math.exp(math.hypot(up, scatter)),
                     (float(tau[0]), float(tau[-1])))


def axis_terms(curve: AllanCurve, axis: int = 0) -> tuple[NoiseTerm, NoiseTerm, NoiseTerm]:
    """White noise (read at tau = 1 s), bias instability and random walk (read at tau =
    3 s) of one axis, in the curve's unit u: u sqrt(s), u, u / sqrt(s).

    Each point of the curve belongs to the term whose slope (-1/2, 0, +1/2) is nearest to
    its local slope (:func:`local_slopes`, :func:`_slope_kind`).

    * White noise: the longest run (at least two points) of -1/2 points, the earliest of
      equal runs, read by :func:`_line_reading` weighted by EDF: the short-tau end, where
      white noise dominates most, is also the most precise.
    * Bias instability: once the curve shows a floor, the level of its flat part / 0.664.
      A floor: the minimum is not the first point, and a later point lies above it beyond
      both intervals (the curve rises again), or the minimum lies above the white-noise
      line beyond its interval (the curve has left the -1/2 slope). Its flat part: the
      minimum and the neighbours whose one-sigma intervals reach down to the minimum's,
      each octave weighted the same (the minimum alone of noisy points is biased low; the
      precise short-tau end of the part still carries white noise). A curve still
      falling at its end only bounds the term, which the reason says.
    * Random walk: the +1/2 points after the minimum that lie above it beyond both
      intervals and at least RANDOM_WALK_OVER_FLOOR times as high, with m >=
      RANDOM_WALK_MIN_M, each octave weighted the same (its precise short-tau end is
      where the floor still adds).

    "Beyond the intervals" means those at DETECTION_CONFIDENCE, whatever the curve's own.
    """
    sigma = curve.adev[:, axis]
    low, high = interval(sigma, curve.edf, DETECTION_CONFIDENCE)  # for the decisions only
    tau = curve.tau_s
    kinds = [_slope_kind(s) for s in local_slopes(tau, sigma)]
    longest = f"{tau[-1]:.3g} s"

    run = _longest_run([k == "white" for k in kinds])
    if len(run) >= 2:
        white = _line_reading(run, curve, axis, -0.5, 1.0, by_edf=True)
    else:
        white = NoiseTerm(None, reason="the curve has no -1/2 slope")

    i_min = int(np.argmin(sigma))
    rises = bool(np.any(low[i_min + 1:] > high[i_min]))
    off_white = white.high is not None and low[i_min] > white.high / math.sqrt(tau[i_min])  # set with the value
    if i_min == 0:
        floor = NoiseTerm(None, reason=f"the curve rises from its shortest tau ({tau[0]:.3g} s): no floor")
    elif rises or off_white:
        # the flat part: the points whose one-sigma intervals reach down to the minimum's
        low1, high1 = interval(sigma, curve.edf, CONFIDENCE)
        flat = [i_min]
        while flat[0] > 0 and low1[flat[0] - 1] <= high1[i_min]:
            flat.insert(0, flat[0] - 1)
        while flat[-1] < len(tau) - 1 and low1[flat[-1] + 1] <= high1[i_min]:
            flat.append(flat[-1] + 1)
        level = _line_reading(flat, curve, axis, 0.0, 1.0, by_edf=False)
        assert level.value is not None and level.low is not None and level.high is not None  # a reading
        floor = NoiseTerm(level.value / FLOOR_OVER_BIAS_INSTABILITY, level.low / FLOOR_OVER_BIAS_INSTABILITY,
                          level.high / FLOOR_OVER_BIAS_INSTABILITY, level.tau_s)
    else:
        bound = sigma[i_min] / FLOOR_OVER_BIAS_INSTABILITY
        floor = NoiseTerm(None, reason=f"no floor up to the longest tau ({longest}): the curve neither rises again "
                                       f"nor leaves the -1/2 slope beyond its intervals; the bias instability is below "
                                       f"{bound:.3g}; record longer")

    points = [j for j in range(i_min + 1, len(tau))
              if kinds[j] == "random walk" and low[j] > high[i_min]
              and sigma[j] >= RANDOM_WALK_OVER_FLOOR * sigma[i_min]
              and round(tau[j] * curve.rate_hz) >= RANDOM_WALK_MIN_M]
    if points:
        walk = _line_reading(points, curve, axis, 0.5, RANDOM_WALK_TAU_S, by_edf=False)
    else:
        walk = NoiseTerm(None, reason=f"no +1/2 slope rises clearly above the floor up to the longest tau "
                                      f"({longest}); record longer")
    return white, floor, walk


# ---------------------------------------------------------------------------- inputs


@dataclass
class StaticRecord:
    """A static record in SI units: gyr (N,3) rad/s and acc (N,3) m/s^2 (either may be
    None when the input lacks it), evenly sampled at rate_hz."""

    description: str
    rate_hz: float
    gyr: np.ndarray | None
    acc: np.ndarray | None

    @property
    def samples(self) -> int:
        data = self.gyr if self.gyr is not None else self.acc
        assert data is not None  # load_static gives a record with one of them at least
        return len(data)

    @property
    def duration_s(self) -> float:
        return self.samples / self.rate_hz


def load_static(path, progress: CountProgress | None = None) -> StaticRecord:
    """A static record from `path` (see sensor_input.read): a BROAD trial's longest rest,
    a CSV, or a recording of `imulink record`. progress: see load_recording."""
    record = sensor_input.read(path, progress)
    if record.movement is not None or str(path).lower().endswith(".mat"):
        return _broad_rest(Path(path), record)
    if len(record) < MIN_SAMPLES:
        raise AllanError(f"{path} holds {len(record)} samples: an Allan analysis needs at least {MIN_SAMPLES}")
    if record.index is not None:
        return _from_recording(Path(path), record)
    try:
        rate = sensor_input.rate_from_timestamps(record.time_s, str(path))
    except InputError as exc:
        raise AllanError(str(exc)) from None
    if record.gyr is None and record.acc is None:
        raise AllanError(f"{path} has neither gyroscope nor accelerometer columns ({', '.join(CSV_COLUMNS['gyr'])}, "
                         f"{', '.join(CSV_COLUMNS['acc'])})")
    return StaticRecord(record.description, rate, record.gyr, record.acc)


def _from_recording(path: Path, record: SensorRecord) -> StaticRecord:
    """A recording's samples, unbroken.

    Unbroken means every sample index from the first to the last: the board counts every
    sensor read, so a sample lost on the board (a full link) or on the way is a missing
    index; a board's timestamps jitter with its main loop, its index does not. The rate
    is the timestamps' mean rate when it lies within RATE_TOLERANCE of the rate the board
    declares (a sensor's clock is off by a percent or so: the timestamps measure it);
    otherwise the declared one: an emulated board running faster than real time stamps
    its samples with the host's pace.
    """
    index = record.index
    assert index is not None  # load_static calls this for a recording, whose samples have one
    breaks = np.flatnonzero(np.diff(index) != 1)
    if len(breaks):
        k = int(breaks[0])
        raise AllanError(f"{path}: the samples are not one unbroken run: the sample index goes from "
                         f"{index[k]} to {index[k + 1]} after sample {k} ({len(breaks)} break(s): "
                         "samples lost or the filter restarted); an Allan analysis needs an unbroken record")
    time_s = record.time_s
    measured = (len(record) - 1) / time_s[-1] if time_s[-1] > 0 else math.inf
    declared = record.declared_rate_hz
    description = record.description
    if declared is None:
        try:
            rate = sensor_input.rate_from_timestamps(time_s, str(path))
        except InputError as exc:
            raise AllanError(str(exc)) from None
    elif abs(measured / declared - 1.0) <= RATE_TOLERANCE:
        rate = measured
    else:
        rate = declared
        description += (f", at the board's declared {declared:g} Hz (its timestamps run at {measured:.4g} Hz: "
                        "an emulated board faster than real time)")
    return StaticRecord(description, rate, record.gyr, record.acc)


def _broad_rest(path: Path, record: SensorRecord) -> StaticRecord:
    """A BROAD trial's longest rest (where movement is false), or the whole trial without a mask."""
    rate, gyr, acc = record.declared_rate_hz, record.gyr, record.acc
    assert rate is not None and gyr is not None and acc is not None  # a BROAD trial has them all
    start, stop, what = 0, len(record), "the whole trial (it has no movement mask)"
    if record.movement is not None:
        rests = sensor_input.still_segments(~record.movement)
        if not rests:
            raise AllanError(f"{path}: the trial never rests (movement is true throughout)")
        start, stop = max(rests, key=lambda r: r[1] - r[0])
        what = f"its longest rest, {start / rate:.1f}-{stop / rate:.1f} s"
    if stop - start < MIN_SAMPLES:
        raise AllanError(f"{path}: {what} holds {stop - start} samples: an Allan analysis needs at least "
                         f"{MIN_SAMPLES}")
    return StaticRecord(f"{record.description}, {what}", rate, gyr[start:stop], acc[start:stop])


# ---------------------------------------------------------------------------- the analysis


@dataclass
class SensorAnalysis:
    """The curve of one sensor ("gyro" or "acc") and its terms: name -> one per axis."""

    sensor: str
    curve: AllanCurve
    terms: dict[str, list[NoiseTerm]]


@dataclass
class AllanResult:
    description: str
    rate_hz: float
    samples: int
    sensors: dict[str, SensorAnalysis] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return self.samples / self.rate_hz


def analyse(record: StaticRecord, confidence: float = CONFIDENCE, progress: CountProgress | None = None) -> AllanResult:
    """The ADEV curve and the noise terms of each sensor of `record`. progress: called
    with (steps done, steps) as the averaging times are computed."""
    inputs = {k: v for k, v in (("gyro", record.gyr), ("acc", record.acc)) if v is not None}
    result = AllanResult(record.description, record.rate_hz, record.samples)
    for number, (sensor, data) in enumerate(inputs.items()):
        step = None if progress is None else (
            lambda done, total, number=number: progress(number * total + done, len(inputs) * total))
        curve = allan_curve(data, record.rate_hz, confidence, step)
        per_axis = [axis_terms(curve, a) for a in range(curve.adev.shape[1])]
        terms = {name: [t[i] for t in per_axis] for i, name in enumerate(TERMS[sensor])}
        result.sensors[sensor] = SensorAnalysis(sensor, curve, terms)
    return result


def terms_json(result: AllanResult) -> dict:
    """The terms in SI, per axis (x, y, z), keyed gyro_arw, gyro_bias_instability,
    gyro_rrw, acc_vrw, acc_bias_instability, acc_rrw; each with `_uncertainty` (half the
    interval), `_low`, `_high` and `_reason` (why a value is null) companions."""
    out: dict[str, list[float | str | None]] = {}
    for sensor, analysis in result.sensors.items():
        for name, terms in analysis.terms.items():
            key = f"{sensor}_{name}"
            out[key] = [t.value for t in terms]
            out[f"{key}_uncertainty"] = [t.uncertainty for t in terms]
            out[f"{key}_low"] = [t.low for t in terms]
            out[f"{key}_high"] = [t.high for t in terms]
            out[f"{key}_reason"] = [t.reason or None for t in terms]
    return out


def to_json(result: AllanResult) -> dict:
    """Everything in SI with self-explaining keys (see :func:`terms_json`), the curves as
    `tau_s` and `<sensor>_adev`, `_adev_low`, `_adev_high`: one [x, y, z] per tau."""
    first = next(iter(result.sensors.values()), None)
    out: dict[str, Any] = {"input": result.description, "sample_rate_hz": result.rate_hz, "samples": result.samples,
           "duration_s": result.duration_s, "confidence": first.curve.confidence if first else CONFIDENCE,
           "axes": list(AXES), "method": "overlapping Allan deviation, octave-spaced tau; terms read as IEEE Std "
           "952 does: -1/2 line at tau = 1 s, floor / 0.664, +1/2 line at tau = 3 s; uncertainty = half the "
           "interval at the stated confidence"}
    out.update(terms_json(result))
    if first is not None:
        out["tau_s"] = first.curve.tau_s.tolist()
        out["edf"] = first.curve.edf.tolist()
    for sensor, analysis in result.sensors.items():
        c = analysis.curve
        out[f"{sensor}_adev"], out[f"{sensor}_adev_low"], out[f"{sensor}_adev_high"] = (
            c.adev.tolist(), c.low.tolist(), c.high.tolist())
    out["units"] = {f"{sensor}_{name}": unit for sensor in result.sensors for name, unit in UNITS[sensor].items()}
    out["units"].update({"tau_s": "s", "sample_rate_hz": "Hz", "duration_s": "s"})
    return out


# ---------------------------------------------------------------------------- the report


def _display(sensor: str, name: str, value: float) -> str:
    """A term in the unit data sheets use, beside SI."""
    if sensor == "gyro":
        if name == "arw":
            return f"{value * _DEG * 60.0:.4g} deg/sqrt(h)"
        if name == "bias_instability":
            return f"{value * _DEG * 3600.0:.4g} deg/h"
        return f"{value * _DEG * 3600.0 * 60.0:.4g} deg/h/sqrt(h)"
    unit = {"vrw": "ug/sqrt(Hz)", "bias_instability": "ug", "rrw": "ug/sqrt(s)"}[name]
    return f"{value * _MICRO_G:.4g} {unit}"


def format_report(result: AllanResult) -> str:
    """The curves and the terms as text."""
    lines = [f"input: {result.description}: {result.samples} samples at {result.rate_hz:.6g} Hz "
             f"({result.duration_s:.1f} s)"]
    for sensor, analysis in result.sensors.items():
        c = analysis.curve
        unit, other = ("rad/s", "deg/h") if sensor == "gyro" else ("m/s^2", "ug")
        scale = _DEG * 3600.0 if sensor == "gyro" else _MICRO_G
        lines += ["", f"{'gyroscope' if sensor == 'gyro' else 'accelerometer'} Allan deviation per axis, in "
                      f"{unit} and {other}, +- half its interval at {c.confidence * 100:.1f} %",
                  f"{'tau s':>9}" + "".join(f"  {axis + ' ' + unit:>11} {other:>8} {'+-':>6}" for axis in AXES)]
        for i, tau in enumerate(c.tau_s):
            cells = []
            for a in range(c.adev.shape[1]):
                spread = (c.high[i, a] - c.low[i, a]) / 2.0 / c.adev[i, a] * 100.0
                cells.append(f"  {c.adev[i, a]:11.4e} {c.adev[i, a] * scale:8.4g} {spread:5.1f}%")
            lines.append(f"{tau:9.4g}" + "".join(cells))
        lines += ["", "noise terms (value +- uncertainty; averaging times read):"]
        for name, terms in analysis.terms.items():
            lines.append(f"  {TERM_NAMES[name]}, {UNITS[sensor][name]}:")
            for axis, t in zip(AXES, terms):
                if t.value is None:
                    lines.append(f"    {axis}: not identified: {t.reason}")
                else:
                    uncertainty, tau_s = t.uncertainty, t.tau_s
                    assert uncertainty is not None and tau_s is not None  # a reading comes with them
                    lines.append(f"    {axis}: {t.value:.4g} +- {uncertainty / t.value * 100:.1f} % "
                                 f"= {_display(sensor, name, t.value)}   ({tau_s[0]:.3g}-{tau_s[1]:.3g} s)")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- filter settings


#: The filters whose settings follow from noise terms.
DERIVABLE_FILTERS = ("eskf", "kf1d")


def setting_range(filter_name: str, name: str) -> tuple[float, float]:
    """The range the C core accepts for a setting (its descriptor table), in the setting's unit:
    the float twin's ends, the exact reals (the fixed build's are those rounded to its Q format)."""
    field = next(f for f in core.settings_fields(filter_name, "float") if f.name == name)
    return field.minimum, field.maximum


@dataclass
class DerivedSettings:
    """Settings in SI (name -> value) and what to know about them, one line each."""

    values: dict[str, float]
    notes: list[str]


def _largest(terms: Mapping[str, Any], key: str) -> float | None:
    values = [v for v in terms.get(key) or () if v is not None]
    return max(values) if values else None


#: The sensor terms of the recordings the filters' default settings were tuned on: BROAD's
#: longest rest (02_undisturbed_slow_rotation_B, docs/calibration.md), its noisiest axis.
#: Gyroscope angle random walk, rad/s^0.5 (0.396 deg/sqrt(h)); the specific-force noise of
#: one ESKF step at BROAD's 285.7 Hz, m/s^2 (velocity random walk 0.00412 m/s^2/sqrt(Hz)
#: times sqrt(285.7 / 3)).
TUNED_ON_GYRO_ARW = math.radians(0.396) / 60.0
TUNED_ON_ACC_NOISE = 0.00412 * math.sqrt(285.7 / 3.0)


def motion_allowance(filter_name: str) -> dict[str, float]:
    """What a filter's noise settings allow for beyond the sensor's own noise, as variances
    (the settings' units squared): the default less the sensor term of the recordings it was
    tuned on. On a moving board the gyroscope's unmodelled errors (scale factor,
    misalignment, g-sensitivity) add to its white noise, and the board's own accelerations
    to the accelerometer's in the gravity measurement; the defaults carry them, eight
    (gyroscope) and seven (accelerometer) times the tuned-on sensor's noise."""
    defaults = core.default_settings(filter_name)
    if filter_name == "eskf":
        return {"gyro_arw": defaults["gyro_arw"] ** 2 - TUNED_ON_GYRO_ARW**2,
                "acc_noise": defaults["acc_noise"] ** 2 - TUNED_ON_ACC_NOISE**2}
    return {"q_angle": defaults["q_angle"] - TUNED_ON_GYRO_ARW**2}


def derive_settings(terms: Mapping[str, Any], filter_name: str,
                    sensor_only: bool = False) -> DerivedSettings:
    """The settings of `filter_name` that the noise terms determine, clamped to their
    ranges (see :func:`settings_from_terms`), and notes on each choice.

    The white-noise settings (ESKF gyro_arw and acc_noise, KF1D q_angle) add the
    :func:`motion_allowance` to the sensor's term in variance, so that a sensor as quiet as
    the one the defaults were tuned on gets the defaults back; `sensor_only` leaves it out
    (the sensor's terms alone: a board that barely moves)."""
    if filter_name not in DERIVABLE_FILTERS:
        raise AllanError(f"no setting of {filter_name!r} follows from noise terms; choose from "
                         f"{', '.join(DERIVABLE_FILTERS)}")
    gyro_arw, gyro_rrw = _largest(terms, "gyro_arw"), _largest(terms, "gyro_rrw")
    acc_vrw, acc_rrw = _largest(terms, "acc_vrw"), _largest(terms, "acc_rrw")
    rate_hz = terms.get("sample_rate_hz")
    allowance = motion_allowance(filter_name)
    if sensor_only:
        allowance = dict.fromkeys(allowance, 0.0)
    wanted: dict[str, float | None] = {}
    notes = ["each value is the largest of the three axes: the filter has one per sensor, and one that assumes "
             "too little noise trusts its model too much"]
    if sensor_only:
        notes.append("the sensor's noise alone (--sensor-only): on a moving board these settings trust the "
                     "gyroscope and the gravity measurement too much")
    else:
        notes.append("the white-noise settings add to the sensor's term what a moving board adds (the "
                     "gyroscope's scale, misalignment and g-sensitivity errors, the board's own accelerations): "
                     "the allowance the defaults carry beyond the sensor they were tuned on (--sensor-only: "
                     "without it)")
    if filter_name == "eskf":
        # The ESKF's process noise is Q = diag(gyro_arw^2, gyro_rrw^2, acc_bias_rw^2) T (imu_eskf.h): the
        # Allan terms, in rad/s^0.5 (= rad/s/sqrt(Hz)), rad/s^1.5 and m/s^2.5.
        wanted["gyro_arw"] = None if gyro_arw is None else math.sqrt(gyro_arw**2 + allowance["gyro_arw"])
        wanted["gyro_rrw"], wanted["acc_bias_rw"] = gyro_rrw, acc_rrw
        # acc_noise is the standard deviation of one filter step's specific force: the mean of three
        # samples, T = 3 / rate, so vrw / sqrt(T), as the ESKF takes arw^2 / T for its rest measurement.
        if acc_vrw is not None and rate_hz:
            wanted["acc_noise"] = math.sqrt(acc_vrw**2 * rate_hz / 3.0 + allowance["acc_noise"])
            notes.append(f"acc_noise counts the sensor's noise over one filter step (3 samples at {rate_hz:.6g} Hz)")
        else:
            wanted["acc_noise"] = None
        notes.append("bias instability has no ESKF setting (the filter models the bias as a random walk)")
    else:
        # KF1D: P = A P A^T + Q dt with Q = diag(q_angle, q_bias) (imu_kf1d.h): the variance densities,
        # rad^2/s = arw^2 and rad^2/s^3 = rrw^2.
        wanted["q_angle"] = None if gyro_arw is None else gyro_arw**2 + allowance["q_angle"]
        wanted["q_bias"] = None if gyro_rrw is None else gyro_rrw**2
    values = {}
    for name, value in wanted.items():
        if value is None:
            notes.append(f"{name} is left at its default: its term was not identified")
            continue
        low, high = setting_range(filter_name, name)
        if not low <= value <= high:
            clamped = min(max(value, low), high)
            notes.append(f"{name} = {value:.4g} lies outside the filter's range [{low:g}, {high:g}]: "
                         f"clamped to {clamped:g}")
            value = clamped
        values[name] = value
    return DerivedSettings(values, notes)


def settings_from_terms(terms: Mapping[str, Any], filter_name: str,
                        sensor_only: bool = False) -> dict[str, float]:
    """The settings of `filter_name` ("eskf" or "kf1d") that noise terms determine, in SI.

    terms: as :func:`terms_json` gives them (gyro_arw, gyro_rrw, acc_vrw, acc_rrw: [x, y, z],
    None where a term was not identified) plus sample_rate_hz. A setting whose term is
    missing is left out (the filter keeps its default); one outside its range
    (:func:`setting_range`) is clamped to it. :func:`derive_settings` also says why.
    """
    return derive_settings(terms, filter_name, sensor_only).values


# ---------------------------------------------------------------------------- the plot


#: [seed 000]'s Table 1 (docs/filters.md, Bibliography; its three MEMS gyros): ARW deg/sqrt(h), bias stability deg/h,
#: RRW deg/h/sqrt(h), drawn for comparison with a gyroscope's curve.
SEED000_TABLE1 = {"arw": (3.3197, 2.6794, 2.885), "bias_instability": (39.8887, 36.4465, 34.5215),
                  "rrw": (520.5, 598.05, 471.84)}


def plot(result: AllanResult, path, reference: bool = True) -> None:
    """Draw the curves of `result` to `path` (.png or .svg), log-log, one panel per sensor:
    each axis with its intervals as error bars, the fitted -1/2 and +1/2 lines and the
    bias-instability floor (0.664 B) where identified, and (`reference`) [seed 000]'s Table 1
    for the gyroscope (the mean of its three gyros, grey). Gyroscope in deg/h,
    accelerometer in m/s^2."""
    fmt = plot_format(path)
    check_plotting()
    from matplotlib.figure import Figure  # without pyplot: no display, no global backend

    panels = list(result.sensors.values())
    fig = Figure(figsize=(8.0, 4.2 * len(panels)), layout="constrained")
    colours = ("tab:red", "tab:green", "tab:blue")
    for row, analysis in enumerate(panels):
        ax = fig.add_subplot(len(panels), 1, row + 1)
        c = analysis.curve
        gyro = analysis.sensor == "gyro"
        scale = _DEG * 3600.0 if gyro else 1.0
        tau = c.tau_s
        span = np.array([tau[0], tau[-1]])
        for a, axis in enumerate(AXES[:c.adev.shape[1]]):
            y = c.adev[:, a] * scale
            ax.errorbar(tau, y, yerr=[y - c.low[:, a] * scale, c.high[:, a] * scale - y], fmt="o-", ms=3,
                        color=colours[a], lw=1.2, capsize=2, label=axis)
            white, floor, walk = (analysis.terms[name][a] for name in TERMS[analysis.sensor])
            if white.value is not None:
                assert white.tau_s is not None  # a reading comes with its averaging times
                t = np.array([tau[0], min(tau[-1], white.tau_s[1] * 8)])
                ax.plot(t, white.value * scale / np.sqrt(t), "--", color=colours[a], lw=0.8)
            if floor.value is not None:
                assert floor.tau_s is not None
                t = np.array([floor.tau_s[0] / 4, floor.tau_s[1] * 4]).clip(*span)
                ax.plot(t, [floor.value * FLOOR_OVER_BIAS_INSTABILITY * scale] * 2, ":", color=colours[a], lw=1.2)
            if walk.value is not None:
                assert walk.tau_s is not None
                t = np.array([max(tau[0], walk.tau_s[0] / 8), tau[-1]])
                ax.plot(t, walk.value * scale * np.sqrt(t / RANDOM_WALK_TAU_S), "-.", color=colours[a], lw=0.8)
        if gyro and reference:
            n, b, k = (np.mean(SEED000_TABLE1[name]) for name in ("arw", "bias_instability", "rrw"))
            t = np.geomspace(span[0], span[1], 50)
            # deg/sqrt(h) -> deg/h at tau s: N / sqrt(tau / 3600 h); K (deg/h/sqrt(h)) sqrt(tau / 3 / 3600)
            ax.plot(t, n * 60.0 / np.sqrt(t), "-", color="0.6", lw=2, alpha=0.5,
                    label="seed 000 Table 1 (mean of 3 gyros)")
            ax.plot(span, [b * FLOOR_OVER_BIAS_INSTABILITY] * 2, "-", color="0.6", lw=2, alpha=0.5)
            ax.plot(t, k * np.sqrt(t / RANDOM_WALK_TAU_S / 3600.0), "-", color="0.6", lw=2, alpha=0.5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("averaging time tau (s)")
        ax.set_ylabel("Allan deviation (deg/h)" if gyro else "Allan deviation (m/s$^2$)")
        ax.set_title(f"{'gyroscope' if gyro else 'accelerometer'}: dashed -1/2 line (white noise), dotted floor "
                     "(0.664 B), dash-dot +1/2 line", fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=8)
    fig.suptitle(textwrap.fill(f"{result.description}: {result.samples} samples at {result.rate_hz:.6g} Hz, "
                               f"intervals at {panels[0].curve.confidence * 100:.1f} %", 110), fontsize=9)
    fig.savefig(path, format=fmt, dpi=110)
