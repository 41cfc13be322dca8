"""Truth motion for the simulator.

A :class:`Trajectory` holds sampled truth: attitude, body angular rate, earth-frame
linear acceleration and a rest mask.  The truth attitude is, by construction, the
exact integral of the sampled body rate: gyro sample ``k`` is the constant body rate
over ``(t_k-1, t_k]`` (the interval that ends at its time stamp, as a sensor's
output data reports the motion since the previous sample) and

    quat[k] = quat[k-1] ⊗ exp(gyr[k] * dt / 2)

(quaternion exponential of the rotation vector ``gyr[k] * dt``), so an estimator fed
with error-free gyro samples can reproduce the truth to rounding error, and one that
integrates sample k and then corrects with the accelerometer and magnetometer of
sample k estimates the attitude at t_k (the convention of the BROAD dataset).

Conventions: quaternions w-first, sensor(body)-to-earth, earth frame ENU.
All constructors are deterministic for a given ``seed`` (``numpy.random.default_rng``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imulink.errors import ImulinkError
from imulink.sim import quat as Q

__all__ = [
    "Trajectory",
    "DEFAULT_INITIAL",
    "integrate_gyro",
    "static",
    "turntable",
    "random_motion",
    "motion_with_rests",
    "TRANSLATIONS",
]

#: Default initial attitude: roll 3 deg, pitch -2 deg, yaw 30 deg (see :func:`quat.from_zyx`).
DEFAULT_INITIAL = Q.from_zyx(np.deg2rad(3.0), np.deg2rad(-2.0), np.deg2rad(30.0))

#: Duration (s) of the smooth raised-cosine transitions between rest and motion.
RAMP_S = 0.5


@dataclass
class Trajectory:
    """Sampled truth motion.

    Attributes:
        rate_hz: sample rate in Hz (``dt = 1 / rate_hz``).
        t: (N,) sample times in s, ``t[k] = k / rate_hz``.
        quat: (N,4) truth attitude, w-first, sensor-to-earth (ENU).
        gyr: (N,3) true body angular rate in rad/s (body relative to earth, in the
            body frame); constant over ``[t_k, t_k+1)``.
        acc_lin: (N,3) linear acceleration in the EARTH frame, m/s^2, gravity excluded.
        rest: (N,) bool, True where the body is at rest (zero rate and acceleration).
    """

    rate_hz: float
    t: np.ndarray
    quat: np.ndarray
    gyr: np.ndarray
    acc_lin: np.ndarray
    rest: np.ndarray

    @property
    def dt(self) -> float:
        """Sample period in s."""
        return 1.0 / self.rate_hz

    @property
    def duration_s(self) -> float:
        """Covered time in s (``N * dt``)."""
        return len(self.t) / self.rate_hz

    def __len__(self) -> int:
        return len(self.t)


def integrate_gyro(q0, gyr, dt: float) -> np.ndarray:
    """Exact attitude for piecewise-constant body rates.

    Args:
        q0: (4,) attitude at ``t_0`` (w-first, sensor-to-earth).
        gyr: (N,3) body rates in rad/s; sample ``k`` holds over ``(t_k - dt, t_k]``.
        dt: sample period in s.

    Returns:
        (N,4) attitudes at ``t_0 .. t_{N-1}``: ``q[0] = q0`` and
        ``q[k] = q[k-1] ⊗ exp(gyr[k] dt / 2)`` (the first rate sample is the motion
        before ``t_0`` and is not needed).
    """
    gyr = np.asarray(gyr, dtype=np.float64)
    n = gyr.shape[0]
    steps = np.empty((n, 4))
    steps[0] = Q.normalize(q0)
    steps[1:] = Q.from_rotvec(gyr[1:] * dt)
    return Q.cumulative_product(steps)


#: Most samples a trajectory may have: an hour at 5 kHz, the fastest rate the
#: filters are checked at (tools/agreement.py). A simulation holds some 450 bytes
#: per sample (8 GB at this size).
MAX_SAMPLES = 18_000_000


class ScenarioError(ImulinkError, ValueError):
    """Simulation arguments no trajectory can be made of (the message says which)."""


def _n_samples(duration_s: float, rate_hz: float) -> int:
    if not (0 < duration_s < math.inf and 0 < rate_hz < math.inf):
        raise ScenarioError(f"duration {duration_s!r} s and rate {rate_hz!r} Hz must be positive finite numbers")
    n = duration_s * rate_hz
    if not 2 <= round(n) <= MAX_SAMPLES:
        raise ScenarioError(f"{duration_s:g} s at {rate_hz:g} Hz is {n:.4g} samples; a trajectory needs from 2 "
                            f"to {MAX_SAMPLES} samples")
    return int(round(n))


def _initial(initial) -> np.ndarray:
    return DEFAULT_INITIAL.copy() if initial is None else Q.normalize(initial)


def _lowpass_noise(rng: np.random.Generator, n: int, dt: float, bandwidth_hz: float,
                   std: float, order: int = 4) -> np.ndarray:
    """(n,3) smooth zero-mean Gaussian noise with per-axis standard deviation ``std``.

    White noise is filtered in the frequency domain with a zero-phase Butterworth
    magnitude response ``1/sqrt(1 + (f/bandwidth_hz)^(2 order))`` (circular, so the
    signal is periodic over the record).  The scaling uses the filter's exact noise
    gain, so ``std`` is the expected (not the sample) standard deviation.
    """
    white = rng.standard_normal((n, 3))
    gain = 1.0 / np.sqrt(1.0 + (np.abs(np.fft.fftfreq(n, dt)) / bandwidth_hz) ** (2 * order))
    h = gain[: n // 2 + 1]
    y = np.fft.irfft(np.fft.rfft(white, axis=0) * h[:, None], n=n, axis=0)
    # Circular filtering of unit white noise: var(y_k) = mean(|H_k|^2) (Parseval).
    return y * (std / np.sqrt(np.mean(gain**2)))


#: How the linear acceleration is made (:func:`random_motion`, :func:`motion_with_rests`).
TRANSLATIONS = ("sustained", "bounded")


def _bounded_acceleration(white: np.ndarray, dt: float, bandwidth_hz: float, accel_std: float,
                          envelope: np.ndarray | None = None) -> np.ndarray:
    """(n,3) linear acceleration of a position that stays within reach: the second derivative
    of band-limited position noise (4th-order shape as :func:`_lowpass_noise`), times
    ``envelope`` when given (the board leaves its rest spot and comes back to it). The
    position is scaled so that its acceleration has the per-axis std ``accel_std``
    (before the envelope). Its spectrum vanishes at 0 Hz as f^4: a hand, an arm, a shaken
    board cannot accelerate one way for long."""
    n = len(white)
    freq = np.abs(np.fft.fftfreq(n, dt))
    gain = 1.0 / np.sqrt(1.0 + (freq / bandwidth_hz) ** 8)
    to_acceleration = (2.0 * np.pi * freq) ** 2 * gain
    position = np.fft.irfft(np.fft.rfft(white, axis=0) * gain[: n // 2 + 1, None], n=n, axis=0)
    # Circular filtering of unit white noise: var of the acceleration = mean(|H_acc|^2).
    position *= accel_std / np.sqrt(np.mean(to_acceleration**2))
    if envelope is None:  # (the position is periodic over the record)
        return (np.roll(position, -1, axis=0) - 2.0 * position + np.roll(position, 1, axis=0)) / dt**2
    # Second differences, so that the acceleration sums back to the position exactly: a move
    # starts and ends with a finite acceleration (the envelope's ramps), one sample into its rests.
    acceleration = np.zeros_like(position)
    acceleration[1:-1] = np.diff(position * envelope[:, None], n=2, axis=0) / dt**2
    return acceleration


def _random_rates_and_acc(rng, n, dt, max_rate_dps, bandwidth_hz, accel_std, translation="sustained",
                          envelope=None):
    """Band-limited body rate (rad/s, soft-limited) and earth-frame acceleration (m/s^2),
    both times ``envelope`` when given; the translation as :func:`random_motion` says."""
    if translation not in TRANSLATIONS:
        raise ValueError(f"unknown translation {translation!r}; expected one of {TRANSLATIONS}")
    w_max = np.deg2rad(max_rate_dps)
    w = _lowpass_noise(rng, n, dt, bandwidth_hz, w_max / 3.0)
    # Soft limit on the rate magnitude: |w| -> w_max tanh(|w| / w_max).
    mag = np.linalg.norm(w, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(mag > 0, w_max * np.tanh(mag / w_max) / mag, 1.0)
    w = w * scale
    if translation == "bounded":
        a = _bounded_acceleration(rng.standard_normal((n, 3)), dt, bandwidth_hz, accel_std, envelope)
    else:
        a = _lowpass_noise(rng, n, dt, bandwidth_hz, accel_std)
        if envelope is not None:
            a = a * envelope[:, None]
    if envelope is not None:
        w = w * envelope[:, None]
    return w, a


def static(duration_s: float, rate_hz: float, initial=None) -> Trajectory:
    """No motion.

    Args:
        duration_s: length in s.
        rate_hz: sample rate in Hz.
        initial: (4,) attitude quaternion (w-first, sensor-to-earth); default
            :data:`DEFAULT_INITIAL` (roll 3 deg, pitch -2 deg, yaw 30 deg).
    """
    n = _n_samples(duration_s, rate_hz)
    q0 = _initial(initial)
    return Trajectory(
        rate_hz=float(rate_hz),
        t=np.arange(n) / rate_hz,
        quat=np.tile(q0, (n, 1)),
        gyr=np.zeros((n, 3)),
        acc_lin=np.zeros((n, 3)),
        rest=np.ones(n, dtype=bool),
    )


def turntable(duration_s: float, rate_hz: float, rate_dps: float = 10.0, initial=None,
              settle_s: float = 10.0) -> Trajectory:
    """At rest for ``settle_s``, then constant rotation about the EARTH vertical axis.

    Args:
        duration_s: length in s.
        rate_hz: sample rate in Hz.
        rate_dps: turntable rate in deg/s (positive = counter-clockwise seen from above).
        initial: (4,) initial attitude; default :data:`DEFAULT_INITIAL`.
        settle_s: initial rest period in s (``rest`` is True there).

    The body rate ``R^T [0, 0, omega]`` is constant in the body frame (rotation about
    a fixed earth axis), so the truth is ``q(t) = exp(omega (t - settle) ez) ⊗ q0``.
    """
    n = _n_samples(duration_s, rate_hz)
    q0 = _initial(initial)
    t = np.arange(n) / rate_hz
    moving = t >= settle_s
    body_rate = Q.rotate_inverse(q0, np.array([0.0, 0.0, np.deg2rad(rate_dps)]))
    gyr = np.where(moving[:, None], body_rate, 0.0)
    return Trajectory(
        rate_hz=float(rate_hz),
        t=t,
        quat=integrate_gyro(q0, gyr, 1.0 / rate_hz),
        gyr=gyr,
        acc_lin=np.zeros((n, 3)),
        rest=~moving,
    )


def random_motion(duration_s: float, rate_hz: float, seed: int = 0, max_rate_dps: float = 200.0,
                  bandwidth_hz: float = 1.0, accel_std: float = 1.0, initial=None,
                  translation: str = "sustained") -> Trajectory:
    """Smooth random rotation and linear acceleration.

    Args:
        duration_s: length in s.
        rate_hz: sample rate in Hz.
        seed: random seed (``numpy.random.default_rng(seed)``).
        max_rate_dps: soft limit on the body-rate magnitude in deg/s.  Each body axis
            is band-limited Gaussian noise of std ``max_rate_dps / 3`` and the rate
            vector magnitude is compressed with ``max * tanh(|w| / max)``.
        bandwidth_hz: corner frequency in Hz of the 4th-order (zero-phase) low-pass
            shaping both the rate and the acceleration.
        accel_std: per-axis standard deviation in m/s^2 of the zero-mean, band-limited
            linear acceleration (earth frame).
        initial: (4,) initial attitude; default :data:`DEFAULT_INITIAL`.
        translation: ``"sustained"``: the acceleration itself is band-limited noise, flat
            down to 0 Hz, so the velocity wanders without bound (a vehicle that speeds up,
            brakes and turns for seconds); ``"bounded"``: it is the second derivative of a
            band-limited position, so it averages out within seconds (a hand, a shaken or
            carried board: a 3 s low-pass keeps 1-10 % of BROAD's horizontal linear
            acceleration however hard a trial moves, 5-8 % of this model's and a quarter
            of the sustained one's; tools/eval_translation.py, docs/accuracy.md).
    """
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    gyr, acc = _random_rates_and_acc(rng, n, dt, max_rate_dps, bandwidth_hz, accel_std, translation)
    q0 = _initial(initial)
    return Trajectory(
        rate_hz=float(rate_hz),
        t=np.arange(n) * dt,
        quat=integrate_gyro(q0, gyr, dt),
        gyr=gyr,
        acc_lin=acc,
        rest=np.zeros(n, dtype=bool),
    )


def motion_with_rests(duration_s: float, rate_hz: float, seed: int = 0, move_s=(5.0, 20.0),
                      rest_s=(2.0, 10.0), **random_motion_kwargs) -> Trajectory:
    """Alternating rest and random-motion segments, starting with a rest.

    Args:
        duration_s: length in s.
        rate_hz: sample rate in Hz.
        seed: random seed (segment lengths and motion).
        move_s: (min, max) length in s of a motion segment (uniformly drawn).
        rest_s: (min, max) length in s of a rest segment (uniformly drawn).
        **random_motion_kwargs: ``max_rate_dps``, ``bandwidth_hz``, ``accel_std``,
            ``initial``, ``translation`` as in :func:`random_motion` (bounded: the board
            comes back to its rest spot after each move).

    The random rate and acceleration are multiplied by an envelope that rises and
    falls with 0.5 s raised-cosine ramps inside each motion segment, so both are
    exactly zero during rests (``rest`` is True where the envelope and the acceleration
    are 0: a bounded move's acceleration reaches one sample beyond its envelope).  With the
    sustained translation only the acceleration is simulated (no velocity or position),
    so a rest needs no braking; with the bounded one the envelope multiplies the position.
    """
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    kw = dict(max_rate_dps=200.0, bandwidth_hz=1.0, accel_std=1.0, initial=None, translation="sustained")
    unknown = set(random_motion_kwargs) - set(kw)
    if unknown:
        raise TypeError(f"unexpected arguments: {sorted(unknown)}")
    kw.update(random_motion_kwargs)

    envelope = np.zeros(n)
    start = rng.uniform(*rest_s)
    total = n * dt
    while start < total:
        length = rng.uniform(*move_s)
        end = start + length
        ramp = min(RAMP_S, 0.5 * length)
        sel = slice(int(np.ceil(start * rate_hz)), min(n, int(np.ceil(end * rate_hz))))
        x = np.clip(np.minimum(t[sel] - start, end - t[sel]) / ramp, 0.0, 1.0)
        envelope[sel] = 0.5 - 0.5 * np.cos(np.pi * x)
        start = end + rng.uniform(*rest_s)

    gyr, acc = _random_rates_and_acc(rng, n, dt, kw["max_rate_dps"], kw["bandwidth_hz"], kw["accel_std"],
                                     kw["translation"], envelope)
    q0 = _initial(kw["initial"])
    return Trajectory(
        rate_hz=float(rate_hz),
        t=t,
        quat=integrate_gyro(q0, gyr, dt),
        gyr=gyr,
        acc_lin=acc,
        rest=(envelope == 0.0) & ~acc.any(axis=1),
    )
