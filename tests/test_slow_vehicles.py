"""Vehicles that leave rest slowly and crawl: a field robot, a tractor, a car creeping off.

An independent simulator's car (tests/independent_sim.py) pulls away from a 10 s rest to 1 or
2 m/s and drives quarter turns every 40 s, with 1 m fixes at 1 Hz. Before:

* the at-rest alignment took the heading from a 5 s chord of at least 20 m only, which such a
  vehicle never makes: the heading stayed unknown (sigma 180 deg), and the forward EKF locked
  onto one 55 deg off (105 m off inside an outage at 2 m/s, with only a fit warning);
* the Kalman baselines took a quiet IMU at a speed under the 1.5 m/s cap as a stop, so a
  steady crawl (which an IMU reads exactly like rest) got 17-27 false ZUPTs with GNSS and was
  held still through whole outages (EKF 33 m, EKF+RTS 15 m off where the batch gets 0.7 m).

iSAM2's online pass took the same false stops (36 m off in the outage at 1 m/s, silent).

Now the heading comes from the first motion straightened by the gyro's yaw; fixes that moved
over 12 s refuse a causal estimate's stop while its speed is above a known stop's floor
(:func:`fgins.factors.stationary.crawl_refuses_stop`, for every method); in dead reckoning
a stop must follow a slow-down the estimate saw (the filters and iSAM2's online pass); the
online pass's fit to its fixes is checked as a filter's is.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.alignment import initial_alignment
from fgins.geodesy import rotation_to_roll_pitch_heading

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import INDUSTRIAL, CarProfile, horizontal_errors, write_drive

OUTAGE = (100.0, 140.0)
HEADING_DEG = 60.0  # CarProfile's default: 30 deg counter-clockwise from east


def _crawler(folder: Path, speed: float, seed: int) -> fgins.Dataset:
    turn_rate = 0.3  # rad/s: quarter turns of ~5 s, left and right
    turns = [(30 + 40 * i, 30 + 40 * i + (np.pi / 2) / turn_rate, 2, turn_rate * (-1) ** i)
             for i in range(5)]  # fmt: skip
    profile = CarProfile(steps=[(10, 5, speed)], turns=turns, gamma=lambda t: 0.0 * t)
    write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed)  # fmt: skip
    return fgins.load(folder / "imu.csv", folder / "gnss.csv", config=folder / "cfg.toml",
                      vehicle="car")  # fmt: skip


def _outage_rms(track, folder: Path) -> float:
    t, error = horizontal_errors(track, folder)
    inside = (t >= OUTAGE[0]) & (t < OUTAGE[1])
    return float(np.sqrt(np.mean(error[inside] ** 2)))


@pytest.mark.parametrize(("speed", "seed"), [(2.0, 1), (1.0, 2), (1.0, 5)])
def test_a_crawling_vehicle_is_aligned_and_the_kalman_baselines_hold(tmp_path, speed, seed):
    dataset = _crawler(tmp_path, speed, seed)
    config = fgins.configure(dataset, vehicle="car")
    align = initial_alignment(dataset, smoother=config.smoother)
    found = rotation_to_roll_pitch_heading(np.asarray(align.rotation)[None])[0, 2]
    sigma = float(np.degrees(align.attitude_sigma_rad[2]))
    error = (found - HEADING_DEG + 180.0) % 360.0 - 180.0
    assert sigma < 10.0 and abs(error) < 3.0 * max(sigma, 1.0), (found, sigma)  # was 0 +- 180

    # With every fix: stops only where the car stood (the first 10 s).
    ekf = fgins.smooth(dataset, "ekf")
    assert max(ekf.info["zupt_times"]) < 11.0, ekf.info["zupt_times"]

    # In an outage: the filters bridge it as the batch does (were 15-105 m off).
    batch = _outage_rms(fgins.smooth(dataset, "batch", gnss_outage=[OUTAGE]), tmp_path)
    rts = _outage_rms(fgins.smooth(dataset, "ekf-rts", gnss_outage=[OUTAGE]), tmp_path)
    forward = _outage_rms(fgins.smooth(dataset, "ekf", gnss_outage=[OUTAGE]), tmp_path)
    assert batch < 1.5, batch
    assert rts < 1.3 * batch + 0.2, (rts, batch)
    assert forward < 4.0, forward
    _online_accurate_or_said(dataset, tmp_path)


def _online_accurate_or_said(dataset: fgins.Dataset, folder: Path) -> None:
    """iSAM2's online pass within 4 m in the outage, or its misfit said. A causal estimate
    whose speed sags below a known stop's floor after a turn (1 m/s, 1 m fixes: 0.44 m/s
    at 40 s with or without stops) still takes a crawl for a stop there; 17.6 m at 1 m/s
    (seed 2), 19 m at 0.5 m/s, both silent before, now with their chi2/dof of 15-62."""
    online = fgins.smooth(dataset, "isam2-online", gnss_outage=[OUTAGE])
    said = [w for w in online.info.get("fit_warnings", []) if "does not fit the GNSS fixes" in w]
    assert _outage_rms(online, folder) < 4.0 or said, online.info.get("fit_warnings")


def test_a_half_metre_per_second_crawl_online_is_accurate_or_said(tmp_path):
    """At 0.5 m/s through 1 m fixes even a 12 s chord hardly tells a crawl from a stop: the
    causal passes still take some false stops. The batch and the final iSAM2 see the whole
    drive and hold; the online pass is accurate or says it does not fit its fixes."""
    dataset = _crawler(tmp_path, 0.5, 3)
    for method in ("batch", "isam2"):
        rms = _outage_rms(fgins.smooth(dataset, method, gnss_outage=[OUTAGE]), tmp_path)
        assert rms < 1.5, (method, rms)
    _online_accurate_or_said(dataset, tmp_path)
