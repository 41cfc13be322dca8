"""Sensor error models and the simulator that turns a :class:`Trajectory` into readings.

Units: gyroscope rad/s (body frame), accelerometer specific force m/s^2 (body frame;
reads ``R^T [0, 0, +g]`` at rest, 0 in free fall), magnetometer uT (body frame).
Readings are quantised to register counts with :func:`imulink.core.counts.si_to_counts`,
and the SI arrays of a :class:`SimResult` are exactly ``counts * scale``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imulink.core.counts import DEFAULT_PROFILE, STANDARD_GRAVITY, SensorProfile, si_to_counts
from imulink.sim import quat as Q
from imulink.sim.trajectories import RAMP_S, Trajectory

__all__ = ["GyroModel", "AccModel", "MagModel", "SensorSuite", "SimResult", "simulate", "Vibration", "Shock",
           "extra_field", "norm_change", "rotated_field"]

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


def _steps(t: np.ndarray, steps) -> np.ndarray:
    """(N,3) the sum of the ``(time_s, (3,) value)`` steps that have happened by each time of ``t``."""
    out = np.zeros((len(t), 3))
    for time_s, value in steps:
        out[t >= time_s] += _vec3(value)
    return out


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
        bias_steps: list of ``(time_s, (3,) rad/s)``: a step added to the bias from that
            time on (a knock, a mount that shifts, a temperature jump: what the
            Gauss-Markov and random-walk terms do not make), in ``gyro_bias_true`` too.
        scale_error: (3, 3) sensitivity error M: the gyroscope reads ``(I + M) w`` for the
            true rate w; the diagonal is each axis's scale-factor error, the rest the
            cross-axis sensitivity (the MPU6050's data sheet: +-3 % and +-2 %). None: none.
    """

    arw: np.ndarray | float
    bias_instability: np.ndarray | float
    rrw: np.ndarray | float
    bias: tuple | np.ndarray = (0.0, 0.0, 0.0)
    bias_instability_tau_s: float = 100.0
    bias_steps: tuple | list = ()
    scale_error: np.ndarray | None = None

    @classmethod
    def seed000(cls, bias_dps=(0.0, 0.0, 0.0)) -> "GyroModel":
        """[seed 000]'s Table 1 (x, y, z gyros; docs/filters.md, Bibliography), converted to SI.

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
            (turn-on + Gauss-Markov + rate random walk + steps; sample k at time
            ``k dt``).  The Gauss-Markov state starts from its stationary distribution,
            the random walk from 0.
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

        bias = _vec3(self.bias) + gm + rw
        if len(self.bias_steps):  # only then, so that the sum without steps stays bit for bit what it was
            bias += _steps(np.arange(n) * dt, self.bias_steps)
        return white, bias


@dataclass
class AccModel:
    """Accelerometer errors.

    Attributes:
        noise_std: white noise std per sample in m/s^2 (scalar or (3,)).
        bias: constant bias in m/s^2, (3,).
        bias_steps: list of ``(time_s, (3,) m/s^2)``: a step added to the bias from that
            time on (see ``SimResult.acc_bias_true``).
    """

    noise_std: np.ndarray | float = 0.02
    bias: tuple | np.ndarray = (0.0, 0.0, 0.0)
    bias_steps: tuple | list = ()


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


def extra_field(start_s: float, end_s: float, magnitude_uT: float, direction_enu) -> tuple:
    """A disturbance for ``MagModel.disturbances``: an extra field of ``magnitude_uT`` (uT)
    along ``direction_enu`` (ENU, any length) during ``[start_s, end_s)`` (s): steel,
    a car or a motor nearby. It changes the field's norm and its dip by what the geometry
    gives (30 uT added to the default 49 uT field: a norm of 19-79 uT)."""
    direction = _vec3(direction_enu)
    return (start_s, end_s, magnitude_uT * direction / np.linalg.norm(direction))


def norm_change(model: "MagModel", start_s: float, end_s: float, change_uT: float) -> tuple:
    """A disturbance that changes the field's norm by ``change_uT`` (uT) during ``[start_s,
    end_s)`` (s) and leaves its direction (dip and heading) as it is: an extra field
    along the earth field."""
    b = model.earth_field()
    return (start_s, end_s, change_uT * b / np.linalg.norm(b))


def rotated_field(model: "MagModel", start_s: float, end_s: float, dip_change_deg: float = 0.0,
                  declination_change_deg: float = 0.0) -> tuple:
    """A disturbance that keeps the field's norm and turns it during ``[start_s, end_s)``
    (s): its dip steeper by ``dip_change_deg`` (deg) and its horizontal part turned
    anticlockwise (seen from above) by ``declination_change_deg`` (deg): the disturbance
    a norm test cannot see (a field bent by a steel frame). The extra field is the turned
    field minus the earth field, so within the 0.5 s ramps the norm dips slightly (by
    ``1 - cos(angle / 2)``, 1.5 % for a 20 deg turn)."""
    dip = np.deg2rad(model.dip_deg + dip_change_deg)
    turn = np.deg2rad(declination_change_deg)
    turned = model.earth_field_uT * np.array([-np.sin(turn) * np.cos(dip), np.cos(turn) * np.cos(dip), -np.sin(dip)])
    return (start_s, end_s, turned - model.earth_field())


@dataclass
class Vibration:
    """Engine and handling vibration added to the gyroscope and accelerometer readings
    (before quantisation and clipping, like the real sensor's own).

    The engine's dominant excitation turns at a frequency ``f(t)`` that wanders within
    ``[freq_min_hz, freq_max_hz]`` as the rpm drifts (a first-order Gauss-Markov process
    of correlation time ``wander_tau_s`` through a tanh that keeps it in the band); each
    of ``orders`` (multiples of ``f``) is a narrow-band random vibration: a carrier at
    ``order f(t)`` whose complex amplitude is a Gauss-Markov process of correlation time
    ``envelope_tau_s`` (a bandwidth of about ``1 / (2 pi envelope_tau_s)``), weighted by
    ``order_rms`` (relative, normalised). The vibration is what the mount does to the
    readings only: the truth trajectory leaves out its few micrometres and hundredths of
    a degree.

    Sampling: the readings are the vibration's value AT the sample times (an MPU6050 with
    its digital low-pass filter wide open: 260 Hz of bandwidth, no anti-alias filter at
    the output rate), so what lies above the Nyquist frequency aliases: a 2nd order of
    40-90 Hz read at 100 Hz lands at 10-50 Hz, and an order crossing a multiple of the
    sample rate folds to near 0 Hz, a slowly wandering pseudo-bias.

    Attributes:
        acc_rms_m_s2: RMS of the accelerometer's vibration vector, m/s^2 (the square root
            of the sum of the three axes' mean squares).
        gyro_rms_rad_s: RMS of the gyroscope's vibration vector, rad/s.
        freq_min_hz, freq_max_hz: the band the fundamental wanders in, Hz.
        wander_tau_s: correlation time of the rpm's drift, s.
        envelope_tau_s: correlation time of each order's amplitude and phase, s.
        orders: multiples of the fundamental that vibrate.
        order_rms: their relative RMS (normalised so that the total is the RMS above).
        acc_axes: (3,) relative RMS of the accelerometer's x, y, z vibration (a car's
            engine shakes mostly vertically); signed: with ``coherent``, the sign is the
            axis's phase (0 or 180 deg).
        gyro_axes: (3,) the same for the gyroscope (a mount rocks in roll and pitch).
        coherent: False: every axis of each sensor vibrates with its own random amplitude
            and phase; True: one amplitude and phase per order for all six (a rigid mount
            rocking as it shakes), so that the products of rate and force do not average
            out: sculling, and with ``gyro_phase_deg`` apart, coning.
        gyro_phase_deg: (3,) with ``coherent``, each gyro axis's phase lead over the
            accelerometer's, deg (90 deg between two axes cones).
        windows: ``(start_s, end_s)`` intervals the vibration is on, with 0.5 s ramps
            (empty: the whole run; an engine idles at a standstill).
    """

    acc_rms_m_s2: float = 0.7
    gyro_rms_rad_s: float = 2.0 * _DEG
    freq_min_hz: float = 20.0
    freq_max_hz: float = 45.0
    wander_tau_s: float = 10.0
    envelope_tau_s: float = 1.0
    orders: tuple = (1.0, 2.0)
    order_rms: tuple = (1.0, 0.5)
    acc_axes: tuple = (0.5, 0.5, 1.0)
    gyro_axes: tuple = (1.0, 1.0, 0.3)
    coherent: bool = False
    gyro_phase_deg: tuple = (0.0, 0.0, 0.0)
    windows: tuple = ()

    def frequency(self, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
        """(n,) the fundamental's frequency, Hz (from its stationary distribution at the start)."""
        phi = np.exp(-dt / self.wander_tau_s)
        drive = rng.standard_normal(n)
        drive[1:] *= np.sqrt(1.0 - phi**2)
        x = _first_order_recursion(drive, phi)
        return self.freq_min_hz + (self.freq_max_hz - self.freq_min_hz) * 0.5 * (1.0 + np.tanh(x))

    def sample(self, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Draw the vibration at the times ``t`` (s, evenly spaced).

        Returns:
            (acc, gyr): (n,3) m/s^2 and rad/s, to add to the readings.
        """
        n = len(t)
        dt = float(t[1] - t[0]) if n > 1 else 1.0
        f0 = self.frequency(n, dt, rng)
        cycles = np.cumsum(f0) * dt  # the fundamental's phase in cycles
        weights = np.asarray(self.order_rms, dtype=np.float64)
        weights = weights / np.sqrt(np.sum(weights**2))
        phi = np.exp(-dt / self.envelope_tau_s)
        streams = 1 if self.coherent else 6  # complex amplitudes per order

        def envelope() -> np.ndarray:
            # complex Gauss-Markov, E|z|^2 = 2: Re(z e^(i wt)) has unit variance
            drive = rng.standard_normal((n, streams)) + 1j * rng.standard_normal((n, streams))
            drive[1:] *= np.sqrt(1.0 - phi**2)
            return _first_order_recursion(drive.real, phi) + 1j * _first_order_recursion(drive.imag, phi)

        out = np.zeros((n, 6))
        gyro_phase = np.exp(1j * np.deg2rad(_vec3(self.gyro_phase_deg)))
        for order, weight in zip(self.orders, weights):
            carrier = np.exp(2j * np.pi * order * cycles)  # z's phase is uniform: no offset needed
            z = envelope()
            if self.coherent:
                z = np.concatenate([np.repeat(z, 3, axis=1), z * gyro_phase[None, :]], axis=1)
            out += weight * np.real(z * carrier[:, None])
        gain = np.concatenate([_axis_rms(self.acc_axes, self.acc_rms_m_s2), _axis_rms(self.gyro_axes,
                                                                                      self.gyro_rms_rad_s)])
        out *= gain
        if self.windows:
            on = np.zeros(n)
            for start, end in self.windows:
                on += _smooth_window(t, start, end)
            out *= np.minimum(on, 1.0)[:, None]
        return out[:, :3], out[:, 3:]


def _axis_rms(axes, total: float) -> np.ndarray:
    """(3,) each axis's RMS: ``axes`` (signed) scaled so that the vector's RMS is ``total``."""
    axes = _vec3(axes)
    return total * axes / np.linalg.norm(axes)


@dataclass
class Shock:
    """A knock or a heel strike on the accelerometer: a short pulse of specific force of
    ``peak_m_s2`` (m/s^2) along ``direction`` (body frame, any length; None: a random
    direction from the shock stream), its main lobe ``duration_s`` (s) wide between its
    zero crossings and centred at ``time_s`` (s).

    The pulse is a Ricker wavelet, ``peak (1 - 2u^2) exp(-u^2)`` with ``u = (t - time_s) /
    sigma`` and ``sigma = duration_s / sqrt 2``: the acceleration of the sensor pushed a
    little way and springing back (a sole, a mount), the main lobe and two opposite side
    lobes of 45 % of the peak. It changes neither the velocity nor the position over the
    shock, so the truth trajectory stays right; only the clipping of the main lobe (beyond
    the profile's range) or its sampling (the value at each sample time, no anti-alias
    filter: a pulse shorter than the sample period is partly missed) leaves an error in
    the integral, as on a real sensor."""

    time_s: float
    peak_m_s2: float
    direction: tuple | np.ndarray | None = (0.0, 0.0, 1.0)
    duration_s: float = 0.015

    def waveform(self, t: np.ndarray) -> np.ndarray:
        """(n,) the pulse's value at the times ``t`` (s), m/s^2 along its direction."""
        sigma = self.duration_s / np.sqrt(2.0)
        u = (t - self.time_s) / sigma
        return np.where(np.abs(u) < 6.0, self.peak_m_s2 * (1.0 - 2.0 * u**2) * np.exp(-np.minimum(u**2, 36.0)), 0.0)


@dataclass
class SensorSuite:
    """The three sensor models plus the register profile used for quantisation.

    Attributes:
        gyro, acc, mag: error models.
        profile: full-scale settings (:class:`imulink.core.counts.SensorProfile`).
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
        """[seed 000] gyros with a (0.2, -0.3, 0.1) deg/s turn-on bias, default acc and mag."""
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
        gyro_bias_true: (N,3) true gyro bias, rad/s (turn-on + Gauss-Markov + RRW + steps).
        gyr_true: (N,3) true body rate, rad/s.
        acc_bias_true: (N,3) true accelerometer bias, m/s^2 (constant + steps).
        vibration_acc, vibration_gyr: (N,3) the vibration added (m/s^2, rad/s), None without.
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
    acc_bias_true: np.ndarray | None = None
    vibration_acc: np.ndarray | None = None
    vibration_gyr: np.ndarray | None = None

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
             free_fall=(), acc_spikes=(), vibration: Vibration | None = None, shocks=()) -> SimResult:
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
        vibration: a :class:`Vibration` added to the gyroscope and accelerometer
            readings (None: none).
        shocks: list of :class:`Shock`: pulses of specific force along given body
            directions (heel strikes, knocks), clipped like everything else.

    The vibration and the shocks draw from streams of their own (spawned after the four
    above), so that a run without them is bit for bit a run of the four alone, and adding
    them leaves the other errors unchanged.

    Returns:
        :class:`SimResult`.
    """
    suite = SensorSuite.default() if suite is None else suite
    n = len(traj.t)
    dt = 1.0 / traj.rate_hz
    t = traj.t
    q = traj.quat
    # spawn(6)'s first four children are spawn(4)'s: the original streams stay as they were
    rng_gyr, rng_acc, rng_mag, rng_tap, rng_vib, rng_shock = (np.random.default_rng(s)
                                                              for s in np.random.SeedSequence(seed).spawn(6))
    vib_acc = vib_gyr = None
    if vibration is not None:
        vib_acc, vib_gyr = vibration.sample(t, rng_vib)

    # Gyroscope: truth + bias + white noise.
    white, bias = suite.gyro.sample(n, dt, rng_gyr)
    gyr = traj.gyr + bias + white
    if suite.gyro.scale_error is not None:  # only then, so that a run without stays bit for bit what it was
        gyr = gyr + traj.gyr @ np.asarray(suite.gyro.scale_error, dtype=np.float64).T
    if vib_gyr is not None:
        gyr += vib_gyr

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
    for shock in shocks:
        direction = rng_shock.standard_normal(3) if shock.direction is None else _vec3(shock.direction)
        acc += shock.waveform(t)[:, None] * (direction / np.linalg.norm(direction))
    if vib_acc is not None:
        acc += vib_acc
    acc_bias = np.tile(_vec3(suite.acc.bias), (n, 1))
    if len(suite.acc.bias_steps):
        acc_bias += _steps(t, suite.acc.bias_steps)
        acc += acc_bias + rng_acc.standard_normal((n, 3)) * _vec3(suite.acc.noise_std)
    else:  # the sum as it always was, bit for bit
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
        acc_bias_true=acc_bias,
        vibration_acc=vib_acc,
        vibration_gyr=vib_gyr,
    )
