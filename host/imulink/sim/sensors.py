"""Sensor error models and the simulator that turns a :class:`Trajectory` into readings.

Units: gyroscope rad/s (body frame), accelerometer specific force m/s^2 (body frame;
reads ``R^T [0, 0, +g]`` at rest, 0 in free fall), magnetometer uT (body frame).
Readings are quantised to register counts with :func:`imulink.counts.si_to_counts`,
and the SI arrays of a :class:`SimResult` are exactly ``counts * scale``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..counts import DEFAULT_PROFILE, STANDARD_GRAVITY, SensorProfile, si_to_counts
from . import quat as Q
from .trajectories import RAMP_S, Trajectory

__all__ = ["GyroModel", "AccModel", "MagModel", "SensorSuite", "SimResult", "simulate"]

_DEG = np.pi / 180.0

#: Duration (s) of an accelerometer tap (see ``acc_spikes`` of :func:`simulate`).
SPIKE_S = 0.02


def _vec3(x) -> np.ndarray:
    """Broadcast a scalar or 3-sequence to a float (3,) array."""
    return np.broadcast_to(np.asarray(x, dtype=np.float64), (3,)).copy()


def _first_order_recursion(b: np.ndarray, phi: float) -> np.ndarray:
    """``y[0] = b[0]``, ``y[k] = phi * y[k-1] + b[k]`` along axis 0, vectorised.

    Parallel prefix scan (log2(N) numpy steps); stable for ``|phi| <= 1``.
    """
    y = np.array(b, dtype=np.float64, copy=True)
    n = y.shape[0]
    d = 1
    while d < n:
        y[d:] = phi**d * y[:-d] + y[d:]  # RHS is evaluated before the assignment
        d *= 2
    return y


def _smooth_window(t: np.ndarray, start: float, end: float, ramp: float = RAMP_S) -> np.ndarray:
    """Weight in [0, 1]: 1 inside [start, end), 0 outside, raised-cosine ramps of ``ramp`` s
    inside the interval (ramps are shortened for intervals shorter than ``2 ramp``)."""
    ramp = max(min(ramp, 0.5 * (end - start)), 1e-12)
    x = np.clip(np.minimum(t - start, end - t) / ramp, 0.0, 1.0)
    w = 0.5 - 0.5 * np.cos(np.pi * x)
    return np.where((t >= start) & (t < end), w, 0.0)


@dataclass
class GyroModel:
    """Gyroscope errors, per axis (scalars are broadcast to the three axes).

    Attributes:
        arw: angle random walk in rad/sqrt(s) (white rate noise, per-sample std
            ``arw / sqrt(dt)``).
        bias_instability: bias instability in rad/s, modelled as a first-order
            Gauss-Markov process with this stationary std and correlation time
            ``bias_instability_tau_s``.
        rrw: rate random walk in rad/s/sqrt(s) (bias random walk, per-sample
            increment std ``rrw * sqrt(dt)``; starts at 0).
        bias: constant turn-on bias in rad/s, (3,).
        bias_instability_tau_s: Gauss-Markov correlation time in s.
    """

    arw: np.ndarray | float
    bias_instability: np.ndarray | float
    rrw: np.ndarray | float
    bias: tuple | np.ndarray = (0.0, 0.0, 0.0)
    bias_instability_tau_s: float = 100.0

    @classmethod
    def seed000(cls, bias_dps=(0.0, 0.0, 0.0)) -> "GyroModel":
        """Seed 000's Table 1 (x, y, z gyros), converted to SI.

        Bias stability 39.8887/36.4465/34.5215 deg/h, ARW 3.3197/2.6794/2.885 deg/sqrt(h),
        RRW 520.5/598.05/471.84 deg/h^1.5.

        Args:
            bias_dps: turn-on bias in deg/s, (3,).
        """
        return cls(
            arw=np.array([3.3197, 2.6794, 2.885]) * _DEG / 60.0,
            bias_instability=np.array([39.8887, 36.4465, 34.5215]) * _DEG / 3600.0,
            rrw=np.array([520.5, 598.05, 471.84]) * _DEG / 3600.0 / 60.0,
            bias=_vec3(bias_dps) * _DEG,
        )

    @classmethod
    def ideal(cls) -> "GyroModel":
        """An error-free gyroscope."""
        return cls(arw=0.0, bias_instability=0.0, rrw=0.0)

    def sample(self, n: int, dt: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Draw ``n`` samples of the errors at period ``dt`` s.

        Returns:
            (white_noise, bias): (n,3) arrays in rad/s; ``bias`` is the total bias
            (turn-on + Gauss-Markov + rate random walk).  The Gauss-Markov state
            starts from its stationary distribution, the random walk from 0.
        """
        arw, bi, rrw = _vec3(self.arw), _vec3(self.bias_instability), _vec3(self.rrw)
        white = rng.standard_normal((n, 3)) * (arw / np.sqrt(dt))

        phi = np.exp(-dt / self.bias_instability_tau_s)
        gm_drive = rng.standard_normal((n, 3))
        gm_drive[1:] *= bi * np.sqrt(1.0 - phi**2)
        gm_drive[0] *= bi  # stationary initial state
        gm = _first_order_recursion(gm_drive, phi)

        steps = rng.standard_normal((n, 3)) * (rrw * np.sqrt(dt))
        steps[0] = 0.0
        rw = np.cumsum(steps, axis=0)

        return white, _vec3(self.bias) + gm + rw


@dataclass
class AccModel:
    """Accelerometer errors.

    Attributes:
        noise_std: white noise std per sample in m/s^2 (scalar or (3,)).
        bias: constant bias in m/s^2, (3,).
    """

    noise_std: np.ndarray | float = 0.02
    bias: tuple | np.ndarray = (0.0, 0.0, 0.0)


@dataclass
class MagModel:
    """Magnetometer errors and the local earth field.

    Attributes:
        noise_std: white noise std per sample in uT (scalar or (3,)); default 0.2 uT,
            the HMC5883L data sheet's noise floor (2 mG at gain 1090).
        hard_iron: constant offset in uT, (3,).
        soft_iron: (3,3) matrix (dimensionless) applied to the body-frame field.
        earth_field_uT: total intensity of the earth field in uT.
        dip_deg: inclination in degrees (positive = field points down, northern
            hemisphere); the ENU field is ``F (0, cos dip, -sin dip)``.
        disturbances: list of ``(start_s, end_s, field_uT_earth)``: an extra field
            (3,) in uT, fixed in the EARTH frame, added during ``[start_s, end_s)``
            with 0.5 s raised-cosine ramps inside the interval.

    Measurement: ``soft_iron @ (R^T (B_earth + disturbance)) + hard_iron + noise``.
    """

    noise_std: np.ndarray | float = 0.2
    hard_iron: tuple | np.ndarray = (0.0, 0.0, 0.0)
    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))
    earth_field_uT: float = 49.0
    dip_deg: float = 67.0
    disturbances: list = field(default_factory=list)

    def earth_field(self) -> np.ndarray:
        """(3,) earth magnetic field in the ENU frame, uT."""
        dip = np.deg2rad(self.dip_deg)
        return self.earth_field_uT * np.array([0.0, np.cos(dip), -np.sin(dip)])


@dataclass
class SensorSuite:
    """The three sensor models plus the register profile used for quantisation.

    Attributes:
        gyro, acc, mag: error models.
        profile: full-scale settings (:class:`imulink.counts.SensorProfile`).
        saturate: if True (default) the SI readings are clipped to the register
            range like the real sensor; if False they are quantised but not clipped
            (the int16 counts are always clipped; ``saturated`` counts the clipping).
    """

    gyro: GyroModel
    acc: AccModel
    mag: MagModel
    profile: SensorProfile = DEFAULT_PROFILE
    saturate: bool = True

    @classmethod
    def default(cls) -> "SensorSuite":
        """Seed 000 gyros with a (0.2, -0.3, 0.1) deg/s turn-on bias, default acc and mag."""
        return cls(gyro=GyroModel.seed000(bias_dps=(0.2, -0.3, 0.1)), acc=AccModel(), mag=MagModel())


@dataclass
class SimResult:
    """Simulated sensor readings with their truth.

    Attributes:
        t: (N,) sample times, s.
        rate_hz: sample rate, Hz.
        quat_true: (N,4) truth attitude (w-first, sensor-to-earth, ENU).
        gyr, acc, mag: (N,3) measured rad/s, m/s^2, uT after quantisation
            (``*_counts * scale``, exactly representable).
        gyr_counts, acc_counts, mag_counts: (N,3) int16 register counts.
        saturated: {"gyr": n, "acc": n, "mag": n} number of clipped values.
        rest: (N,) truth rest mask.
        profile: the register profile used.
        earth_field_uT: (3,) undisturbed earth field in ENU, uT.
        gyro_bias_true: (N,3) true gyro bias, rad/s (turn-on + Gauss-Markov + RRW).
        gyr_true: (N,3) true body rate, rad/s.
    """

    t: np.ndarray
    rate_hz: float
    quat_true: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    gyr_counts: np.ndarray
    acc_counts: np.ndarray
    mag_counts: np.ndarray
    saturated: dict
    rest: np.ndarray
    profile: SensorProfile
    earth_field_uT: np.ndarray
    gyro_bias_true: np.ndarray
    gyr_true: np.ndarray

    @property
    def dt(self) -> float:
        """Sample period in s."""
        return 1.0 / self.rate_hz

    def __len__(self) -> int:
        return len(self.t)


def _interval_mean_in_body(q: np.ndarray, gyr: np.ndarray, dt: float, f_earth: np.ndarray) -> np.ndarray:
    """(N,3) the mean over each sample interval of R(t)^T f_earth[k], the body turning at
    gyr[k] from q[k-1] to q[k]: M^T R_{k-1}^T f with M = (1/theta) int_0^theta Exp(s u) ds =
    I + (1 - cos theta)/theta [u x] + (1 - sin theta/theta) [u x]^2 (theta = |gyr| dt, u its
    axis); sample 0 at q[0]."""
    out = np.empty_like(f_earth)
    out[0] = Q.rotate_inverse(q[0], f_earth[0])
    f_start = Q.rotate_inverse(q[:-1], f_earth[1:])  # in the body at each interval's start
    phi = gyr[1:] * dt
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    u = phi / safe[:, None]
    a = np.where(small, theta / 2.0, (1.0 - np.cos(theta)) / safe)   # [u x] coefficient
    b = np.where(small, theta**2 / 6.0, 1.0 - np.sin(safe) / safe)    # [u x]^2 coefficient
    # M^T f = f - a (u x f) + b (u x (u x f))  ([u x]^T = -[u x], ([u x]^2)^T = [u x]^2)
    uxf = np.cross(u, f_start)
    out[1:] = f_start - a[:, None] * uxf + b[:, None] * np.cross(u, uxf)
    return out


def _quantise(x: np.ndarray, counts: np.ndarray, scale: float, clip: bool) -> np.ndarray:
    return counts.astype(np.float64) * scale if clip else np.rint(x / scale) * scale


def simulate(traj: Trajectory, suite: SensorSuite | None = None, seed: int = 0,
             free_fall=(), acc_spikes=()) -> SimResult:
    """Generate gyroscope, accelerometer and magnetometer readings along ``traj``.

    Args:
        traj: truth motion.
        suite: sensor models; default :meth:`SensorSuite.default`.
        seed: random seed; the gyro, accelerometer, magnetometer and tap directions
            use independent streams spawned from it (same seed -> identical output).
        free_fall: list of ``(start_s, end_s)``: the specific force is zero during
            ``[start_s, end_s)`` (the accelerometer reads only bias + noise).  This is
            an accelerometer-only effect: the truth attitude is not changed.
        acc_spikes: list of ``(time_s, magnitude_m_s2)``: a 20 ms rectangular impulse
            (tap) of the given magnitude in a random body-frame direction, added to the
            specific force over ``[time_s, time_s + 0.02)``.  Accelerometer-only, like
            free fall.  Values beyond the profile's range saturate on quantisation.

    Returns:
        :class:`SimResult`.
    """
    suite = SensorSuite.default() if suite is None else suite
    n = len(traj.t)
    dt = 1.0 / traj.rate_hz
    t = traj.t
    q = traj.quat
    rng_gyr, rng_acc, rng_mag, rng_tap = (np.random.default_rng(s)
                                          for s in np.random.SeedSequence(seed).spawn(4))

    # Gyroscope: truth + bias + white noise.
    white, bias = suite.gyro.sample(n, dt, rng_gyr)
    gyr = traj.gyr + bias + white

    # Accelerometer: specific force f = R^T (a_lin + g ez). A navigation trajectory
    # (navigation.NavTrajectory) brings its own gravity (normal gravity along the path), and
    # its sample is the specific force's mean over the sample interval, in which the body
    # turns (an integrating output path: what strapdown navigation needs in fast motion, a
    # foot's 400 deg/s); the attitude scenarios sample it at the interval's end attitude,
    # as their golden vectors were made.
    gravity = getattr(traj, "gravity", None)
    f_earth = traj.acc_lin.copy()
    f_earth[:, 2] += STANDARD_GRAVITY if gravity is None else gravity
    for start, end in free_fall:
        f_earth[(t >= start) & (t < end)] = 0.0
    acc = Q.rotate_inverse(q, f_earth) if gravity is None else _interval_mean_in_body(q, traj.gyr, dt, f_earth)
    for time_s, magnitude in acc_spikes:
        direction = rng_tap.standard_normal(3)
        direction /= np.linalg.norm(direction)
        acc[(t >= time_s) & (t < time_s + SPIKE_S)] += magnitude * direction
    acc += _vec3(suite.acc.bias) + rng_acc.standard_normal((n, 3)) * _vec3(suite.acc.noise_std)

    # Magnetometer.
    m = suite.mag
    b_earth = m.earth_field()
    field_earth = np.tile(b_earth, (n, 1))
    for start, end, extra in m.disturbances:
        field_earth += _smooth_window(t, start, end)[:, None] * _vec3(extra)
    mag = Q.rotate_inverse(q, field_earth) @ np.asarray(m.soft_iron, dtype=np.float64).T
    mag += _vec3(m.hard_iron) + rng_mag.standard_normal((n, 3)) * _vec3(m.noise_std)

    p = suite.profile
    gc, ac, mc, sat = si_to_counts(gyr, acc, mag, p, return_saturation=True)
    return SimResult(
        t=t.copy(),
        rate_hz=traj.rate_hz,
        quat_true=q.copy(),
        gyr=_quantise(gyr, gc, p.gyro_scale, suite.saturate),
        acc=_quantise(acc, ac, p.acc_scale, suite.saturate),
        mag=_quantise(mag, mc, p.mag_scale, suite.saturate),
        gyr_counts=gc,
        acc_counts=ac,
        mag_counts=mc,
        saturated=sat,
        rest=traj.rest.copy(),
        profile=p,
        earth_field_uT=b_earth,
        gyro_bias_true=bias,
        gyr_true=traj.gyr.copy(),
    )
