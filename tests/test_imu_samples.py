"""Instantaneous IMU samples become the held samples the integrators use
(:mod:`fgins.factors.imu_samples`): against a closed form, and on the independent flight
simulator (instantaneous samples, like most logs), where holding them as they were left a
fast roll's attitude lagging by w dt / 2 (an outside tester: 1.3 m in a 40 s outage with a
0.11 m sigma, NEES 135)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins.datatypes import ImuData
from fgins.factors.imu_samples import held_samples
from fgins.geodesy import so3_exp

sys.path.insert(0, str(Path(__file__).parent))
from flight_sim import FixedWing, write_flight


def _held_integration(imu: ImuData) -> np.ndarray:
    """Velocity after holding each sample over its interval with the start attitude (the
    scheme of GTSAM's preintegration and the baselines' mechanization), no gravity."""
    rotation, velocity = np.eye(3), np.zeros(3)
    for k in range(len(imu.t) - 1):
        dt = imu.t[k + 1] - imu.t[k]
        velocity = velocity + rotation @ imu.accel[k] * dt
        rotation = rotation @ so3_exp(imu.gyro[k] * dt)
    return velocity


@pytest.mark.parametrize("rate_hz", [50.0, 100.0, 400.0])
def test_held_samples_integrate_a_turning_force_to_second_order(rate_hz):
    """Body turning at 2 rad/s about z with a constant 1 m/s^2 along its x axis: the
    velocity is (sin wt, 1 - cos wt, 0) / w exactly. Holding the instantaneous samples is
    first order in dt; the converted ones second order."""
    w, duration = 2.0, 2.0
    t = np.arange(0.0, duration + 1e-12, 1.0 / rate_hz)
    instant = ImuData(
        t=t, gyro=np.tile([0.0, 0.0, w], (len(t), 1)), accel=np.tile([1.0, 0.0, 0.0], (len(t), 1))
    )
    exact = np.array([np.sin(w * duration), 1.0 - np.cos(w * duration), 0.0]) / w
    raw_error = np.linalg.norm(_held_integration(instant) - exact)
    held_error = np.linalg.norm(_held_integration(held_samples(instant)) - exact)
    # Each step's force rotated by w dt / 2 too little: the error is that angle times the
    # velocity gained.
    assert raw_error == pytest.approx(0.5 * w / rate_hz * np.linalg.norm(exact), rel=0.05)
    assert held_error < 0.1 * (w / rate_hz) ** 2 * np.linalg.norm(exact)
    assert held_error < 0.01 * raw_error


def test_samples_before_a_gap_are_kept():
    t = np.array([0.0, 0.01, 0.02, 2.0, 2.01])
    imu = ImuData(t=t, gyro=np.arange(15.0).reshape(5, 3) * 0.01, accel=np.ones((5, 3)))
    held = held_samples(imu)
    np.testing.assert_array_equal(held.gyro[2], imu.gyro[2])  # before the 1.98 s gap
    np.testing.assert_array_equal(held.gyro[-1], imu.gyro[-1])  # the last sample
    np.testing.assert_allclose(held.gyro[0], 0.5 * (imu.gyro[0] + imu.gyro[1]))


def _rolling_flight(folder: Path) -> Path:
    """70 m/s, turns entered and left within 1 s (roll rates near 60 deg/s) at 100 Hz."""
    rate = 9.8 * np.tan(np.radians(60)) / 70.0
    wing = FixedWing(speed=70.0, heading0_deg=30.0,
                     turns=[(30, 45, 1.0, rate), (50, 65, 1.0, -rate), (75, 90, 1.0, rate)])  # fmt: skip
    return write_flight(folder, wing, 110.0, seed=7, frame="frd", vehicle="aircraft",
                        imu_rate=100.0, gnss_rate=2.0)  # fmt: skip


def _outage_error(track, folder: Path, window: tuple[float, float]) -> tuple[float, float]:
    truth = pd.read_csv(folder / "truth.csv")
    rows = np.clip(np.searchsorted(truth["time"].to_numpy(), track.t - 1e-9), 0, len(truth) - 1)
    diff = track.position[:, :2] - truth[["east", "north"]].to_numpy()[rows]
    inside = (track.t >= window[0]) & (track.t < window[1])
    var = np.stack([track.position_cov[:, 0, 0], track.position_cov[:, 1, 1]], -1)
    rms = float(np.sqrt(np.mean(np.sum(diff[inside] ** 2, 1))))
    nees = float(np.mean(np.sum(diff[inside] ** 2 / var[inside], 1) / 2))
    return rms, nees


def test_instantaneous_samples_of_a_rolling_aircraft_are_integrated_as_such(tmp_path):
    folder = _rolling_flight(tmp_path / "flight")
    window = (40.0, 80.0)
    dataset = fgins.load(folder, vehicle="aircraft")
    results = {}
    for timing in ("instant", "held"):  # "held" was how every sample was integrated
        config = fgins.configure(dataset, vehicle="aircraft")
        config.imu["sample_timing"] = timing
        track = fgins.smooth(dataset, "batch", config=config, gnss_outage=[window])
        results[timing] = _outage_error(track, folder, window)
    assert results["instant"][0] < 0.7 * results["held"][0], results
    assert results["instant"][1] < 3.0, results
