"""A compact independent flight simulator for tests (shares no code with fgins.sim).

ENU axes at the origin (an Earth-fixed Cartesian frame), normal gravity where the vehicle is
(a round Earth: :mod:`round_earth`, through pymap3d) and Earth rate. IMU samples are the
instantaneous ``gyro = vee(R^T dR/dt) + R^T w_ie`` and ``accel = R^T (a - g(p) + 2 w_ie x v)`` (4th-order central differences of analytic motion),
plus turn-on biases and white noise; GNSS fixes carry position and velocity with their sigmas.

- :class:`Multirotor`: smooth (C3) moves in any direction, yaw independent of them, body z
  along the thrust (tilted toward the acceleration): the motion fgins's own simulator lacks.
- :class:`FixedWing`: speed, course and flight-path angle; wind axes with sideslip zero, so
  turns are coordinated and banked.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pymap3d
import round_earth

OMEGA_E = 7.292115e-5
WGS_A, WGS_F = 6378137.0, 1 / 298.257223563
STEP = 1e-3
D2R = np.pi / 180
# industrial MEMS: ARW deg/sqrt(h), turn-on deg/h, VRW m/s/sqrt(h), turn-on mg
INDUSTRIAL = dict(preset="industrial-mems", arw=0.15, gon=150.0, vrw=0.05, aon=3.0)


def normal_gravity(lat_deg: float, h: float) -> float:
    e2 = WGS_F * (2 - WGS_F)
    s2 = np.sin(lat_deg * D2R) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - e2 * s2)
    m = 0.00344978650684
    return g0 * (1 - 2 / WGS_A * (1 + WGS_F + m - 2 * WGS_F * s2) * h + 3 / WGS_A**2 * h * h)


def _diff(f, t, h=STEP):
    return (f(t - 2 * h) - 8 * f(t - h) + 8 * f(t + h) - f(t + 2 * h)) / (12 * h)


def _vee(m):
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
    )


def _step7(u):
    u = np.clip(u, 0.0, 1.0)
    return u**4 * (35 - 84 * u + 70 * u**2 - 20 * u**3)


def _step5(u):
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10 - 15 * u + 6 * u * u)


def _step5_integral(u):
    c = np.clip(u, 0, 1)
    return np.where(u > 1, u - 0.5, np.where(u < 0, 0.0, c**6 - 3 * c**5 + 2.5 * c**4))


@dataclass
class Multirotor:
    """moves: (start s, duration s, [dE, dN, dU] m); yaws: (start, duration, turn rad, CCW)."""

    heading0_deg: float
    moves: list
    yaws: list
    g: float = 9.8

    def position(self, t):
        out = np.zeros((*np.shape(t), 3))
        for start, duration, d in self.moves:
            out = out + _step7((t - start) / duration)[..., None] * np.asarray(d, float)
        return out

    def velocity(self, t):
        out = np.zeros((*np.shape(t), 3))
        for start, duration, d in self.moves:
            u = np.clip((t - start) / duration, 0, 1)
            out = out + (140 * u**3 * (1 - u) ** 3 / duration)[..., None] * np.asarray(d, float)
        return out

    def rotation(self, t):
        thrust = _diff(self.velocity, t) + np.array([0, 0, self.g])
        z = thrust / np.linalg.norm(thrust, axis=-1, keepdims=True)
        yaw = np.radians(90 - self.heading0_deg) + 0 * np.asarray(t, float)
        for start, duration, turn in self.yaws:
            yaw = yaw + turn * _step7((t - start) / duration)
        x = np.stack([np.cos(yaw), np.sin(yaw), 0 * yaw], -1)
        x = x - np.sum(x * z, -1, keepdims=True) * z
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        return np.stack([x, np.cross(z, x), z], -1)


@dataclass
class FixedWing:
    """Constant speed; turns: (start, end, ramp s, course rate rad/s, CCW); climbs: (start,
    end, ramp, flight-path angle rad)."""

    speed: float
    heading0_deg: float
    turns: list = field(default_factory=list)
    climbs: list = field(default_factory=list)
    g: float = 9.8

    def _angles(self, t):
        t = np.asarray(t, float)
        course = np.radians(90 - self.heading0_deg) + 0 * t
        for start, end, ramp, rate in self.turns:
            course = course + rate * ramp * (
                _step5_integral((t - start) / ramp) - _step5_integral((t - end) / ramp)
            )
        gamma = 0 * t
        for start, end, ramp, angle in self.climbs:
            gamma = gamma + angle * (_step5((t - start) / ramp) - _step5((t - end) / ramp))
        return course, gamma

    def _direction(self, t):
        c, g = self._angles(t)
        return np.stack([np.cos(g) * np.cos(c), np.cos(g) * np.sin(c), np.sin(g)], -1)

    def velocity(self, t):
        return self.speed * self._direction(t)

    def rotation(self, t):
        x = self._direction(t)
        force = _diff(self.velocity, t) + np.array([0, 0, self.g])
        z = force - np.sum(force * x, -1, keepdims=True) * x
        z /= np.linalg.norm(z, axis=-1, keepdims=True)
        return np.stack([x, np.cross(z, x), z], -1)


def write_flight(folder: Path, motion, duration_s: float, *, seed: int, frame: str = "flu",
                 vehicle: str = "uav", imu_rate: float = 100.0, gnss_rate: float = 5.0,
                 sigma_h: float = 1.0, sigma_u: float = 2.0, sigma_v: float = 0.1,
                 lat0: float = 47.0, lon0: float = 8.0, alt0: float = 400.0) -> Path:  # fmt: skip
    """imu.csv, gnss.csv (position + velocity), truth.csv and config.toml in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    g = normal_gravity(lat0, alt0)
    motion.g = g
    w_ie = OMEGA_E * np.array([0, np.cos(lat0 * D2R), np.sin(lat0 * D2R)])
    n = round(duration_s * imu_rate) + 1
    t = np.arange(n) / imu_rate
    v, rot = motion.velocity(t), motion.rotation(t)
    if hasattr(motion, "position"):
        p = motion.position(t)
    else:  # Simpson's rule on the IMU grid
        mid = motion.velocity(t[:-1] + 0.5 / imu_rate)
        p = np.vstack([np.zeros(3), np.cumsum((v[:-1] + 4 * mid + v[1:]) / (6 * imu_rate), 0)])
    rot_dot = _diff(motion.rotation, t, 2 * STEP)
    gyro = _vee(np.einsum("nji,njk->nik", rot, rot_dot)) + np.einsum("nji,j->ni", rot, w_ie)
    force = _diff(motion.velocity, t) - round_earth.gravity(p, lat0, lon0, alt0) + 2 * np.cross(w_ie, v)
    accel = np.einsum("nji,nj->ni", rot, force)
    flip = np.diag([1.0, -1.0, -1.0]) if frame == "frd" else np.eye(3)
    rot, gyro, accel = rot @ flip, gyro @ flip, accel @ flip
    grade = INDUSTRIAL
    gyro_white = grade["arw"] * D2R / 60  # rad/s/sqrt(Hz)
    accel_white = grade["vrw"] / 60
    gyro = gyro + rng.normal(0, grade["gon"] * D2R / 3600, 3)
    gyro = gyro + rng.normal(0, gyro_white * np.sqrt(imu_rate), gyro.shape)
    accel = accel + rng.normal(0, grade["aon"] * 1e-3 * 9.80665, 3)
    accel = accel + rng.normal(0, accel_white * np.sqrt(imu_rate), accel.shape)
    np.savetxt(folder / "imu.csv", np.column_stack([t, gyro, accel]), delimiter=",",
               fmt="%.6f," + ",".join(["%.10e"] * 6),
               header="time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z", comments="")  # fmt: skip
    every = round(imu_rate / gnss_rate)
    k = np.arange(0, n, every)
    fixes = p[k] + rng.normal(0, 1, (len(k), 3)) * [sigma_h, sigma_h, sigma_u]
    vel = v[k] + rng.normal(0, sigma_v, (len(k), 3))
    # A receiver's velocity is in the local level where it is.
    vel = np.einsum("nji,nj->ni", round_earth.local_axes(fixes, lat0, lon0, alt0), vel)
    lat, lon, alt = pymap3d.enu2geodetic(*fixes.T, lat0, lon0, alt0)
    sig = np.tile([sigma_h, sigma_h, sigma_u], (len(k), 1))
    np.savetxt(folder / "gnss.csv", np.column_stack([t[k], lat, lon, alt, vel, sig]),
               delimiter=",", fmt="%.10f",
               header="time,lat,lon,alt,vel_east,vel_north,vel_up,std_east,std_north,std_up",
               comments="")  # fmt: skip
    # Truth velocity and attitude in the local level at each point, as a reference gives them.
    axes = round_earth.local_axes(p, lat0, lon0, alt0)
    v = np.einsum("nji,nj->ni", axes, v)
    r = np.swapaxes(axes, 1, 2) @ rot
    roll = np.degrees(np.arctan2(r[:, 2, 1], r[:, 2, 2]))
    pitch = np.degrees(np.arcsin(np.clip(r[:, 2, 0], -1, 1)))
    heading = np.mod(90 - np.degrees(np.arctan2(r[:, 1, 0], r[:, 0, 0])), 360)
    tlat, tlon, talt = pymap3d.enu2geodetic(*p.T, lat0, lon0, alt0)
    np.savetxt(folder / "truth.csv",
               np.column_stack([t, tlat, tlon, talt, p, v, roll, pitch, heading]), delimiter=",",
               fmt="%.10f",
               header="time,lat,lon,alt,east,north,up,vel_east,vel_north,vel_up,roll_deg,"
               "pitch_deg,heading_deg", comments="")  # fmt: skip
    mounting = "[180.0, 0.0, 0.0]" if frame == "frd" else "[0.0, 0.0, 0.0]"
    (folder / "config.toml").write_text(
        f'[imu]\npreset = "{grade["preset"]}"\n'
        f"gyro_noise_rad_per_s_per_sqrt_hz = {gyro_white}\n"
        f"accel_noise_m_per_s2_per_sqrt_hz = {accel_white}\n"
        f"gyro_turn_on_bias_deg_per_s = {grade['gon'] / 3600}\n"
        f"accel_turn_on_bias_mg = {grade['aon']}\n"
        "gyro_bias_instability_deg_per_hr = 0\naccel_bias_instability_mg = 0\n"
        f"rate_hz = {imu_rate}\n\n"
        f"[gnss]\nsigma_m = [{sigma_h}, {sigma_h}, {sigma_u}]\n"
        f"velocity_sigma_m_per_s = {sigma_v}\n\n"
        f'[smoother]\nvehicle = "{vehicle}"\nimu_to_vehicle_rpy_deg = {mounting}\n\n'
        f"[origin]\nlat = {lat0}\nlon = {lon0}\nalt = {alt0}\n"
    )
    return folder
