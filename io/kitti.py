"""``demo:kitti``: the real KITTI drive that ships inside the gtsam wheel.

``KittiEquivBiasedImu.txt`` (100 Hz IMU, body x forward, y left, z up),
``KittiEquivBiasedImu_metadata.txt`` (noise values) and ``KittiGps_converted.txt`` (1 Hz GNSS
positions already in a local X,Y,Z = east,north,up frame). The local frame has no geodetic
anchor; we place it at the KITTI Karlsruhe sequence's start so lat/lon output is meaningful,
and ENU output equals the file's X,Y,Z exactly.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from fgins.datatypes import Dataset, GnssData, InputError, Origin
from fgins.geodesy import enu_to_lla
from fgins.io.imu_checks import imu_from_samples

# Karlsruhe, near the KITTI raw-data drives (the converted file carries no geodetic origin).
KITTI_ORIGIN = Origin(lat=49.011212804408, lon=8.4228850417969, alt=112.83492279053)


def gtsam_data_dir() -> Path:
    spec = importlib.util.find_spec("gtsam")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("demo:kitti needs the gtsam package (pip install gtsam)")
    folder = Path(next(iter(spec.submodule_search_locations))) / "Data"
    if not (folder / "KittiGps_converted.txt").exists():
        raise InputError(f"demo:kitti: {folder} has no KITTI files (gtsam wheel without Data/?)")
    return folder


def read_kitti_metadata(path: Path) -> dict[str, float]:
    lines = [line.split() for line in path.read_text().splitlines() if line.strip()]
    return {name: float(value) for name, value in zip(lines[0], lines[1], strict=True)}


# Noise values tuned on this drive (one-step GNSS prediction error with all GNSS, and the
# outage protocol of scripts/bench_outages.py). The metadata file's values are optimistic:
# white noise 0.01 m/s^2/sqrt(Hz) and 1.75e-4 rad/s/sqrt(Hz), bias walks 1.67e-4, 2.91e-6.
KITTI_IMU_CONFIG: dict[str, float] = {
    "accel_noise_m_per_s2_per_sqrt_hz": 0.02,
    "gyro_noise_rad_per_s_per_sqrt_hz": 3.0e-4,
    "accel_bias_rw_m_per_s2_per_sqrt_s": 5.0e-3,
    "gyro_bias_rw_rad_per_s_per_sqrt_s": 2.0e-5,
    "accel_turn_on_bias_mg": 20.0,
    "gyro_turn_on_bias_deg_per_s": 0.1,
    "integration_sigma_m_per_s2_per_sqrt_hz": 1e-4,
}
KITTI_GNSS_CONFIG: dict[str, object] = {"sigma_m": [0.3, 0.3, 0.5], "pdop_max": None}


def read_kitti(folder: Path | None = None) -> Dataset:
    """The KITTI drive as every input is given to a run: parsed, then checked by the
    input-validation layer (its gaps and eight interpolated stretches flagged suspect).

    Same as ``load_dataset(["demo:kitti"])`` for the built-in files.
    """
    from fgins.io.inputs import validated

    return validated(parse_kitti(folder))


def parse_kitti(folder: Path | None = None) -> Dataset:
    """Parse the KITTI files into a :class:`Dataset` (no checks: see :func:`read_kitti`)."""
    folder = folder or gtsam_data_dir()
    warnings: list[str] = []
    imu_raw = np.loadtxt(folder / "KittiEquivBiasedImu.txt", skiprows=1)
    gps_raw = np.loadtxt(folder / "KittiGps_converted.txt", skiprows=1, delimiter=",")
    metadata = read_kitti_metadata(folder / "KittiEquivBiasedImu_metadata.txt")
    # Columns: Time dt accelX accelY accelZ omegaX omegaY omegaZ. The first row's dt is the
    # absolute time (no predecessor); the row itself is a valid sample.
    imu = imu_from_samples(
        imu_raw[:, 0], imu_raw[:, 5:8], imu_raw[:, 2:5], source="KittiEquivBiasedImu.txt",
        warnings=warnings,
    )  # fmt: skip
    enu = gps_raw[:, 1:4]
    gnss = GnssData(t=gps_raw[:, 0], lla=enu_to_lla(enu, KITTI_ORIGIN))
    return Dataset(
        imu=imu,
        gnss=gnss,
        origin=KITTI_ORIGIN,
        name="demo:kitti",
        imu_config=dict(KITTI_IMU_CONFIG),
        gnss_config=dict(KITTI_GNSS_CONFIG),
        vehicle="car",
        warnings=warnings,
        metadata={"kitti_metadata": metadata, "gnss_enu_file": enu},
    )
