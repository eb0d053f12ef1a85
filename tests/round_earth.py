"""Round-Earth gravity and local-level rotations for the tests' own simulators, through
pymap3d (independent of :mod:`fgins.geodesy`): the point's geodetic latitude, longitude and
height, its local up as an ECEF vector, that vector in the origin's ENU axes."""

from __future__ import annotations

import numpy as np
import pymap3d

WGS_A, WGS_F = 6378137.0, 1 / 298.257223563


def normal_gravity(lat_deg, h):
    """WGS-84 normal gravity magnitude (Somigliana, second-order free-air), arrays allowed."""
    e2 = WGS_F * (2 - WGS_F)
    s2 = np.sin(np.radians(lat_deg)) ** 2
    g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - e2 * s2)
    m = 0.00344978650684
    return g0 * (1 - 2 / WGS_A * (1 + WGS_F + m - 2 * WGS_F * s2) * h + 3 / WGS_A**2 * h * h)


def local_axes(enu: np.ndarray, lat0: float, lon0: float, alt0: float) -> np.ndarray:
    """(N, 3, 3): columns are the local east, north and up at each ENU point, in the origin's
    ENU axes (so ``v_origin = A @ v_local``)."""
    lat, lon, _ = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], lat0, lon0, alt0)
    columns = []
    for e, n, u in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
        x, y, z = pymap3d.enu2uvw(e, n, u, lat, lon)
        columns.append(np.column_stack(pymap3d.uvw2enu(x, y, z, lat0, lon0)))
    return np.stack(columns, axis=-1)


def gravity(enu: np.ndarray, lat0: float, lon0: float, alt0: float) -> np.ndarray:
    """(N, 3) normal gravity at ENU points in the origin's ENU axes: along the local down of
    each point, with that point's latitude and height."""
    lat, _, h = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], lat0, lon0, alt0)
    up = local_axes(enu, lat0, lon0, alt0)[:, :, 2]
    return -normal_gravity(lat, h)[:, None] * up
