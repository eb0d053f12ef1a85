"""Exact IMU commands and truth from a motion profile (the estimators' discrete model).

Navigation model (shared with factors/ and baseline/, GTSAM's with omegaCoriolis = w_ie):
local ENU at the origin (an Earth-fixed Cartesian frame), gravity g_n(p) where the vehicle is
(fgins.geodesy.gravity_enu: a round Earth; (0, 0, -normal_gravity(lat0, h0)) at the origin),
constant Earth rate w_ie in ENU. Each IMU sample is held over [t_k, t_k+1) and propagated as

    R_k+1 = R_k Exp((gyro_k - R_k^T w_ie) dt)
    a_n   = R_k accel_k + g_n(p_k) - 2 w_ie x v_k
    p_k+1 = p_k + v_k dt + a_n dt^2 / 2,   v_k+1 = v_k + a_n dt

The commands are solved from the profile's attitude and velocity at consecutive samples, so
propagating them reproduces those samples to rounding error; the truth returned here *is*
that propagation (evaluated in closed form, vectorised; :func:`mechanize` is the step-by-step
reference the tests compare against).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import InputError, Origin
from fgins.geodesy import earth_rate_enu, gravity_enu, normal_gravity, so3_exp
from fgins.sim.motion import MotionProfile


@dataclass(frozen=True)
class NavModel:
    """Gravity and Earth rate of the local ENU frame at ``origin``; with ``origin``, gravity
    where the vehicle is (a round Earth, :func:`fgins.geodesy.gravity_enu`)."""

    gravity: np.ndarray
    earth_rate: np.ndarray
    origin: Origin | None = None

    @classmethod
    def at(cls, origin: Origin, with_earth_rate: bool = True) -> NavModel:
        gravity = np.array([0.0, 0.0, -normal_gravity(origin.lat, origin.alt)])
        rate = earth_rate_enu(origin.lat) if with_earth_rate else np.zeros(3)
        return cls(gravity=gravity, earth_rate=rate, origin=origin)

    def gravity_at(self, position: np.ndarray) -> np.ndarray:
        """Gravity (..., 3) at ENU positions (..., 3)."""
        if self.origin is None:
            return np.broadcast_to(self.gravity, np.shape(position))
        return gravity_enu(position, self.origin)


@dataclass
class ExactMotion:
    """Truth at the IMU times and the error-free IMU samples held over [t_k, t_k+1)."""

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray


def rotation_log(r: np.ndarray) -> np.ndarray:
    """SO(3) log, vectorised, accurate for the tiny per-sample rotations (uses atan2)."""
    v = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    sin2 = np.linalg.norm(v, axis=-1)  # 2 sin(angle)
    cos2 = np.trace(r, axis1=-2, axis2=-1) - 1.0  # 2 cos(angle)
    angle = np.arctan2(sin2, cos2)
    small = sin2 < 1e-12
    factor = np.where(small, 0.5, angle / np.where(small, 1.0, sin2))
    if np.any(angle > np.pi - 1e-6):
        raise InputError("strapdown: a rotation of ~180 degrees within one IMU sample")
    return v * factor[..., None]


def exact_motion(
    profile: MotionProfile, nav: NavModel, imu_axes: np.ndarray | None = None
) -> ExactMotion:
    """IMU commands that make the discrete mechanization follow ``profile`` exactly.

    ``imu_axes`` (3x3) maps IMU-axis vectors into the profile's body axes (x forward, y left,
    z up); the IMU's attitude is then ``profile.rotation() @ imu_axes`` and its samples and the
    truth rotation are in the IMU's axes (FRD: diag(1, -1, -1); a mounting: F R_vehicle_imu).
    The commands are solved from that rotation sequence itself, so they stay exact (and
    consistent with GTSAM's preintegration) whatever the axes. Position and velocity are the
    IMU's (it sits at the profile's reference point).

    The last profile sample only closes the last IMU interval: truth and IMU have
    ``len(profile) - 1`` samples.
    """
    if len(profile) < 3:
        raise InputError("strapdown: the profile needs at least 3 samples")
    dt_all = np.diff(profile.t)
    dt = float(dt_all[0])
    if not np.allclose(dt_all, dt, rtol=1e-9, atol=0.0):
        raise InputError("strapdown: the profile must be sampled uniformly")
    rotation = profile.rotation()
    if imu_axes is not None:
        axes = np.asarray(imu_axes, dtype=float)
        if axes.shape != (3, 3) or not np.allclose(axes.T @ axes, np.eye(3), atol=1e-9):
            raise InputError("strapdown: imu_axes must be a 3x3 rotation or axis permutation")
        rotation = rotation @ axes
    velocity = profile.velocity()
    r_k, r_next = rotation[:-1], rotation[1:]
    v_k, v_next = velocity[:-1], velocity[1:]
    r_k_t = np.swapaxes(r_k, -1, -2)
    # Body rate relative to the navigation frame that takes R_k exactly onto R_k+1 (in
    # blocks: the (N, 3, 3) temporaries of the log stay small on hour-long drives).
    w_nb = np.empty((len(r_k), 3))
    block = 100_000
    for i in range(0, len(r_k), block):
        w_nb[i : i + block] = rotation_log(r_k_t[i : i + block] @ r_next[i : i + block]) / dt
    gyro = w_nb + r_k_t @ nav.earth_rate
    a_n = (v_next - v_k) / dt
    steps = v_k * dt + 0.5 * a_n * dt**2
    position = np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    specific_force_n = a_n - nav.gravity_at(position[:-1]) + 2.0 * np.cross(nav.earth_rate, v_k)
    accel = np.einsum("nji,nj->ni", r_k, specific_force_n)
    return ExactMotion(
        t=profile.t[:-1].copy(),
        position=position[:-1],
        velocity=v_k.copy(),
        rotation=r_k.copy(),
        gyro=gyro,
        accel=accel,
    )


def mechanize(
    t: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    rotation0: np.ndarray,
    velocity0: np.ndarray,
    position0: np.ndarray,
    nav: NavModel,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step-by-step reference propagation (slow Python loop): rotations, velocities, positions
    at every sample time (sample k's command is held until t_k+1)."""
    n = len(t)
    rotations = np.empty((n, 3, 3))
    velocities = np.empty((n, 3))
    positions = np.empty((n, 3))
    r, v, p = np.array(rotation0, float), np.array(velocity0, float), np.array(position0, float)
    for k in range(n):
        rotations[k], velocities[k], positions[k] = r, v, p
        if k == n - 1:
            break
        dt = t[k + 1] - t[k]
        a_n = r @ accel[k] + nav.gravity_at(p) - 2.0 * np.cross(nav.earth_rate, v)
        p = p + v * dt + 0.5 * a_n * dt**2
        v = v + a_n * dt
        r = r @ so3_exp((gyro[k] - r.T @ nav.earth_rate) * dt)
    return rotations, velocities, positions
