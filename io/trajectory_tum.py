"""TUM trajectory files (``.tum``), the plain format evo, rpg_trajectory_evaluation and most
SLAM tools read: one pose per line, ``timestamp tx ty tz qx qy qz qw``.

fgins writes positions in the local ENU frame of the run (metres, the same origin as the CSV's
``east,north,up``), the body-to-ENU rotation as a unit quaternion (x, y, z, w; w >= 0) and
times in the dataset's seconds, all with full float64 precision (``%.17g``, round-trips
exactly). Comment lines (``#``) at the top name the format and the origin; evo skips them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fgins.datatypes import InputError, Origin, Trajectory
from fgins.geodesy import lla_to_enu, rotation_to_quaternion
from fgins.io.atomic import atomic_path

TUM_COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


def _header(origin: Origin, what: str) -> str:
    return (
        f"fgins {what}: {' '.join(TUM_COLUMNS)}\n"
        f"frame: local ENU (m) at origin lat={origin.lat!r} lon={origin.lon!r} alt={origin.alt!r}"
        " (deg, deg, ellipsoidal m); quaternion: body-to-ENU rotation"
    )


def _write(path: str | Path, rows: np.ndarray, header: str) -> None:
    if rows.shape[0] == 0:
        raise InputError(f"{path}: nothing to write (no poses)")
    with atomic_path(path) as tmp:
        np.savetxt(tmp, rows, fmt="%.17g", delimiter=" ", header=header, comments="# ")


def write_trajectory_tum(trajectory: Trajectory, path: str | Path) -> None:
    """Write ``trajectory`` as a TUM file: ENU position and body-to-ENU quaternion per state."""
    quaternion = rotation_to_quaternion(trajectory.rotation)
    rows = np.column_stack([trajectory.t, trajectory.position, quaternion])
    _write(path, rows, _header(trajectory.origin, f"trajectory ({trajectory.method or 'unknown'})"))


def write_gnss_tum(t: np.ndarray, lla: np.ndarray, origin: Origin, path: str | Path) -> None:
    """Write GNSS fixes as a TUM *reference*: ENU at ``origin``, identity orientation.

    A fix carries no attitude, so every quaternion is (0, 0, 0, 1). Use it for position
    metrics only (evo's APE/RPE with ``--pose_relation trans_part``, no alignment).
    """
    enu = lla_to_enu(np.asarray(lla, dtype=float), origin)
    quaternion = np.tile([0.0, 0.0, 0.0, 1.0], (enu.shape[0], 1))
    rows = np.column_stack([np.asarray(t, dtype=float), enu, quaternion])
    _write(path, rows, _header(origin, "GNSS reference (identity orientation)"))


def read_tum(path: str | Path) -> np.ndarray:
    """The rows (N, 8) of a TUM file (comments skipped)."""
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable TUM trajectory ({exc})") from None
    if rows.shape[1] != len(TUM_COLUMNS):
        raise InputError(f"{path}: expected 8 columns ({' '.join(TUM_COLUMNS)})")
    return rows
