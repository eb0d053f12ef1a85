"""Geodesy and attitude helpers (WGS-84, local ENU), numpy only."""

from __future__ import annotations

import functools
import math
from typing import Protocol

import numpy as np
import pymap3d


class Origin(Protocol):
    """Anything with ``lat``, ``lon`` (deg) and ``alt`` (ellipsoidal m), e.g.
    :class:`fgins.datatypes.Origin`. A protocol, not an import, so that ``geodesy`` (numpy
    only) does not depend on the data model that uses it."""

    lat: float
    lon: float
    alt: float


WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
EARTH_RATE = 7.292115e-5  # rad/s


def lla_to_enu(lla: np.ndarray, origin: Origin) -> np.ndarray:
    """Geodetic (deg, deg, ellipsoidal m) rows -> local ENU metres at ``origin``."""
    lla = np.atleast_2d(lla)
    e, n, u = pymap3d.geodetic2enu(
        lla[:, 0], lla[:, 1], lla[:, 2], origin.lat, origin.lon, origin.alt
    )
    return np.column_stack([e, n, u])


def enu_to_lla(enu: np.ndarray, origin: Origin) -> np.ndarray:
    """Local ENU metres at ``origin`` -> geodetic (deg, deg, ellipsoidal m) rows."""
    enu = np.atleast_2d(enu)
    lat, lon, alt = pymap3d.enu2geodetic(
        enu[:, 0], enu[:, 1], enu[:, 2], origin.lat, origin.lon, origin.alt
    )
    return np.column_stack([lat, lon, alt])


def plane_fall(enu: np.ndarray, origin: Origin) -> np.ndarray:
    """How far (m) the up coordinate of each ENU point lies below its ellipsoidal height
    above the origin's: the origin's tangent plane falls away from the surface, about
    d^2 / 2r d away (7.8 m 10 km out, 80 m 32 km out), so a height that stays with the
    surface (a barometer's) is ``up + fall`` in the navigation frame's terms.

    ``sqrt(r^2 + d^2) - r`` with r the normal section's radius of curvature in the point's
    direction (Euler: 1/r = cos^2(az)/M + sin^2(az)/N at the origin) plus the heights: within
    1.4 mm of the exact ellipsoidal value 32 km out, 4 cm 100 km out, and smooth (a Kalman
    Jacobian's finite differences see no conversion noise, as they would through ECEF).
    """
    enu = np.atleast_2d(np.asarray(enu, dtype=float))
    east, north, up = enu[:, 0], enu[:, 1], enu[:, 2]
    sin_lat = math.sin(math.radians(origin.lat))
    w = 1.0 - WGS84_E2 * sin_lat**2
    meridian, prime = WGS84_A * (1.0 - WGS84_E2) / w**1.5, WGS84_A / math.sqrt(w)
    d2 = east**2 + north**2
    bent = north**2 / meridian + east**2 / prime  # d^2 times the curvature along the line
    radius = np.where(d2 > 0, d2 / np.where(bent > 0, bent, 1.0), math.sqrt(meridian * prime))
    radius = radius + origin.alt + up
    return d2 / (np.sqrt(radius**2 + d2) + radius)  # sqrt(r^2 + d^2) - r, without cancelling


EARTH_MEAN_RADIUS_M = 6.371e6


def normal_gravity(lat_deg: float, height_m: float = 0.0) -> float:
    """WGS-84 normal gravity magnitude (Somigliana, with the free-air height correction)."""
    s2 = np.sin(np.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - WGS84_E2 * s2)
    # Second-order free-air correction (Moritz / NIMA TR8350.2).
    return float(
        g0
        * (
            1
            - 2 / WGS84_A * (1 + WGS84_F + 0.00344978650684 - 2 * WGS84_F * s2) * height_m
            + 3 / WGS84_A**2 * height_m**2
        )
    )


def _normal_gravity_array(lat_rad: np.ndarray, height_m: np.ndarray) -> np.ndarray:
    """:func:`normal_gravity` over arrays (latitude in radians)."""
    s2 = np.sin(lat_rad) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - WGS84_E2 * s2)
    return g0 * (
        1
        - 2 / WGS84_A * (1 + WGS84_F + 0.00344978650684 - 2 * WGS84_F * s2) * height_m
        + 3 / WGS84_A**2 * height_m**2
    )


def ecef_to_enu_rotation(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float) -> np.ndarray:
    """Rotations (..., 3, 3) whose rows are east, north, up at (lat, lon) in ECEF axes:
    ``v_enu = R @ v_ecef``."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    return np.stack(
        [
            np.stack([-so + zero, co + zero, zero], axis=-1),
            np.stack([-sl * co, -sl * so, cl + zero], axis=-1),
            np.stack([cl * co, cl * so, sl + zero], axis=-1),
        ],
        axis=-2,
    )


def local_to_origin_rotation(lat_deg: np.ndarray, lon_deg: np.ndarray, origin: Origin) -> np.ndarray:
    """Rotations (N, 3, 3) taking vectors in the local ENU axes at each (lat, lon) into the
    origin's ENU axes (the navigation frame): ``v_nav = R @ v_local``.

    Velocities and attitudes of a receiver or a reference are given in the local level at
    the point; the navigation frame is the level at the origin. 20 km away they differ by
    0.18 deg (0.3 m/s of a 100 m/s velocity turned into the vertical).
    """
    at_origin = ecef_to_enu_rotation(origin.lat, origin.lon)
    local = ecef_to_enu_rotation(np.atleast_1d(lat_deg), np.atleast_1d(lon_deg))
    return at_origin @ np.swapaxes(local, -1, -2)


def vectors_local_to_nav(lla: np.ndarray, vectors: np.ndarray, origin: Origin) -> np.ndarray:
    """ENU vectors (N, 3) given in the local level at each point ``lla`` (N, 3; a
    receiver's velocity) in the navigation frame (the origin's ENU). A NaN component (a
    receiver without vertical velocity) is rotated as 0 and stays NaN."""
    rotation = local_to_origin_rotation(lla[:, 0], lla[:, 1], origin)
    return _rotated(rotation, vectors)


def vectors_nav_to_local(lla: np.ndarray, vectors: np.ndarray, origin: Origin) -> np.ndarray:
    """The inverse of :func:`vectors_local_to_nav`."""
    rotation = local_to_origin_rotation(lla[:, 0], lla[:, 1], origin)
    return _rotated(np.swapaxes(rotation, -1, -2), vectors)


def _rotated(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    vectors = np.asarray(vectors, dtype=float)
    missing = ~np.isfinite(vectors)
    out = np.einsum("nij,nj->ni", rotation, np.where(missing, 0.0, vectors))
    out[missing] = np.nan
    return out


def _geodetic_from_ecef(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(latitude, longitude in radians, ellipsoidal height) of ECEF points (..., 3): Bowring's
    closed form, one iteration (sub-millimetre below 10 km of height); numpy, so a
    per-block call costs microseconds, not pymap3d's ~0.1 ms."""
    b = WGS84_A * math.sqrt(1.0 - WGS84_E2)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    p = np.hypot(x[..., 0], x[..., 1])
    theta = np.arctan2(x[..., 2] * WGS84_A, p * b)
    lat = np.arctan2(
        x[..., 2] + ep2 * b * np.sin(theta) ** 3, p - WGS84_E2 * WGS84_A * np.cos(theta) ** 3
    )
    sin_lat = np.sin(lat)
    height = p * np.cos(lat) + x[..., 2] * sin_lat - WGS84_A * np.sqrt(1 - WGS84_E2 * sin_lat**2)
    return lat, np.arctan2(x[..., 1], x[..., 0]), height


@functools.lru_cache(maxsize=64)
def _origin_frame(lat: float, lon: float, alt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origin in ECEF, ECEF -> ENU rotation, gravity's correction at the origin) of an
    origin: computed once, as gravity is asked for per filter block (~10 us a call)."""
    x0 = np.array(pymap3d.geodetic2ecef(lat, lon, alt), dtype=float)
    to_enu = ecef_to_enu_rotation(lat, lon)
    lat_r, lon_r, height = _geodetic_from_ecef(x0)
    up = np.array([np.cos(lat_r) * np.cos(lon_r), np.cos(lat_r) * np.sin(lon_r), np.sin(lat_r)])
    formula = -float(_normal_gravity_array(lat_r, height)) * (to_enu @ up)
    correction = np.array([0.0, 0.0, -normal_gravity(lat, alt)]) - formula
    return x0, to_enu, correction


def _gravity_formula(position_enu: np.ndarray, origin: Origin) -> np.ndarray:
    """Normal gravity at ENU positions: along the local vertical (the ellipsoid's normal)
    through the point, its magnitude at that latitude and height."""
    x0, to_enu, _ = _origin_frame(float(origin.lat), float(origin.lon), float(origin.alt))
    lat, lon, height = _geodetic_from_ecef(x0 + position_enu @ to_enu)  # ENU -> ECEF: R^T p
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    return -_normal_gravity_array(lat, height)[..., None] * (up @ to_enu.T)


def gravity_enu(position_enu: np.ndarray, origin: Origin) -> np.ndarray:
    """Normal gravity vectors (..., 3) at ENU positions (..., 3) of the origin's frame.

    The navigation frame is the flat tangent plane at the origin: an Earth-fixed Cartesian
    frame, exact as long as gravity is taken where the vehicle is. Gravity there leans
    towards the Earth's centre by the angle the distance subtends (1.5 mg of horizontal
    acceleration 10 km away; an aircraft 64 km out drifted 22 m in an outage on the origin's
    gravity) and weakens by 0.3 mg per 1000 m of height. At the origin this is exactly
    ``(0, 0, -normal_gravity(origin.lat, origin.alt))`` (the formula's sub-microgal
    difference from it there is taken out), so a drive near its origin sees the same gravity
    as before.
    """
    position = np.asarray(position_enu, dtype=float)
    _, _, correction = _origin_frame(float(origin.lat), float(origin.lon), float(origin.alt))
    return _gravity_formula(position, origin) + correction


def earth_rate_enu(lat_deg: float) -> np.ndarray:
    """Earth rotation rate expressed in the local ENU frame (rad/s)."""
    lat = np.radians(lat_deg)
    return EARTH_RATE * np.array([0.0, np.cos(lat), np.sin(lat)])


def rotation_to_roll_pitch_heading(rotation: np.ndarray) -> np.ndarray:
    """Body-to-ENU rotations (N,3,3) -> roll, pitch, heading in degrees (N,3).

    Body axes x forward, y left, z up. Roll is positive right side down, pitch positive nose
    up, heading from north clockwise in [0, 360).
    """
    r = np.asarray(rotation).reshape(-1, 3, 3)
    roll = np.degrees(np.arctan2(r[:, 2, 1], r[:, 2, 2]))
    pitch = np.degrees(np.arcsin(np.clip(r[:, 2, 0], -1.0, 1.0)))
    yaw = np.degrees(np.arctan2(r[:, 1, 0], r[:, 0, 0]))
    heading = np.mod(90.0 - yaw, 360.0)
    return np.column_stack([roll, pitch, heading])


def roll_pitch_heading_to_rotation(
    roll_deg: float, pitch_deg: float, heading_deg: float
) -> np.ndarray:
    """Inverse of :func:`rotation_to_roll_pitch_heading` for one attitude (3,3)."""
    roll, pitch, yaw = np.radians([roll_deg, -pitch_deg, 90.0 - heading_deg])
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix of a 3-vector."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def skew_batch(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors (..., 3) -> (..., 3, 3)."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def triad(
    body_first: np.ndarray, body_second: np.ndarray, nav_first: np.ndarray, nav_second: np.ndarray
) -> np.ndarray:
    """TRIAD: the body -> nav rotation that maps ``body_first`` onto ``nav_first`` exactly
    and ``body_second`` onto ``nav_second`` as well as the first allows; vectorised over
    leading axes ((..., 3) each -> (..., 3, 3))."""

    def frames(first: np.ndarray, second: np.ndarray) -> np.ndarray:
        e1 = first / np.maximum(np.linalg.norm(first, axis=-1, keepdims=True), 1e-300)
        e2 = np.cross(e1, second)
        e2 = e2 / np.maximum(np.linalg.norm(e2, axis=-1, keepdims=True), 1e-300)
        return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)

    body = frames(np.asarray(body_first, float), np.asarray(body_second, float))
    nav = frames(np.asarray(nav_first, float), np.asarray(nav_second, float))
    return nav @ np.swapaxes(body, -1, -2)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, vectorised over leading axes: (..., 3) -> (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    if phi.shape == (3,):
        return _so3_exp_one(phi)
    squared = np.einsum("...i,...i->...", phi, phi)
    angle = np.sqrt(squared)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - squared / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - squared / 24.0, (1.0 - np.cos(safe)) / safe**2)
    # I + a [phi]x + b [phi]x^2 with [phi]x^2 = phi phi^T - |phi|^2 I: elementwise, no
    # batched 3x3 matmul (this runs for every IMU sample in the Kalman baselines).
    ap = a[..., None] * phi
    out = b[..., None, None] * (phi[..., :, None] * phi[..., None, :])
    diagonal = 1.0 - b * squared
    out[..., 0, 0] += diagonal
    out[..., 1, 1] += diagonal
    out[..., 2, 2] += diagonal
    out[..., 0, 1] -= ap[..., 2]
    out[..., 0, 2] += ap[..., 1]
    out[..., 1, 2] -= ap[..., 0]
    out[..., 1, 0] += ap[..., 2]
    out[..., 2, 0] -= ap[..., 1]
    out[..., 2, 1] += ap[..., 0]
    return out


def _so3_exp_one(phi: np.ndarray) -> np.ndarray:
    """:func:`so3_exp` of one rotation vector, in Python floats (no array overhead)."""
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    squared = x * x + y * y + z * z
    if squared < 1e-16:
        a, b = 1.0 - squared / 6.0, 0.5 - squared / 24.0
    else:
        angle = math.sqrt(squared)
        a, b = math.sin(angle) / angle, (1.0 - math.cos(angle)) / squared
    d = 1.0 - b * squared
    return np.array(
        [
            [d + b * x * x, b * x * y - a * z, b * x * z + a * y],
            [b * y * x + a * z, d + b * y * y, b * y * z - a * x],
            [b * z * x - a * y, b * z * y + a * x, d + b * z * z],
        ]
    )


def so3_log(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> rotation vectors (..., 3) (angles below pi)."""
    r = np.asarray(r, dtype=float)
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    v = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    s = np.sin(angle)
    factor = np.where(angle < 1e-8, 0.5, angle / (2.0 * np.where(angle < 1e-8, 1.0, s)))
    return v * factor[..., None]


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) -> unit quaternions (N, 4) as x, y, z, w (w >= 0).

    Shepperd's method: branch on the largest of w, x, y, z so the square root never sees a
    near-zero argument.
    """
    r = np.asarray(rotation, dtype=float).reshape(-1, 3, 3)
    trace = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    diag = np.stack([r[:, 0, 0], r[:, 1, 1], r[:, 2, 2], trace], axis=1)
    branch = np.argmax(diag, axis=1)
    q = np.empty((r.shape[0], 4))
    for k in range(4):
        sel = branch == k
        if not np.any(sel):
            continue
        m = r[sel]
        if k == 3:  # w largest
            s = 2.0 * np.sqrt(1.0 + trace[sel])
            q[sel] = np.column_stack(
                [
                    (m[:, 2, 1] - m[:, 1, 2]) / s,
                    (m[:, 0, 2] - m[:, 2, 0]) / s,
                    (m[:, 1, 0] - m[:, 0, 1]) / s,
                    0.25 * s,
                ]
            )
            continue
        i, j, l = k, (k + 1) % 3, (k + 2) % 3
        s = 2.0 * np.sqrt(np.clip(1.0 + m[:, i, i] - m[:, j, j] - m[:, l, l], 0.0, None))
        part = np.empty((m.shape[0], 4))
        part[:, i] = 0.25 * s
        part[:, j] = (m[:, j, i] + m[:, i, j]) / s
        part[:, l] = (m[:, l, i] + m[:, i, l]) / s
        part[:, 3] = (m[:, l, j] - m[:, j, l]) / s
        q[sel] = part
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q * np.where(q[:, 3:4] < 0, -1.0, 1.0)
