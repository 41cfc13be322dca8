"""Truth and sensors for navigation: a vehicle's position, velocity and attitude on the
WGS-84 ellipsoid, a GNSS receiver's fixes and a barometer's pressure along it.

Frames and conventions as in the rest of the simulator: quaternions w-first,
sensor-to-earth; the sensor's y axis points forward (the board lies flat with its y axis
along the vehicle), x to the right, z up. The earth frame is the local-level
east-north-up frame where the vehicle is: attitude, velocity and gravity are in it, and
gravity is the WGS-84 normal gravity there (:func:`normal_gravity`), along its up. The
vehicle's geodetic position is the integral of its velocity over the ellipsoid:
d(lat)/dt = v_n / (M + h), d(lon)/dt = v_e / ((N + h) cos lat), dh/dt = v_u (M and N the
meridian and prime-vertical radii). A tangent plane at the origin would not do beyond a
few km: 10 km away its up is 0.09 deg off the local one and 8 m above the ellipsoid.
The local-level frame is taken as inertial: the earth's rotation (15 deg/h) and the
transport rate (v / R: 0.8 deg/h at 25 m/s) are left out of the truth, far below an
MPU6050's noise and turn-on bias. ``pos_enu`` holds the integral of the velocity
(distances travelled east, north and up), for errors in metres.

Everything is deterministic for a given seed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imulink.sim import quat as Q
from imulink.sim.sensors import AccModel, GyroModel, MagModel, SensorSuite, _smooth_window
from imulink.sim.trajectories import Trajectory, _lowpass_noise, _n_samples, integrate_gyro

# WGS-84 (NIMA TR8350.2): semi-major axis, flattening, first eccentricity squared.
WGS84_A = 6_378_137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_B = WGS84_A * (1.0 - WGS84_F)
#: Normal gravity at the equator and the pole (m/s^2) and GM * omega^2 a^2 b / GM, TR8350.2.
GAMMA_E, GAMMA_P = 9.7803253359, 9.8321849378
WGS84_M = 0.00344978650684


@dataclass(frozen=True)
class Origin:
    """The ENU frame's origin: latitude and longitude (deg), height above the ellipsoid (m)."""
    lat_deg: float = 47.3769
    lon_deg: float = 8.5417
    height_m: float = 450.0


def radii(lat_deg) -> tuple[np.ndarray, np.ndarray]:
    """Meridian (M) and prime-vertical (N) radii of curvature, m."""
    s2 = np.sin(np.deg2rad(lat_deg)) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A * (1.0 - WGS84_E2) / w**3, WGS84_A / w


def local_offsets(lat_deg, lon_deg, height_m, ref_lat_deg, ref_lon_deg, ref_height_m) -> np.ndarray:
    """(..., 3) east, north, up (m) of geodetic points from nearby reference points, to first
    order in the difference (within a few km of each other: fixes against the truth)."""
    m, n = radii(ref_lat_deg)
    return np.stack([np.deg2rad(np.asarray(lon_deg) - ref_lon_deg) * (n + ref_height_m)
                     * np.cos(np.deg2rad(ref_lat_deg)),
                     np.deg2rad(np.asarray(lat_deg) - ref_lat_deg) * (m + ref_height_m),
                     np.asarray(height_m) - ref_height_m], axis=-1)


def normal_gravity(lat_deg, height_m) -> np.ndarray:
    """WGS-84 normal gravity (m/s^2): Somigliana's formula on the ellipsoid and the
    second-order free-air correction for the height (TR8350.2, eq. 4-1 and 4-3)."""
    s2 = np.sin(np.deg2rad(lat_deg)) ** 2
    k = WGS84_B * GAMMA_P / (WGS84_A * GAMMA_E) - 1.0
    gamma = GAMMA_E * (1.0 + k * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    h = np.asarray(height_m, dtype=np.float64)
    return gamma * (1.0 - 2.0 / WGS84_A * (1.0 + WGS84_F + WGS84_M - 2.0 * WGS84_F * s2) * h
                    + 3.0 / WGS84_A**2 * h**2)


@dataclass
class NavTrajectory(Trajectory):
    """A :class:`Trajectory` with the vehicle's path: ``vel_enu`` (N,3) m/s in the local
    level frame, ``pos_enu`` (N,3) m its integral, ``lat_deg``, ``lon_deg``, ``height_m``
    (N,) the geodetic position, ``gravity`` (N,) m/s^2 along -up. Consistent with
    ``acc_lin`` (constant over each sample interval): ``vel[k] = vel[k-1] + acc_lin[k] dt``,
    ``pos[k] = pos[k-1] + (vel[k-1] + vel[k]) dt / 2``, and the geodetic position the same
    trapezoid over the rates of latitude, longitude and height."""

    pos_enu: np.ndarray
    vel_enu: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    gravity: np.ndarray
    origin: Origin = field(default_factory=Origin)


def _geodetic_path(vel: np.ndarray, dt: float, origin: Origin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude (deg) and height (m) from the local-level velocity, integrated by
    the trapezoid with the radii at each interval's start (they change by less than 1e-9
    of themselves over an interval)."""
    n = len(vel)
    lat, lon, h = np.empty(n), np.empty(n), np.empty(n)
    lat[0], lon[0], h[0] = math.radians(origin.lat_deg), math.radians(origin.lon_deg), origin.height_m
    mid = (vel[:-1] + vel[1:]) * (dt / 2.0)  # metres east, north, up per interval
    for k in range(1, n):
        m, nn = radii(math.degrees(lat[k - 1]))
        h[k] = h[k - 1] + mid[k - 1, 2]
        lat[k] = lat[k - 1] + mid[k - 1, 1] / (m + h[k - 1])
        lon[k] = lon[k - 1] + mid[k - 1, 0] / ((nn + h[k - 1]) * math.cos(lat[k - 1]))
    return np.degrees(lat), np.degrees(lon), h


def _body_rates(quat: np.ndarray, dt: float) -> np.ndarray:
    """The piecewise-constant body rates that turn quat[k-1] into quat[k] (rate k; rate 0 zero)."""
    d = Q.multiply(Q.conjugate(quat[:-1]), quat[1:])
    d *= np.where(d[:, :1] < 0, -1.0, 1.0)  # the short way
    norm = np.linalg.norm(d[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(norm, d[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where(norm[:, None] > 0, d[:, 1:] / norm[:, None], 0.0)
    rates = np.zeros((len(quat), 3))
    rates[1:] = axis * (angle / dt)[:, None]
    return rates


def _trajectory(rate_hz: float, target: np.ndarray, velocity, origin: Origin, stopped: np.ndarray) -> NavTrajectory:
    """The trajectory through the attitudes `target` (the body rates that turn each into the
    next, integrated) with the velocity `velocity(quat)` gives for the integrated attitude
    (m/s, local level); `stopped` marks where the body should be at rest (it is where it
    also has no rate and no acceleration)."""
    n = len(target)
    dt = 1.0 / rate_hz
    gyr = _body_rates(target, dt)
    gyr[np.linalg.norm(gyr, axis=1) < 1e-9] = 0.0  # rounding of equal attitudes' product, not motion
    quat = integrate_gyro(target[0], gyr, dt)
    vel = velocity(quat)
    acc = np.zeros((n, 3))
    acc[1:] = np.diff(vel, axis=0) / dt
    pos = np.zeros((n, 3))
    pos[1:] = np.cumsum((vel[:-1] + vel[1:]) * (dt / 2.0), axis=0)
    rest = stopped & (np.linalg.norm(gyr, axis=1) == 0.0) & (np.linalg.norm(acc, axis=1) < 1e-12)
    lat, lon, height = _geodetic_path(vel, dt, origin)
    return NavTrajectory(rate_hz=rate_hz, t=np.arange(n) / rate_hz, quat=quat, gyr=gyr, acc_lin=acc, rest=rest,
                         pos_enu=pos, vel_enu=vel, lat_deg=lat, lon_deg=lon, height_m=height,
                         gravity=normal_gravity(lat, height), origin=origin)


def _attitude(yaw: np.ndarray, nose_up: np.ndarray, bank: np.ndarray) -> np.ndarray:
    """Heading `yaw` (rad, CCW from north), then nose up by `nose_up` (about the body x axis),
    then banked by `bank` (about the body y axis, the forward one)."""
    return Q.multiply(Q.from_axis_angle([0.0, 0.0, 1.0], yaw),
                      Q.multiply(Q.from_axis_angle([1.0, 0.0, 0.0], nose_up), Q.from_axis_angle([0.0, 1.0, 0.0], bank)))


def _path(rate_hz: float, speed: np.ndarray, yaw: np.ndarray, grade: np.ndarray, bank: np.ndarray,
          origin: Origin, stopped: np.ndarray) -> NavTrajectory:
    """A vehicle moving forward (its y axis) at `speed` (m/s) with heading `yaw`, nose up
    by `grade` and banked by `bank` (rad, see _attitude); `stopped` marks the rest."""
    def forward(quat):
        along = np.zeros((len(speed), 3))
        along[:, 1] = speed
        return Q.rotate(quat, along)
    return _trajectory(rate_hz, _attitude(yaw, grade, bank), forward, origin, stopped)


def _smooth(x: np.ndarray, rate_hz: float, seconds: float) -> np.ndarray:
    """A moving average over `seconds`, twice (a smooth ramp for steps)."""
    width = max(1, int(round(seconds * rate_hz)))
    kernel = np.ones(width) / width
    for _ in range(2):
        padded = np.concatenate([np.full(width, x[0]), x, np.full(width, x[-1])])
        x = np.convolve(padded, kernel, mode="same")[width:-width]
    return x


def car_drive(duration_s: float, rate_hz: float, seed: int = 0, origin: Origin = Origin()) -> NavTrajectory:
    """A car: drives at 8-25 m/s in stretches of 20-90 s, about one in three ending in a
    stop of 5-20 s; turns of 45-120 deg at 10-25 deg/s, slowing down for them so that the
    lateral acceleration stays within 3 m/s^2; hills of up to 6 % grade with a few hundred
    metres between them; a bank of 0.5 deg per m/s^2 of lateral acceleration (the body roll
    of a soft suspension). Speed changes take 16 s ramps (3.1 m/s^2 at most). Starts at rest
    for 10 s, heading north-east."""
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    ramp = 8.0  # half of a speed change's ramp, s (_smooth twice over 8 s)
    # Speed schedule: rest, then stretches at random speeds, some ending in a stop (the
    # target is zero a ramp longer on each side, so that the car stands still all the stop).
    target = np.zeros(n)
    time = 10.0 + ramp
    while time < duration_s:
        length = rng.uniform(20.0, 90.0)
        target[(t >= time) & (t < time + length)] = rng.uniform(8.0, 25.0)
        time += length
        if rng.random() < 0.35:
            time += rng.uniform(5.0, 20.0) + 2.0 * ramp
    stopped = target == 0.0
    # Turns: yaw-rate pulses at random times, the speed capped around them.
    yaw_rate = np.zeros(n)
    time = 15.0
    while time < duration_s:
        time += rng.uniform(15.0, 60.0)
        angle = math.radians(rng.uniform(45.0, 120.0)) * rng.choice([-1.0, 1.0])
        rate = math.radians(rng.uniform(10.0, 25.0))
        length = abs(angle) / rate
        yaw_rate[(t >= time) & (t < time + length)] = math.copysign(rate, angle)
        around = (t >= time - 2.0 * ramp) & (t < time + length + 2.0 * ramp)
        target[around] = np.minimum(target[around], 3.0 / rate)
        time += length
    speed = _smooth(target, rate_hz, ramp)
    speed[speed < 1e-9] = 0.0
    yaw_rate = _smooth(yaw_rate, rate_hz, 1.0) * np.clip(speed / 5.0, 0.0, 1.0)  # no turning on the spot
    yaw = math.radians(-45.0) + np.cumsum(yaw_rate) * dt
    # Hills: a smooth grade along the distance driven.
    distance = np.cumsum(speed) * dt
    hills = _lowpass_noise(rng, 4096, 25.0, 1.0 / 600.0, 0.03)[:, 0]  # a sample per 25 m of road
    slope = np.interp(distance / 25.0, np.arange(4096), hills, period=4096)
    grade = np.arctan(0.06 * np.tanh(slope / 0.06))  # a soft limit at 6 %; constant while standing
    bank = np.deg2rad(0.5) * _smooth(speed * yaw_rate, rate_hz, 0.5)
    return _path(rate_hz, speed, yaw, grade, bank, origin, stopped)


def _minimum_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum-jerk profile from 0 to 1 over tau in [0, 1] and its derivative."""
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2), 30.0 * tau**2 * (1.0 - tau) ** 2


def _rectangle_headings(lengths_m: tuple[float, float], stride_m: float) -> list[float]:
    """Changes of heading, one per stride, that walk a rectangle anticlockwise (rad): the
    sides in whole strides, each 90 deg corner over two strides."""
    changes = []
    for side in lengths_m * 2:
        changes += [0.0] * max(1, int(round(side / stride_m)) - 2) + [math.pi / 4] * 2
    return changes


#: A staircase's tread (going), m: a stride on stairs spans two of them.
STAIR_TREAD_M = 0.28


def foot_walk(duration_s: float, rate_hz: float, seed: int = 0, origin: Origin = Origin(),
              rectangle_m: tuple[float, float] = (20.0, 10.0), stairs=()) -> NavTrajectory:
    """A foot-mounted sensor (on the instep: y forward, z up while the foot is flat) walking
    laps of a rectangle, anticlockwise, from a corner: strides of 1.4 m in 1.0-1.2 s,
    of which the foot stands flat and still for 55 % (the stance, where a zero-velocity
    update applies) and swings for the rest: forward by the minimum-jerk profile, lifted by
    up to 12 cm, toe down by up to 35 deg after the push-off and toe up by 15 deg before the
    heel strikes, turning a corner's half per stride. Starts with 10 s standing.

    `stairs`: (start_s, strides, rise_m) flights: from the first stride starting at or after
    start_s (s), that many strides go up (rise_m > 0) or down (< 0) a staircase, each stride
    two steps of rise_m (m; 0.17 a usual riser) and two treads of STAIR_TREAD_M forward (the
    other foot takes the step between), straight on; the foot rises (or falls) along the
    swing's minimum-jerk profile, above the usual lift, and lands flat on the step. The
    rectangle's turns resume after the flight, which lengthens a side: laps no longer close."""
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    vel = np.zeros((n, 3))
    yaw = np.zeros(n)
    nose_up = np.zeros(n)
    stopped = np.ones(n, bool)
    changes = _rectangle_headings(rectangle_m, 1.4)
    flights = sorted(stairs)
    heading, time, k, flight, on_flight = 0.0, 10.0, 0, 0, 0
    while True:
        period = rng.uniform(1.0, 1.2)
        stride = 1.4  # the same every stride, so that each lap of the rectangle closes
        swing = 0.45 * period
        start = time + 0.55 * period
        if start + swing > duration_s:
            break
        rise = None  # m per step of a stair stride
        if flight < len(flights) and time >= flights[flight][0]:
            rise, stride = flights[flight][2], 2.0 * STAIR_TREAD_M
            on_flight += 1
            if on_flight == flights[flight][1]:
                flight, on_flight = flight + 1, 0
        span = (t >= start) & (t < start + swing)
        tau = (t[span] - start) / swing
        shape, rate = _minimum_jerk(tau)
        turn = changes[k % len(changes)] if rise is None else 0.0
        direction = heading + turn * shape
        speed = rate * (stride / (np.sum(rate) * dt))  # exactly `stride` over the sampled swing
        vel[span, 0] = -np.sin(direction) * speed  # yaw CCW from north: forward is (-sin, cos)
        vel[span, 1] = np.cos(direction) * speed
        lift = 0.12 * math.pi / swing * np.sin(2.0 * math.pi * tau)  # up and down again
        vel[span, 2] = lift - lift.mean()  # back on the floor exactly, whatever the sampling
        if rise is not None:
            vel[span, 2] += rate * (2.0 * rise / (np.sum(rate) * dt))  # exactly two steps up (down)
        yaw[span] = direction
        yaw[t >= start + swing] = heading + turn
        nose_up[span] = np.radians(-25.0) * np.sin(2.0 * math.pi * tau) * np.sin(math.pi * tau) - np.radians(
            10.0) * np.sin(math.pi * tau) ** 2 * (1.0 - 2.0 * tau)
        stopped[span] = False
        heading += turn
        time += period
        if rise is None:
            k += 1
    return _trajectory(rate_hz, _attitude(yaw, nose_up, np.zeros(n)), lambda quat: vel, origin, stopped)


def handheld_walk(duration_s: float, rate_hz: float, seed: int = 0, origin: Origin = Origin(),
                  rectangle_m: tuple[float, float] = (30.0, 15.0)) -> NavTrajectory:
    """A phone held in front, screen up (y forward), carried around a rectangular corridor
    loop at 1.2-1.5 m/s: each step (about 1.9 a second) bobs it up and down by 2 cm and
    sways it 1.5 cm sideways at half that rate, rolling and pitching it by 2-3 deg; corners
    turned at 45 deg/s; a pause of 3-8 s now and then (reading a marker). Starts with 10 s
    standing."""
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    # forward speed: walking stretches with pauses
    target = np.zeros(n)
    time = 10.0 + 1.0
    while time < duration_s:
        length = rng.uniform(20.0, 60.0)
        target[(t >= time) & (t < time + length)] = rng.uniform(1.2, 1.5)
        time += length + rng.uniform(3.0, 8.0) + 2.0
    stopped = target == 0.0
    speed = _smooth(target, rate_hz, 1.0)
    speed[speed < 1e-9] = 0.0
    # heading: the corners of the loop, reached by distance
    distance = np.cumsum(speed) * dt
    perimeter = 2.0 * sum(rectangle_m)
    corners = np.cumsum([rectangle_m[0], rectangle_m[1], rectangle_m[0], rectangle_m[1]])
    turns = np.floor(distance / perimeter) * 4 + np.searchsorted(corners, np.mod(distance, perimeter), side="right")
    yaw = _smooth(turns * (math.pi / 2.0), rate_hz, 1.0)  # 90 deg over about 2 s
    step_hz = 1.9 * np.clip(speed / 1.3, 0.0, 1.2)
    phase = 2.0 * math.pi * np.cumsum(step_hz) * dt
    walking = np.clip(speed / 1.2, 0.0, 1.0)
    bob_v = 0.02 * walking * 2.0 * math.pi * step_hz * np.cos(phase)  # d/dt of 0.02 sin(phase)
    sway_v = 0.015 * walking * math.pi * step_hz * np.cos(phase / 2.0)
    roll = np.radians(3.0) * walking * np.sin(phase / 2.0)
    pitch = np.radians(2.0) * walking * np.sin(phase + 0.5)

    def velocity(quat):
        v = np.zeros((n, 3))
        v[:, 0] = -np.sin(yaw) * speed + np.cos(yaw) * sway_v
        v[:, 1] = np.cos(yaw) * speed + np.sin(yaw) * sway_v
        v[:, 2] = bob_v
        return v
    return _trajectory(rate_hz, _attitude(yaw, pitch, roll), velocity, origin, stopped)


def drone_flight(duration_s: float, rate_hz: float, seed: int = 0, origin: Origin = Origin()) -> NavTrajectory:
    """A quadcopter (the board flat in its frame, y forward): 10 s on the ground, a climb
    at up to 2 m/s to 20-40 m, then legs to random waypoints within 300 m of the start at
    up to 12 m/s and 4 m/s^2 (minimum-jerk legs), climbing and descending between them,
    each followed by a hover of 5-15 s (still: marked rest); the nose turns to each leg's
    direction in its first quarter. A multirotor's thrust is along its z axis: the frame
    tilts into its acceleration, up to about 25 deg."""
    n = _n_samples(duration_s, rate_hz)
    dt = 1.0 / rate_hz
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    pos = np.zeros((n, 3))
    vel = np.zeros((n, 3))
    acc = np.zeros((n, 3))
    heading = np.zeros(n)
    here, yaw, time = np.zeros(3), 0.0, 10.0
    first = True
    while time < duration_s:
        if first:
            target = np.array([0.0, 0.0, rng.uniform(20.0, 40.0)])
            length = target[2] / 1.2  # at most about 2 m/s
        else:
            angle, radius = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(50.0, 300.0)
            target = np.array([radius * math.cos(angle), radius * math.sin(angle), rng.uniform(20.0, 40.0)])
            distance = float(np.linalg.norm(target - here))
            # a minimum-jerk leg peaks at 1.875 d / T and 5.77 d / T^2: at most 12 m/s and 4 m/s^2
            length = max(distance / 6.4, math.sqrt(5.77 * distance / 4.0), 4.0)
        span = (t >= time) & (t < time + length)
        tau = (t[span] - time) / length
        shape, rate = _minimum_jerk(tau)
        jerk_acc = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)  # d(rate)/dtau
        step = target - here
        pos[span] = here + shape[:, None] * step
        vel[span] = rate[:, None] * step / length
        acc[span] = jerk_acc[:, None] * step / length**2
        new_yaw = yaw if first else math.atan2(-step[0], step[1])  # the nose along the leg
        new_yaw = yaw + math.remainder(new_yaw - yaw, 2.0 * math.pi)
        heading[span] = yaw + (new_yaw - yaw) * np.clip(tau * 4.0, 0.0, 1.0) ** 2 * (3.0 - 2.0 * np.clip(
            tau * 4.0, 0.0, 1.0))  # turned in the leg's first quarter
        time += length
        hover = rng.uniform(5.0, 15.0)
        after = (t >= time) & (t < time + hover)
        pos[after] = target
        heading[after] = new_yaw
        time += hover
        here, yaw, first = target, new_yaw, False
    on_ground = (t < 10.0)
    # thrust along body z: z_b along a + g up; the nose (body y) along the heading, levelled
    gravity = normal_gravity(origin.lat_deg, origin.height_m)
    thrust = acc + np.array([0.0, 0.0, gravity])
    z_b = thrust / np.linalg.norm(thrust, axis=1, keepdims=True)
    nose = np.stack([-np.sin(heading), np.cos(heading), np.zeros(n)], axis=1)
    y_b = nose - np.sum(nose * z_b, axis=1, keepdims=True) * z_b
    y_b /= np.linalg.norm(y_b, axis=1, keepdims=True)
    x_b = np.cross(y_b, z_b)
    target_quat = Q.from_rotmat(np.stack([x_b, y_b, z_b], axis=-1))  # columns: body axes in ENU
    return _trajectory(rate_hz, target_quat, lambda quat: vel, origin, on_ground | (np.linalg.norm(vel, axis=1) == 0))


#: The MPU6050 data sheet's white noise (rate noise 0.005 deg/s/sqrt(Hz), accelerometer
#: 400 ug/sqrt(Hz)) and turn-on biases within its zero-rate and zero-g specifications: the
#: sensors of the navigation benchmarks (issue 16).
DATASHEET_GYRO_BIAS = np.radians([0.8, -0.5, 0.6])
DATASHEET_ACC_BIAS = np.array([0.25, -0.3, 0.2])


def datasheet_sensors(rate_hz: float) -> SensorSuite:
    """An MPU6050 as its data sheet describes it, with the turn-on biases above; the HMC5883L's noise."""
    return SensorSuite(gyro=GyroModel(arw=math.radians(0.005), bias_instability=0.0, rrw=0.0,
                                      bias=DATASHEET_GYRO_BIAS),
                       acc=AccModel(noise_std=400e-6 * 9.80665 * math.sqrt(rate_hz / 2.0), bias=DATASHEET_ACC_BIAS),
                       mag=MagModel())


@dataclass
class GnssModel:
    """A receiver's errors. White errors: horizontal (`h_sigma_m`, the 2-D RMS: each of east
    and north gets h_sigma / sqrt 2), vertical and velocity (each axis); time-correlated
    errors: first-order Gauss-Markov with time constant `tau_s` and the given standard
    deviations; `latency_s`: a fix reaches the board that much after the time it is valid
    for; `outages`: (start, end) s without fixes; `multipath`: (start, end, east, north, up)
    m added to the position while it lasts. The reported accuracies (hAcc, vAcc, sAcc) are
    the white and correlated sigmas together, as a receiver's own estimate would be, and
    grow by the multipath jump's size only if `reported_multipath` is set (a receiver often
    does not see it).

    Rough conditions (all off by default; none is in the reported accuracies, which is
    what makes them hard; their random numbers come from streams of their own, so the
    errors above stay the same with them or without):

    - `outlier_fraction`: that share of the fixes (rounded, chosen at random among those
      outside outages) each off by a horizontal distance uniform in `outlier_m` (m) in a
      random direction, and by a vertical one uniform in `outlier_vertical_m` (m) with a
      random sign: single-epoch blunders (a reflected signal taken for the direct one);
    - `velocity_outliers`: (time_s, (east, north, up) m/s): the first fix valid at or
      after that time has its velocity off by the vector (a Doppler blunder);
    - `multipath_episodes`: (start_s, end_s, amplitude_m): a slowly wandering bias (near a
      building, under trees): a Gauss-Markov process of time constant `multipath_tau_s`
      (s), soft-limited (tanh) to at most `amplitude_m` horizontally (the 2-D size) and
      vertically, faded in and out over `multipath_ramp_s` (s) raised-cosine ramps inside
      the episode; a random walk of the receiver's solution rather than a jump;
    - cold start: the first `cold_start_fixes` fixes (outside outages) off by
      `cold_start_offset_m` (east, north, up; m), shrinking as exp(-(t - t_first) /
      `cold_start_tau_s`) (inf: not at all) towards the truth, reporting
      `cold_start_acc_m` (hAcc, vAcc; m; None: the usual accuracies): a receiver with a
      stale almanac or a wrong time whose first solutions are kilometres off, and that
      may well report a small accuracy for them."""
    rate_hz: float = 1.0
    h_sigma_m: float = 2.5
    v_sigma_m: float = 5.0
    vel_sigma_m_s: float = 0.1
    correlated_h_m: float = 0.0
    correlated_v_m: float = 0.0
    tau_s: float = 100.0
    latency_s: float = 0.0
    outages: tuple = ()
    multipath: tuple = ()
    reported_multipath: bool = False
    outlier_fraction: float = 0.0
    outlier_m: tuple[float, float] = (20.0, 50.0)
    outlier_vertical_m: tuple[float, float] = (0.0, 0.0)
    velocity_outliers: tuple = ()
    multipath_episodes: tuple = ()
    multipath_tau_s: float = 10.0
    multipath_ramp_s: float = 5.0
    cold_start_offset_m: tuple = (0.0, 0.0, 0.0)
    cold_start_fixes: int = 0
    cold_start_tau_s: float = math.inf
    cold_start_acc_m: tuple | None = None


@dataclass
class GnssFixes:
    """Fixes in time order: `index` is the IMU sample the fix is valid at (its measurement
    time), `t_valid` that sample's time, `t_arrival` when it reaches the board; position
    as latitude, longitude (deg) and ellipsoidal height (m), and as the truth's `pos_enu`
    plus the error (m); velocity ENU (m/s), the receiver's reported accuracies (m, m/s,
    1 sigma), and the truth at `index`. `flags`: per fix, which rough conditions of the
    GnssModel touch it ("outlier", "velocity_outlier", "multipath" (an episode's bias
    above 1 % of its amplitude), "cold_start"): the truth for an evaluation."""
    index: np.ndarray
    t_valid: np.ndarray
    t_arrival: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    pos_enu: np.ndarray
    vel_enu: np.ndarray
    h_acc_m: np.ndarray
    v_acc_m: np.ndarray
    s_acc_m_s: np.ndarray
    truth_pos_enu: np.ndarray
    truth_vel_enu: np.ndarray
    flags: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.index)


def _gauss_markov(rng: np.random.Generator, n: int, dt: float, tau_s: float, sigma: float) -> np.ndarray:
    """(n,) first-order Gauss-Markov process, stationary with standard deviation `sigma`."""
    if sigma == 0.0:
        return np.zeros(n)
    phi = math.exp(-dt / tau_s)
    drive = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    out = np.empty(n)
    out[0] = rng.standard_normal() * sigma
    for k in range(1, n):
        out[k] = phi * out[k - 1] + drive[k]
    return out


def gnss_fixes(traj: NavTrajectory, model: GnssModel | None = None, seed: int = 0) -> GnssFixes:
    """The fixes a receiver makes along `traj`, at `model.rate_hz` from t = 0 (default: GnssModel())."""
    model = GnssModel() if model is None else model
    rng = np.random.default_rng(seed)
    step = max(1, int(round(traj.rate_hz / model.rate_hz)))
    index = np.arange(0, len(traj), step)
    t = traj.t[index]
    keep = np.ones(len(index), bool)
    for start, end in model.outages:
        keep &= ~((t >= start) & (t < end))
    m = len(index)
    dt = step / traj.rate_hz
    horizontal = model.h_sigma_m / math.sqrt(2.0)
    error = rng.standard_normal((m, 3)) * np.array([horizontal, horizontal, model.v_sigma_m])
    corr_h = model.correlated_h_m / math.sqrt(2.0)
    error += np.stack([_gauss_markov(rng, m, dt, model.tau_s, corr_h), _gauss_markov(rng, m, dt, model.tau_s, corr_h),
                       _gauss_markov(rng, m, dt, model.tau_s, model.correlated_v_m)], axis=1)
    extra = np.zeros((m, 3))
    for start, end, east, north, up in model.multipath:
        extra[(t >= start) & (t < end)] += (east, north, up)
    offset = error + extra  # metres east, north, up at the truth point
    vel = traj.vel_enu[index] + rng.standard_normal((m, 3)) * model.vel_sigma_m_s
    h_acc = np.full(m, math.hypot(model.h_sigma_m, model.correlated_h_m))
    v_acc = np.full(m, math.hypot(model.v_sigma_m, model.correlated_v_m))
    if model.reported_multipath:
        h_acc = np.hypot(h_acc, np.hypot(extra[:, 0], extra[:, 1]))
        v_acc = np.hypot(v_acc, extra[:, 2])
    flags = _rough_conditions(model, seed, t, keep, dt, offset, vel, h_acc, v_acc)
    lat0, lon0, h0 = traj.lat_deg[index], traj.lon_deg[index], traj.height_m[index]
    meridian, prime_vertical = radii(lat0)
    lat = lat0 + np.degrees(offset[:, 1] / (meridian + h0))
    lon = lon0 + np.degrees(offset[:, 0] / ((prime_vertical + h0) * np.cos(np.deg2rad(lat0))))
    h = h0 + offset[:, 2]
    pos = traj.pos_enu[index] + offset
    return GnssFixes(index=index[keep], t_valid=t[keep], t_arrival=t[keep] + model.latency_s, lat_deg=lat[keep],
                     lon_deg=lon[keep], height_m=h[keep], pos_enu=pos[keep], vel_enu=vel[keep], h_acc_m=h_acc[keep],
                     v_acc_m=v_acc[keep], s_acc_m_s=np.full(int(keep.sum()), model.vel_sigma_m_s),
                     truth_pos_enu=traj.pos_enu[index[keep]], truth_vel_enu=traj.vel_enu[index[keep]],
                     flags={name: flag[keep] for name, flag in flags.items()})


def _rough_conditions(model: GnssModel, seed: int, t: np.ndarray, keep: np.ndarray, dt: float, offset: np.ndarray,
                      vel: np.ndarray, h_acc: np.ndarray, v_acc: np.ndarray) -> dict:
    """Apply the model's rough conditions (its docstring) in place to every epoch's
    position error `offset` (m, ENU), velocity `vel` (m/s) and reported accuracies (m),
    `t` the epochs' times (s), `keep` those outside outages, `dt` the fix period (s).
    Returns the flags, per epoch. Each condition draws from its own child of the seed,
    so that none moves the others' numbers nor the white and correlated errors."""
    m = len(t)
    rng_outlier, rng_multipath = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    flags = {name: np.zeros(m, bool) for name in ("outlier", "velocity_outlier", "multipath", "cold_start")}
    kept = np.flatnonzero(keep)
    count = int(round(model.outlier_fraction * len(kept)))
    if count:
        chosen = np.sort(rng_outlier.choice(kept, size=count, replace=False))
        size = rng_outlier.uniform(*model.outlier_m, size=count)
        azimuth = rng_outlier.uniform(0.0, 2.0 * math.pi, size=count)
        up = rng_outlier.uniform(*model.outlier_vertical_m, size=count) * rng_outlier.choice([-1.0, 1.0], size=count)
        offset[chosen] += np.stack([size * np.sin(azimuth), size * np.cos(azimuth), up], axis=1)
        flags["outlier"][chosen] = True
    for time_s, error in model.velocity_outliers:
        after = np.flatnonzero(keep & (t >= time_s - 1e-9))
        if len(after):
            vel[after[0]] += np.asarray(error, dtype=np.float64)
            flags["velocity_outlier"][after[0]] = True
    for start, end, amplitude in model.multipath_episodes:
        # a 2-D Gauss-Markov vector of 2-D RMS `amplitude`, its size soft-limited below it
        x = np.stack([_gauss_markov(rng_multipath, m, dt, model.multipath_tau_s, amplitude / math.sqrt(2.0))
                      for _ in range(2)], axis=1)
        size = np.linalg.norm(x, axis=1)
        limited = amplitude * np.tanh(size / amplitude) / np.where(size > 0.0, size, 1.0)
        up = amplitude * np.tanh(_gauss_markov(rng_multipath, m, dt, model.multipath_tau_s, amplitude) / amplitude)
        ramp = _smooth_window(t, start, end, model.multipath_ramp_s)
        bias = np.c_[x * limited[:, None], up] * ramp[:, None]
        offset += bias
        flags["multipath"] |= np.linalg.norm(bias, axis=1) > 0.01 * amplitude
    if model.cold_start_fixes > 0:
        cold = kept[:model.cold_start_fixes]
        shrink = np.exp(-(t[cold] - t[cold[0]]) / model.cold_start_tau_s)
        offset[cold] += shrink[:, None] * np.asarray(model.cold_start_offset_m, dtype=np.float64)
        if model.cold_start_acc_m is not None:
            h_acc[cold], v_acc[cold] = model.cold_start_acc_m
        flags["cold_start"][cold] = True
    return flags


def antenna_fixes(traj: NavTrajectory, fixes: GnssFixes, arm_m) -> GnssFixes:
    """The fixes of an antenna at `arm_m` (m, sensor frame: x right, y forward, z up) from the
    sensor whose trajectory `traj` is: R l further and, while the body turns at w, R (w x l)
    faster (the errors of `fixes` kept)."""
    arm = np.asarray(arm_m, dtype=np.float64)
    k = fixes.index
    rot = Q.to_rotmat(traj.quat[k])
    offset = np.einsum("nij,j->ni", rot, arm)
    m, n = radii(fixes.lat_deg)
    moved = GnssFixes(**fixes.__dict__)
    moved.lat_deg = fixes.lat_deg + np.degrees(offset[:, 1] / (m + fixes.height_m))
    cos_lat = np.cos(np.radians(fixes.lat_deg))
    moved.lon_deg = fixes.lon_deg + np.degrees(offset[:, 0] / ((n + fixes.height_m) * cos_lat))
    moved.height_m = fixes.height_m + offset[:, 2]
    moved.pos_enu = fixes.pos_enu + offset
    moved.vel_enu = fixes.vel_enu + np.einsum("nij,nj->ni", rot, np.cross(traj.gyr[k], arm))
    return moved


@dataclass
class MarkerFixes:
    """Position fixes from markers at known places ([seed 003]'s QR codes,
    docs/filters.md, Bibliography): `index` the IMU
    sample each is taken at, the geodetic position (deg, m) with its error, the accuracy
    given with it (m, 1 sigma, each axis), and the truth at `index`."""
    index: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    accuracy_m: float
    truth_pos_enu: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


def marker_fixes(traj: NavTrajectory, every_s: float = 60.0, accuracy_m: float = 0.1, seed: int = 0) -> MarkerFixes:
    """A position fix every `every_s` seconds (from the first one at `every_s`), each where
    the body is then, off by white errors of `accuracy_m` on each axis: a marker read as
    one passes it. Position only: no velocity."""
    rng = np.random.default_rng(seed)
    index = np.arange(int(round(every_s * traj.rate_hz)), len(traj), int(round(every_s * traj.rate_hz)))
    error = rng.standard_normal((len(index), 3)) * accuracy_m
    lat0, lon0, h0 = traj.lat_deg[index], traj.lon_deg[index], traj.height_m[index]
    m, n = radii(lat0)
    return MarkerFixes(index=index, lat_deg=lat0 + np.degrees(error[:, 1] / (m + h0)),
                       lon_deg=lon0 + np.degrees(error[:, 0] / ((n + h0) * np.cos(np.deg2rad(lat0)))),
                       height_m=h0 + error[:, 2], accuracy_m=accuracy_m, truth_pos_enu=traj.pos_enu[index])


#: The International Standard Atmosphere's troposphere: sea-level pressure (Pa) and
#: temperature (K), lapse rate (K/m), g0 M / (R L).
ISA_P0, ISA_T0, ISA_LAPSE = 101_325.0, 288.15, 0.0065
ISA_EXPONENT = 9.80665 * 0.0289644 / (8.3144598 * 0.0065)


def pressure_at(height_m, sea_level_pa=ISA_P0) -> np.ndarray:
    """ISA pressure (Pa) at a height (m, taken as geopotential height above mean sea level)."""
    return sea_level_pa * (1.0 - ISA_LAPSE * np.asarray(height_m, dtype=np.float64) / ISA_T0) ** ISA_EXPONENT


def height_at(pressure_pa, sea_level_pa=ISA_P0) -> np.ndarray:
    """The inverse of :func:`pressure_at`."""
    return ISA_T0 / ISA_LAPSE * (1.0 - (np.asarray(pressure_pa, dtype=np.float64) / sea_level_pa)
                                 ** (1.0 / ISA_EXPONENT))


@dataclass
class BaroModel:
    """A barometer (defaults: the MS5611 at OSR 4096). White pressure noise (Pa; the data
    sheet's 0.012 mbar resolution), a pressure error per kelvin of the sensor's temperature
    change (its second-order compensation leaves some), the sensor's temperature (a slow
    drift from `temperature_c` by `temperature_drift_c` over the run, a cosine), and the
    weather: the sea-level pressure a random walk of `weather_pa_per_sqrt_h`."""
    rate_hz: float = 50.0
    noise_pa: float = 1.2
    temperature_c: float = 25.0
    temperature_drift_c: float = 5.0
    pa_per_kelvin: float = 0.5
    weather_pa_per_sqrt_h: float = 30.0
    geoid_sep_m: float = 47.0


@dataclass
class BaroSamples:
    """Samples in time order: `index` the IMU sample each is taken at, pressure (Pa),
    temperature (degC), and the truth height above the ellipsoid at `index` (m)."""
    index: np.ndarray
    t: np.ndarray
    pressure_pa: np.ndarray
    temperature_c: np.ndarray
    truth_height_m: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


def baro_samples(traj: NavTrajectory, model: BaroModel | None = None, seed: int = 0) -> BaroSamples:
    """A barometer along `traj`: ISA pressure at the vehicle's height above mean sea level
    (ellipsoidal height minus the geoid separation), plus the model's errors (default:
    BaroModel())."""
    model = BaroModel() if model is None else model
    rng = np.random.default_rng(seed)
    step = max(1, int(round(traj.rate_hz / model.rate_hz)))
    index = np.arange(0, len(traj), step)
    t = traj.t[index]
    height = traj.height_m[index]
    duration_h = max(traj.duration_s, 1e-9) / 3600.0
    weather = np.cumsum(rng.standard_normal(len(index))) * model.weather_pa_per_sqrt_h * math.sqrt(
        duration_h / len(index))
    temperature = model.temperature_c + model.temperature_drift_c * 0.5 * (1.0 - np.cos(
        math.pi * t / max(traj.duration_s, 1e-9)))
    pressure = (pressure_at(height - model.geoid_sep_m, ISA_P0 + weather)
                + model.pa_per_kelvin * (temperature - model.temperature_c)
                + rng.standard_normal(len(index)) * model.noise_pa)
    return BaroSamples(index=index, t=t, pressure_pa=pressure, temperature_c=temperature, truth_height_m=height)
