"""Simulated drives changed the way a user's data can differ (shared by several tests)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fgins.datatypes import Dataset
from fgins.mounting import mounting_rotation


def turned_imu(run: Any, rpy: tuple[float, float, float]) -> tuple[Dataset, dict[str, Any]]:
    """``run``'s dataset with its IMU mounted at ``rpy`` (deg, the IMU's orientation in the
    car), and the ``[gnss]`` table whose lever arm (IMU axes) turns with it. The mounting
    itself is not put into any configuration: that is the caller's choice."""
    r_vi = mounting_rotation(rpy)
    dataset = run.dataset
    imu = replace(dataset.imu, gyro=dataset.imu.gyro @ r_vi, accel=dataset.imu.accel @ r_vi)
    gnss = dict(dataset.gnss_config)
    gnss["lever_arm_m"] = list(r_vi.T @ np.asarray(gnss.get("lever_arm_m", [0, 0, 0]), float))
    return replace(dataset, imu=imu, warnings=[]), gnss


def sim_outage_rms_and_sigma(track: Any, folder: Path, windows) -> tuple[float, float]:
    """Horizontal RMS error inside ``windows`` (s, the track's time base) against an fgins
    sim folder's ``truth.csv`` (lat, lon, alt), and the RMS of the horizontal sigma the
    track reports there."""
    import pandas as pd
    import pymap3d

    truth = pd.read_csv(Path(folder) / "truth.csv")
    frame = track.to_dataframe()
    t = frame["time"].to_numpy()
    reference = [np.interp(t, truth["time"], truth[c]) for c in ("lat", "lon", "alt")]
    east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *reference)
    inside = np.zeros(len(t), bool)
    for start, end in windows:
        inside |= (t >= start) & (t < end)
    sigma = np.hypot(frame["std_east"], frame["std_north"]).to_numpy()
    return float(np.sqrt(np.mean(np.hypot(east, north)[inside] ** 2))), float(np.sqrt(np.mean(sigma[inside] ** 2)))


def add_velocity_outliers(folder: Path, fraction: float, size: float, seed: int) -> None:
    """Throw ``fraction`` of the fixes' horizontal velocities in ``folder/gnss.csv`` by
    ``size`` m/s in random directions (a city's multipath)."""
    import pandas as pd

    fixes = pd.read_csv(Path(folder) / "gnss.csv")
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(fixes), int(fraction * len(fixes)), replace=False)
    angle = rng.uniform(0.0, 2.0 * np.pi, len(rows))
    fixes.loc[rows, "vel_east"] += size * np.cos(angle)
    fixes.loc[rows, "vel_north"] += size * np.sin(angle)
    fixes.to_csv(Path(folder) / "gnss.csv", index=False, float_format="%.6f")

