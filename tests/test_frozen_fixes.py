"""A receiver that repeats its last fix while the vehicle moves (a frozen position output),
for part of a drive: the repeats are left out and said. An outside tester froze 20 s of
fgins's urban car: the fault exclusion took them out only after a gyro scale of -2.3 % had
been read from them, 2.6 m RMS (32 % of epochs beyond 3 sigma) where the drive gives 0.34 m.
A vehicle standing still under a receiver's static hold repeats its fix too: kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d
import pytest

import fgins
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import write_sim_dir


@pytest.fixture(scope="module")
def urban(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("frozen") / "drive"
    write_sim_dir(SCENARIOS["car-urban"](seed=0, duration_s=180.0), folder)
    return folder


def _frozen_copy(urban: Path, folder: Path, rows: slice, velocities: bool) -> Path:
    folder.mkdir()
    for name in ("imu.csv", "config.toml", "truth.csv"):
        (folder / name).write_bytes((urban / name).read_bytes())
    fixes = pd.read_csv(urban / "gnss.csv")
    fixes.loc[rows, ["lat", "lon", "alt"]] = fixes.loc[rows.start, ["lat", "lon", "alt"]].to_numpy()
    if not velocities:
        fixes = fixes.drop(columns=["vel_east", "vel_north", "vel_up"])
    fixes.to_csv(folder / "gnss.csv", index=False)
    return folder


def _horizontal_rms(track, folder: Path) -> float:
    truth = pd.read_csv(folder / "truth.csv")
    frame = track.to_dataframe()
    t = frame["time"].to_numpy()
    reference = [np.interp(t, truth["time"], truth[c]) for c in ("lat", "lon", "alt")]
    east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *reference)
    return float(np.sqrt(np.mean(east**2 + north**2)))


@pytest.mark.parametrize("velocities", [False, True])
def test_fixes_frozen_while_the_car_drives_are_left_out_and_said(urban, tmp_path, velocities):
    folder = _frozen_copy(urban, tmp_path / "frozen", slice(100, 119), velocities)
    dataset = fgins.load(folder)
    said = [w for w in dataset.warnings if "repeat one position while the vehicle moves" in w]
    assert said and "19 repeated fixes left out" in said[0], dataset.warnings
    track = fgins.smooth(dataset, "batch", progress=False)
    assert not track.info.get("gyro_scale_corrected") or not any(track.info["gyro_scale_corrected"])
    assert _horizontal_rms(track, folder) < 1.0
    # The count line adds up to the file's rows (it said "152 epochs" for 200; outside tester).
    rows = len(pd.read_csv(folder / "gnss.csv"))
    line = track.info["gnss_gating"]
    counted = int(line.split("GNSS: ")[1].split(" epochs")[0])
    assert "+19 repeats of a frozen position" in line and counted + 19 == rows, line


def test_a_fix_held_while_the_car_stands_still_is_kept(urban, tmp_path):
    """The urban car stands still from 116 to 126 s: a receiver's static hold there."""
    folder = _frozen_copy(urban, tmp_path / "hold", slice(117, 125), True)
    dataset = fgins.load(folder)
    assert not [w for w in dataset.warnings if "repeat one position" in w], dataset.warnings
    assert len(dataset.gnss) == len(pd.read_csv(folder / "gnss.csv"))


def test_a_static_receiver_on_a_coarse_grid_keeps_its_repeated_fixes(shared, tmp_path):
    """gpsd's meinberg-gps164: a static timing receiver printing positions to 0.01 arc-minute
    (12.5 m east steps), speed 0.0; 48 of its 70 fixes at one point, the rest one to three
    steps east. Beside an IMU at rest, the repeats were "frozen while the vehicle moves" (the
    next fix lay 12.5 m away) and left out: the 48 at the true point dropped, the 22 off it
    kept, 12-23 m off at z 11-12 (outside tester). The fixes come back within a step and the
    receiver says it stands: nothing is frozen."""
    from fgins.io.nmea import read_nmea

    log = shared / "data" / "nmea" / "gpsd" / "meinberg-gps164.log"
    fixes = read_nmea(log).gnss
    rng = np.random.default_rng(5)
    t = np.arange(fixes.t[0] - 2.0, fixes.t[-1] + 2.0, 0.01)
    gyro = rng.normal(0, 4e-4, (len(t), 3))
    accel = rng.normal(0, 0.01, (len(t), 3)) + np.array([0.0, 0.0, 9.807])
    imu = tmp_path / "imu.csv"
    np.savetxt(imu, np.column_stack([t, gyro, accel]), delimiter=",", fmt="%.6f",
               header="time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z", comments="")  # fmt: skip
    dataset = fgins.load(log, imu, imu_preset="industrial-mems")
    assert not any("repeat one position" in w for w in dataset.warnings), dataset.warnings
    assert len(dataset.gnss) == len(fixes)
