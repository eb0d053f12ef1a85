"""The trajectory CSV of DESIGN.md (results and simulator truth), written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d

from fgins.datatypes import InputError, Origin, Trajectory
from fgins.geodesy import enu_to_lla, roll_pitch_heading_to_rotation
from fgins.io.atomic import atomic_path

COLUMNS = [
    "time", "lat", "lon", "alt", "east", "north", "up",
    "vel_east", "vel_north", "vel_up", "roll_deg", "pitch_deg", "heading_deg",
    "std_east", "std_north", "std_up",
]  # fmt: skip
EXTRA_COLUMNS = [
    "gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x", "accel_bias_y", "accel_bias_z",
]  # fmt: skip


def trajectory_table(trajectory: Trajectory) -> np.ndarray:
    """The trajectory as rows of :data:`COLUMNS` + :data:`EXTRA_COLUMNS`."""
    lla = enu_to_lla(trajectory.position, trajectory.origin)
    attitude = trajectory.roll_pitch_heading_deg()
    return np.column_stack(
        [
            trajectory.t, lla, trajectory.position, trajectory.velocity, attitude,
            trajectory.position_std, trajectory.gyro_bias, trajectory.accel_bias,
        ]
    )  # fmt: skip


def trajectory_columns(trajectory: Trajectory) -> tuple[list[str], np.ndarray]:
    """The CSV's header and its values before formatting: (:data:`COLUMNS` +
    :data:`EXTRA_COLUMNS`, (N, 22) float array). One place for the column computation, shared
    by the CSV writer and ``Trajectory.to_dataframe()``."""
    return COLUMNS + EXTRA_COLUMNS, trajectory_table(trajectory)


def write_trajectory_csv(trajectory: Trajectory, path: str | Path) -> None:
    """Write the DESIGN.md trajectory CSV (plus bias columns); NaN where unknown."""
    table = trajectory_table(trajectory)
    formats = ["%.6f", "%.9f", "%.9f"] + ["%.4f"] * (table.shape[1] - 3)
    formats[-6:] = ["%.4e"] * 6
    with atomic_path(path) as tmp:
        np.savetxt(
            tmp, table, delimiter=",", fmt=formats,
            header=",".join(COLUMNS + EXTRA_COLUMNS), comments="",
        )  # fmt: skip


def read_trajectory_csv(path: str | Path, origin: Origin | None = None) -> Trajectory:
    """Read a trajectory CSV (e.g. simulator ``truth.csv``) back into a :class:`Trajectory`.

    Without ``origin`` the ENU origin is recovered from the first row's lat/lon/alt and ENU.
    """
    path = Path(path)
    try:
        with path.open() as handle:
            header = handle.readline().strip().split(",")
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable trajectory CSV ({exc})") from None
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing trajectory column(s) {', '.join(missing)}")
    col = {name: data[:, header.index(name)] for name in header}
    if origin is None:
        lat, lon, alt = pymap3d.enu2geodetic(
            -col["east"][0], -col["north"][0], -col["up"][0],
            col["lat"][0], col["lon"][0], col["alt"][0],
        )  # fmt: skip
        origin = Origin(float(lat), float(lon), float(alt))
    rotation = np.array(
        [
            roll_pitch_heading_to_rotation(r, p, h)
            for r, p, h in zip(col["roll_deg"], col["pitch_deg"], col["heading_deg"], strict=True)
        ]
    )
    std = np.column_stack([col["std_east"], col["std_north"], col["std_up"]])
    cov = np.zeros((len(data), 3, 3))
    for i in range(3):
        cov[:, i, i] = std[:, i] ** 2

    def optional(names: list[str]) -> np.ndarray | None:
        if all(n in col for n in names):
            return np.column_stack([col[n] for n in names])
        return None

    return Trajectory(
        t=col["time"],
        position=np.column_stack([col["east"], col["north"], col["up"]]),
        velocity=np.column_stack([col["vel_east"], col["vel_north"], col["vel_up"]]),
        rotation=rotation,
        origin=origin,
        method=path.stem,
        gyro_bias=optional(EXTRA_COLUMNS[:3]),
        accel_bias=optional(EXTRA_COLUMNS[3:]),
        position_cov=cov,
    )
