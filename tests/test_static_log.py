"""A log of a vehicle that never moves (parked, a static recording): every method must run,
and say that the heading is unknown rather than claim it.

Reference: the independent car simulator (tests/independent_sim.py) at rest, true heading
varied; position and roll/pitch are observable, the heading is not (only the Earth's rate
would show it, far below an industrial MEMS gyro's 180 deg/h turn-on bias). Before: iSAM2
ended in "diverged" (chi2/dof 1980) on one of six such logs, and the reported heading
sigmas were 5-60 deg where the errors were up to 162 deg (EKF: 30 sigma).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.solution_checks import never_moved

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import INDUSTRIAL, CarProfile, horizontal_errors, write_drive

METHODS = ("batch", "isam2", "ekf", "ekf-rts")


def _flat(t):
    return 0.0 * np.asarray(t, float)


def _drive(folder: Path, seed: int, heading_deg: float, steps=()) -> fgins.Dataset:
    profile = CarProfile(steps=list(steps), turns=[], gamma=_flat, heading0_deg=heading_deg)
    write_drive(folder, profile, 120.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed)  # fmt: skip
    return fgins.load(folder, config=folder / "cfg.toml")


@pytest.mark.parametrize(("seed", "heading_deg"), [(3, 160.0), (2, -30.0), (5, -120.0)])
def test_a_vehicle_that_never_moves_gets_a_position_and_an_unknown_heading(
    tmp_path, seed, heading_deg
):
    dataset = _drive(tmp_path, seed, heading_deg)
    assert never_moved(dataset) is not None
    for method in METHODS:
        track = fgins.smooth(dataset, method)
        frame = track.to_dataframe()
        assert np.all(frame["std_heading_deg"] == 180.0), method
        assert np.all(frame[["std_roll_deg", "std_pitch_deg"]].to_numpy() < 5.0), method
        summary = track.summary()
        assert summary["heading_observable"] is False
        assert any("never moved" in w for w in summary.get("fit_warnings", [])), method
        _, error = horizontal_errors(track, tmp_path)
        assert np.sqrt(np.mean(error**2)) < 1.5, method


def test_isam2_refines_a_final_estimate_that_does_not_fit_with_lm_and_says_so(tmp_path):
    """The static log on which iSAM2 diverged: its online heading swung by tens of degrees
    and left the gyro bias 3 mrad/s off; LM on the same graph (from the batch's start, else
    from that estimate) fits, and the summary says which."""
    track = fgins.smooth(_drive(tmp_path, 3, 160.0), "isam2")
    summary = track.summary()
    assert re.search(
        r"the iSAM2 estimate did not fit the data \(chi2/dof [\d.e+]+\): (refined|solved) by "
        r"Levenberg-Marquardt on the same graph", summary["fallback"]
    ), summary["fallback"]
    assert summary["chi2_per_dof"] < 2.0


@pytest.mark.parametrize("start_s", [20.0, 100.0])
def test_a_vehicle_that_drives_off_keeps_its_heading_sigma(tmp_path, start_s):
    """Standing still, then driving off at 8 m/s (late in the log too): the heading is
    observable from the motion and is not called unknown."""
    dataset = _drive(tmp_path, 1, 30.0, steps=[(start_s, 5.0, 8.0)])
    assert never_moved(dataset) is None
    frame = fgins.smooth(dataset, "batch").to_dataframe()
    assert frame["std_heading_deg"].iloc[-1] < 10.0


def test_kitti_and_a_configured_heading_are_not_called_static(tmp_path):
    assert never_moved(fgins.load("demo:kitti")) is None
    dataset = _drive(tmp_path, 2, -30.0)
    config = fgins.configure(dataset, config=tmp_path / "cfg.toml")
    config.smoother.initial_heading_deg = 120.0  # the true heading, given
    track = fgins.smooth(dataset, "batch", config=config)
    assert "heading_observable" not in track.summary()
    assert track.to_dataframe()["std_heading_deg"].iloc[0] < 5.0


def test_a_car_shuttling_back_and_forth_a_few_metres_is_not_called_static(tmp_path):
    """Forward 8 m and back again, twice: the fixes' running median never leaves a few
    metres, but the IMU feels every start and stop (0.75 m/s^2), so the heading is observable
    and keeps its sigma."""
    steps = [(10.0, 2.0, 1.5), (16.0, 2.0, -1.5), (22.0, 2.0, -1.5), (28.0, 2.0, 1.5)]
    steps += [(t + 40.0, tau, dv) for t, tau, dv in steps]
    dataset = _drive(tmp_path, 4, 75.0, steps=steps)
    assert never_moved(dataset) is None
    summary = fgins.smooth(dataset, "batch").summary()
    assert "heading_observable" not in summary
