"""A body that turns more than half a revolution between two keyframes (a multirotor's
pirouette or flip; tests/flight_sim.py, an independent simulator).

GTSAM's preintegrated rotation is a tangent-space vector whose Jacobians are singular where
the accumulated rotation reaches 2 pi. With keyframes only at 1 Hz GNSS epochs, an outside
tester's 400 deg/s yaw pirouette left batch 5.3 m off inside a 50 s outage (NEES 6-19, a
chi2 warning blaming the IMU noise; iSAM2 "diverged", blaming the user's settings) and 1.1 m
off on noise-free data with exact fixes; two 360 deg flips 2.05 m (NEES 5-20, no warning).
Keyframes now split every interval that turns more than pi/2 (graph/keyframes.py).
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins.datatypes import ImuData
from fgins.graph.keyframes import MAX_TURN_RAD, keyframe_times, turned_angle

sys.path.insert(0, str(Path(__file__).parent))
from flight_sim import Multirotor, write_flight

OUTAGE = (25.0, 60.0)


def test_no_keyframe_interval_turns_more_than_half_a_revolution():
    # A gyro whose rate steps between 0.1 and 12 rad/s on an uneven sample grid.
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.004, 0.016, 3000))
    rate = np.where((t > 5) & (t < 12), 12.0, 0.1) * (1 + 0.2 * rng.random(len(t)))
    axis = rng.normal(size=(len(t), 3))
    gyro = axis / np.linalg.norm(axis, axis=1, keepdims=True) * rate[:, None]
    imu = ImuData(t, gyro, np.tile([0.0, 0.0, 9.8], (len(t), 1)))
    gnss_times = np.arange(np.ceil(t[0]), t[-1], 1.0)
    times = keyframe_times(imu, gnss_times, max_interval=1.0)
    t_grid, angle = turned_angle(imu)
    turned = np.diff(np.interp(times, t_grid, angle))
    assert turned.max() <= MAX_TURN_RAD + 1e-9
    assert np.all(np.diff(times) > 0) and set(gnss_times) <= set(times)
    # Where the body turns slowly, nothing is added: the GNSS keyframes (and the ends) stay.
    slow = (times < 4.0) | (times > 13.0)
    assert np.allclose(np.diff(times[slow & (times > 1.0) & (times < 4.0)]), 1.0)
    # The fast stretch is split as little as it must be: each piece turns over half the limit.
    fast = (times[:-1] > 5.5) & (times[1:] < 11.5)
    assert fast.sum() > 20 and turned[fast].min() > 0.5 * MAX_TURN_RAD


def _spinning_multirotor(turn_deg: float, seconds: float) -> Multirotor:
    moves = [(4, 6, [0, 0, 10]), (12, 10, [40, 10, 0]), (28, 12, [-30, 40, 0]),
             (44, 10, [10, -40, 5]), (58, 8, [20, 0, -5])]  # fmt: skip
    yaws = [(16, seconds, np.radians(turn_deg)), (34, seconds, -np.radians(turn_deg)),
            (50, seconds, np.radians(turn_deg))]  # fmt: skip
    return Multirotor(heading0_deg=40.0, moves=moves, yaws=yaws)


def _errors(track, folder: Path) -> tuple[float, float]:
    truth = pd.read_csv(folder / "truth.csv")
    rows = np.clip(np.searchsorted(truth["time"].to_numpy(), track.t - 1e-9), 0, len(truth) - 1)
    diff = track.position[:, :2] - truth[["east", "north"]].to_numpy()[rows]
    inside = (track.t >= OUTAGE[0]) & (track.t < OUTAGE[1])
    var = np.stack([track.position_cov[:, 0, 0], track.position_cov[:, 1, 1]], -1)
    rms = float(np.sqrt(np.mean(np.sum(diff[inside] ** 2, 1))))
    nees = float(np.mean(np.sum(diff**2 / var, 1) / 2))
    return rms, nees


@pytest.mark.parametrize(
    "turn_deg, seconds, frame", [(720.0, 2.0, "flu"), (-1080.0, 3.0, "frd"), (540.0, 1.5, "flu")]
)
def test_a_pirouetting_multirotor_bridges_an_outage_as_a_slow_one(tmp_path, turn_deg, seconds, frame):
    """Peak yaw rates of 790, 1185 and 790 deg/s (a 2 s yaw of 720 deg has 2.2x its mean rate
    at the middle), three pirouettes, two inside the outage, 1 Hz GNSS: batch and iSAM2 bridge
    it as they bridge the same flight yawing 20x slower, with consistent sigmas."""
    errors = {}
    for name, turn, duration in (("fast", turn_deg, seconds), ("slow", turn_deg / 20, seconds)):
        folder = write_flight(tmp_path / name, _spinning_multirotor(turn, duration), 70.0, seed=11,
                              frame=frame, vehicle="uav", gnss_rate=1.0)  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", fgins.FginsWarning)
            dataset = fgins.load(folder, vehicle="uav")
            for method in ("batch", "isam2"):
                track = fgins.smooth(dataset, method, gnss_outage=[OUTAGE])
                errors[name, method] = _errors(track, folder)
                assert track.info["chi2_per_dof"] < 1.5, (name, method, track.info["chi2_per_dof"])
    slow_rms = errors["slow", "batch"][0]
    for method in ("batch", "isam2"):
        rms, nees = errors["fast", method]
        assert rms < max(1.5 * slow_rms, slow_rms + 0.3), (method, errors)
        assert 0.2 < nees < 2.5, (method, errors)


@pytest.mark.parametrize(("range_deg_s", "frame", "method"), [(250.0, "flu", "batch"), (300.0, "frd", "isam2")])
def test_a_gyro_saturated_at_its_range_is_said_and_bridged(tmp_path, range_deg_s, frame, method):
    """The pirouetting multirotor read by a gyro whose range is +-250 or +-300 deg/s: its z
    channel sits on the range through each pirouette (peaks ~800 deg/s) and 200-400 deg of
    yaw are lost each time. Nothing looked at it: the batch ended 46 m off inside the outage
    (its error 48x its sigma) and 15 m outside it, after 367 iterations and 73 s, blaming the
    GNSS sigmas (scaled 3.3x), an antenna 14 m up and the gyro bias. The clipped runs are now
    found, said (channel, value, samples) and bridged as gaps, and the fixes after each
    pirouette set the heading again."""
    folder = write_flight(tmp_path / "flight", _spinning_multirotor(720.0, 2.0), 70.0, seed=11,
                          frame=frame, vehicle="uav", gnss_rate=5.0)  # fmt: skip
    imu = pd.read_csv(folder / "imu.csv")
    limit = np.radians(range_deg_s)
    clipped = int((imu[["gyro_x", "gyro_y", "gyro_z"]].abs() > limit).to_numpy().sum())
    assert clipped > 100  # the case this test is about
    for axis in ("gyro_x", "gyro_y", "gyro_z"):
        imu[axis] = imu[axis].clip(-limit, limit)
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dataset = fgins.load(folder, vehicle="uav")
        track = fgins.smooth(dataset, method, gnss_outage=[OUTAGE])
    said = [str(w.message) for w in caught if "saturated" in str(w.message)]
    assert said and all("gyro_z" in line and f"{range_deg_s:g} deg/s" in line for line in said), said
    rms, nees = _errors(track, folder)
    assert rms < 3.0 and nees < 3.0, (rms, nees)


def test_saturation_is_a_run_on_the_extreme_not_a_large_or_repeated_value():
    """Clipped channels (either sign, gyro or accelerometer) are found with their runs; a
    noisy peak of 800 deg/s, an IMU at rest whose coarse samples repeat, and a noise-free
    simulation's steady 3 rad/s roll (its rate repeated exactly) are not."""
    from fgins.io.imu_checks import find_saturation

    rng = np.random.default_rng(0)
    t = np.arange(0.0, 20.0, 0.01)

    def noisy(signal, sigma):
        return signal + rng.normal(0.0, sigma, t.size)

    data = np.column_stack([
        noisy(14.0 * np.exp(-((t - 5.0) ** 2)), 0.01),  # 800 deg/s peak
        np.round(rng.normal(0.0, 0.002, t.size), 2),  # at rest, quantised to 0.01 rad/s
        np.clip(noisy(6.0 * np.sin(t), 0.01), -4.3633, 4.3633),  # a +-250 deg/s gyro, clipped
        np.clip(noisy(30.0 * np.exp(-((t - 12.0) ** 2) / 0.01), 0.05), None, 19.6133),  # +2 g pothole
        rng.normal(0.0, 0.05, t.size),
        9.81 + rng.normal(0.0, 0.05, t.size),
    ])  # fmt: skip
    found = {(s.channel, round(s.extreme, 3)): s for s in find_saturation(data)}
    assert set(found) == {("gyro_z", 4.363), ("gyro_z", -4.363), ("accel_x", 19.613)}, found
    assert len(found["gyro_z", 4.363].runs) == 4 and found["accel_x", 19.613].samples >= 3
    ramp = np.clip(t - 2.0, 0.0, 1.0) * np.clip(12.0 - t, 0.0, 1.0)
    noise_free = np.column_stack([3.0 * ramp, 0 * t, 0.5 * np.sin(t), 0 * t, 9.81 * np.sin(0.3 * ramp), 9.81 + 0 * t])
    assert find_saturation(noise_free) == []


def test_a_filter_on_a_saturated_gyro_names_the_saturation_among_its_causes(tmp_path):
    """The forward EKF on the pirouetting multirotor with a +-150 deg/s gyro misses its fixes:
    its note listed clocks, axes, units and noise, never the saturation the reader had just
    reported (outside tester: EKF+RTS refused as diverged so)."""
    folder = write_flight(tmp_path / "flight", _spinning_multirotor(720.0, 2.0), 70.0, seed=11,
                          vehicle="uav", gnss_rate=5.0)  # fmt: skip
    imu = pd.read_csv(folder / "imu.csv")
    limit = np.radians(150.0)
    for axis in ("gyro_x", "gyro_y", "gyro_z"):
        imu[axis] = imu[axis].clip(-limit, limit)
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        dataset = fgins.load(folder, vehicle="uav")
    try:
        track = fgins.smooth(dataset, "ekf", gnss_outage=[OUTAGE])
    except fgins.FginsError as refused:
        notes = [str(refused)]
    else:
        notes = [w for w in track.info.get("fit_warnings", []) if "its IMU predictions miss" in w]
    assert notes  # the case this test is about
    assert all("saturated gyro or accelerometer" in note for note in notes), notes
