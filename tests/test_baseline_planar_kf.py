"""5-state planar Kalman filter baseline (fgins.baseline.planar_kf).

Independent references: simulator truth with known GNSS and barometer noise, a loop that
crosses +-180 deg (the course innovation must be wrapped), closed-form angle wrapping.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

import fgins
from fgins.baseline.planar_kf import PlanarKfOptions, run_planar_kf, wrap_angle
from fgins.config import RunConfig, imu_noise_from_config, load_config
from fgins.datatypes import GnssData, InputError, Origin
from fgins.geodesy import enu_to_lla
from fgins.pipeline import run_method
from fgins.sim import motion
from fgins.sim.gnss import GnssModel
from fgins.sim.imu_errors import ImuErrorModel
from fgins.sim.scenarios import SCENARIOS, simulate_run


def _config(run) -> RunConfig:
    return load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)


@pytest.fixture(scope="module")
def uav_loop():
    run = SCENARIOS["uav-loop-baro"](seed=0, duration_s=180)
    return run, _config(run)


@pytest.fixture(scope="module")
def fast_loop_with_course():
    """The 25 m loop at 6 m/s with GNSS velocity: course updates while the heading crosses
    +-180 deg every 26 s."""
    noise = imu_noise_from_config({"preset": "consumer-mems"})
    run = simulate_run(
        name="loop-course",
        seed=0,
        profile=motion.circular_loop(20.0, 120.0, radius_m=25.0, speed_m_per_s=6.0),
        origin=Origin(52.52, 13.405, 60.0),
        imu_preset="consumer-mems",
        noise=noise,
        errors=ImuErrorModel.from_noise(noise),
        gnss_model=GnssModel(rate_hz=1.0, uere_m=2.0, velocity_sigma_m_per_s=0.1),
    )
    return run, _config(run)


def _horizontal_rms(trajectory, truth, settled) -> float:
    error = np.linalg.norm((trajectory.position - truth.position)[settled, :2], axis=1)
    return float(np.sqrt(np.mean(error**2)))


def test_wrap_angle_closed_form():
    angles = np.array([np.pi, -np.pi, 1.5 * np.pi, -1.5 * np.pi, 0.3, 7.0 * np.pi, 2 * np.pi])
    expected = np.array([np.pi, np.pi, -0.5 * np.pi, 0.5 * np.pi, 0.3, np.pi, 0.0])
    np.testing.assert_allclose(wrap_angle(angles), expected, atol=1e-12)


def test_tracks_the_uav_loop_within_the_gnss_sigma(uav_loop):
    run, config = uav_loop
    trajectory = run_planar_kf(run.dataset, config, progress=False)
    np.testing.assert_array_equal(trajectory.t, run.dataset.imu.t)
    assert trajectory.method == "planar-kf"
    settled = trajectory.t > trajectory.t[0] + 30.0
    # Per-axis GNSS sigma: UERE 2 m x HDOP ~1.1 (2.5 from 90 to 120 s).
    gnss_sigma = 2.0 * 1.1
    assert _horizontal_rms(trajectory, run.truth, settled) < gnss_sigma
    error = (trajectory.position - run.truth.position)[settled]
    z = np.abs(error) / trajectory.position_std[settled]
    assert np.mean(np.all(z < 3.0, axis=1)) > 0.95
    assert trajectory.info["baro_updates"] == len(run.dataset.baro.t)


def test_output_is_level_and_moves_along_the_heading(uav_loop):
    run, config = uav_loop
    trajectory = run_planar_kf(run.dataset, config, progress=False)
    attitude = trajectory.roll_pitch_heading_deg()
    np.testing.assert_allclose(attitude[:, :2], 0.0, atol=1e-9)
    # Standing still (the first 5 s) the speed estimate may dip below zero: that is noise.
    moving = np.hypot(*run.truth.velocity[:, :2].T) > 1.0
    course = np.degrees(np.arctan2(trajectory.velocity[:, 0], trajectory.velocity[:, 1]))
    difference = (course - attitude[:, 2] + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(difference[moving], 0.0, atol=1e-6)
    assert np.all(np.isfinite(trajectory.position_cov))


@pytest.mark.parametrize("with_baro", [True, False])
def test_the_climb_rate_follows_the_height_not_its_steps(uav_loop, with_baro):
    """The planar height is held between updates and steps at each: its derivative sample by
    sample wrote 100-517 m/s climbs at every fix (outside tester). The loop is level: the
    climb rate stays within the updates' noise over a few seconds."""
    run, config = uav_loop
    dataset = run.dataset if with_baro else replace(run.dataset, baro=None)
    trajectory = run_planar_kf(dataset, config, progress=False)
    climb = trajectory.velocity[:, 2] - run.truth.velocity[:, 2]
    assert np.sqrt(np.mean(climb**2)) < (0.1 if with_baro else 1.0)
    assert np.max(np.abs(climb)) < (0.5 if with_baro else 3.0)


def test_barometer_reduces_the_vertical_error(uav_loop):
    run, config = uav_loop
    settled = run.dataset.imu.t > run.dataset.imu.t[0] + 30.0
    rms = {}
    for label, dataset in (("baro", run.dataset), ("no baro", replace(run.dataset, baro=None))):
        trajectory = run_planar_kf(dataset, config, progress=False)
        vertical = (trajectory.position - run.truth.position)[settled, 2]
        rms[label] = float(np.sqrt(np.mean(vertical**2)))
    # Baro noise 0.3 m against a GNSS vertical sigma of 2 m x VDOP ~1.8.
    assert rms["baro"] < 0.5 * rms["no baro"]
    assert rms["baro"] < 1.0


def test_heading_crossing_180_deg_needs_the_wrapped_innovation(fast_loop_with_course):
    run, config = fast_loop_with_course
    settled = run.dataset.imu.t > run.dataset.imu.t[0] + 20.0
    truth_heading = run.truth.roll_pitch_heading_deg()[:, 2]
    crossings = np.abs(np.diff(truth_heading[settled] - 180.0)) > 180.0  # through south
    assert crossings.sum() >= 3
    wrapped = run_planar_kf(run.dataset, config, progress=False)
    assert wrapped.info["course_updates"] > 100
    heading_error = (wrapped.roll_pitch_heading_deg()[:, 2] - truth_heading + 180.0) % 360 - 180
    assert np.abs(heading_error[settled]).max() < 5.0
    assert _horizontal_rms(wrapped, run.truth, settled) < 1.0
    # The study's unwrapped innovation turns each crossing into a ~360 deg "error".
    unwrapped = run_planar_kf(
        run.dataset, config, progress=False, options=PlanarKfOptions(wrap_heading=False)
    )
    assert _horizontal_rms(unwrapped, run.truth, settled) > 10.0


def test_gnss_between_imu_samples_is_used_at_its_own_time():
    # Error-free IMU on the 6 m/s loop; millimetre fixes half a sample (25 ms) after IMU
    # samples, at the true position then. Snapping them to a sample (the study's index lag)
    # would leave 6 m/s x 25 ms = 15 cm.
    noise = imu_noise_from_config({"preset": "consumer-mems"})
    exact = simulate_run(
        name="loop-exact",
        seed=0,
        profile=motion.circular_loop(20.0, 90.0, radius_m=25.0, speed_m_per_s=6.0),
        origin=Origin(52.52, 13.405, 60.0),
        imu_preset="consumer-mems",
        noise=noise,
        errors=ImuErrorModel(),
        gnss_model=GnssModel(rate_hz=1.0, sigma_m=(1.0, 1.0, 1.0)),
    )
    imu, truth = exact.dataset.imu, exact.truth
    k = np.arange(10, len(imu) - 1, 20)
    fix_t = imu.t[k] + 0.5 * np.diff(imu.t)[0]
    dataset = replace(
        exact.dataset,
        gnss=GnssData(t=fix_t, lla=enu_to_lla(truth.at(fix_t), exact.dataset.origin)),
    )
    config = load_config(
        dataset_imu=exact.dataset.imu_config,
        dataset_gnss={"sigma_m": [1e-3] * 3, "use_velocity": False},
    )
    heading = float(truth.roll_pitch_heading_deg()[0, 2])
    config.smoother = replace(config.smoother, initial_heading_deg=heading)
    trajectory = run_planar_kf(dataset, config, progress=False)
    settled = trajectory.t > trajectory.t[0] + 20.0
    error = np.linalg.norm((trajectory.position - truth.position)[settled], axis=1)
    assert error.max() < 0.02
    assert trajectory.info["gnss_updates"] == len(k)


def test_pipeline_and_bad_input(uav_loop):
    run, config = uav_loop
    mask = np.ones(len(run.dataset.gnss), dtype=bool)
    mask[60:90] = False
    trajectory = run_method(run.dataset, config, "planar-kf", gnss_mask=mask, progress=False)
    assert trajectory.info["gnss_updates"] == trajectory.info["gnss_epochs_used"]
    with pytest.raises(InputError, match="no usable GNSS"):
        run_planar_kf(run.dataset, config, gnss_mask=np.zeros(len(run.dataset.gnss), bool))
    with pytest.raises(InputError):
        PlanarKfOptions(max_block_s=0.0)


def test_the_planar_fit_on_kitti_is_within_its_sigmas():
    """On the KITTI drive the planar filter's track missed the fixes it used by 0.56 m RMS
    while it claimed 0.22 m and the fixes 0.3 m (residual over claimed variance 2.2, checked
    here from its output); that much was said. The cause was its first tilt, taken braking on
    a slope (see test_a_drive_that_starts_on_a_slope_...): it now fits within its sigmas, as
    the 15-state EKF+RTS does, and neither has anything to say."""
    from fgins.baseline.measurements import select_gnss
    from fgins.config import config_for_dataset
    from fgins.io.inputs import load_dataset

    dataset = load_dataset(["demo:kitti"], progress=False)
    config = config_for_dataset(dataset)
    epochs = select_gnss(dataset, config, None)
    for method in ("planar-kf", "ekf-rts"):
        track = run_method(dataset, config, method, progress=False)
        near = np.clip(np.searchsorted(track.t, epochs.t), 0, len(track) - 1)
        residual = (track.at(epochs.t) - epochs.position)[:, :2]
        claimed = epochs.position_sigma[:, :2] ** 2 + np.stack(
            [track.position_cov[near, 0, 0], track.position_cov[near, 1, 1]], axis=1
        )
        consistency = float(np.mean(residual**2 / claimed))
        notes = [w for w in track.info.get("fit_warnings", []) if "scatter" in w]
        assert consistency < 1.5 and not notes, (method, consistency, notes)


def _independent_car(folder, seed: int, hilly: bool) -> list[tuple[float, float]]:
    """The independent simulator's car: flat through five turns, or over +-8 % grades."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, hilly_drive, write_drive

    profile = (
        hilly_drive()
        if hilly
        else CarProfile(steps=[(10, 8, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    )
    write_drive(
        folder,
        profile,
        240.0,
        grade=INDUSTRIAL,
        imu_rate=100.0,
        jitter=0.0,
        gnss_rate=1.0,
        seed=seed,
    )
    return [(85.0, 125.0)]


def _planar(folder, outages):
    import sys
    from pathlib import Path

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import outage_rms_and_sigma

    dataset = fgins.load(
        folder / "imu.csv", folder / "gnss.csv", config=folder / "cfg.toml", vehicle="car"
    )
    track = fgins.smooth(dataset, "planar-kf", gnss_outage=outages)
    return outage_rms_and_sigma(track, folder, outages)[0], track.info.get("fit_warnings", [])


@pytest.mark.parametrize(("turn", "seed"), [("rfu", 1), ("backward", 2)])
def test_the_planar_filter_travels_along_the_vehicles_forward_axis(tmp_path, turn, seed):
    """An IMU mounted turned in the car (x right and y forward, or facing back): the planar
    filter took the IMU's x for the direction of travel, whatever the mounting (an
    independent simulator's car with the IMU at [180, 0, -90]: 185 m inside a 40 s outage,
    18 m with its forward axis)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import turn_imu_axes

    outages = _independent_car(tmp_path, seed, hilly=False)
    straight, _ = _planar(tmp_path, outages)
    turn_imu_axes(tmp_path, turn)
    turned, _ = _planar(tmp_path, outages)
    assert turned < 1.3 * straight + 1.0, (turned, straight)


@pytest.mark.parametrize(("hilly", "seed"), [(True, 3), (False, 4)])
def test_grades_that_mislead_the_planar_model_are_said(tmp_path, hilly, seed):
    """Over +-8 % grades the planar model reads gravity as acceleration and drifts inside
    outages with sigmas that do not cover it (31-48 m at NEES 12 on 2-3 deg grades, unsaid);
    a flat drive has nothing to say."""
    outages = _independent_car(tmp_path, seed, hilly=hilly)
    _, warnings = _planar(tmp_path, outages)
    said = [w for w in warnings if w.startswith("planar-kf: the vehicle's pitch (a road's grade, an aircraft's climb) changes")]
    assert len(said) == int(hilly), warnings


@pytest.mark.parametrize(
    ("scenario", "seed"), [("highway", 1), ("mems-car-pdop", 2), ("car-urban", 3)]
)
def test_the_planar_sigma_covers_an_unestimated_bias_through_an_outage(scenario, seed):
    """The filter has no bias states: a turn-on gyro bias turns its yaw at a constant rate
    through an outage, and the along-track error grows as t^2. Its noise held that at a 1 s
    horizon, so 30 s outages ended 4-5x outside the sigma (highway: 150 m against 33 m;
    35 % of the outage epochs within 3 sigma). Scored against the simulator's truth: the
    errors now lie within 3 sigma and the sigma is not inflated far beyond them."""
    from fgins.bench.metrics import errors_against
    from fgins.config import config_for_dataset
    from fgins.outages import outage_mask

    run = SCENARIOS[scenario](seed=seed, duration_s=200.0)
    config = config_for_dataset(run.dataset)
    windows = [(60.0, 90.0), (150.0, 180.0)]
    track = run_method(
        run.dataset,
        config,
        "planar-kf",
        gnss_mask=outage_mask(run.dataset, windows),
        progress=False,
    )
    errors = errors_against(track, run.truth.t, run.truth.position, run.dataset.t0, windows)
    inside = errors.inside
    ratio = errors.horizontal[inside] / errors.horizontal_std[inside]
    assert np.mean(ratio <= 3.0) >= 0.9, np.percentile(ratio, [50, 90, 100])
    ends = [np.flatnonzero(inside & (errors.t - run.dataset.t0 < b))[-1] for _, b in windows]
    assert np.all(errors.horizontal[ends] > 0.2 * errors.horizontal_std[ends]), (
        errors.horizontal[ends],
        errors.horizontal_std[ends],
    )


@pytest.mark.parametrize(("slope_deg", "seed"), [(5.0, 1), (-4.0, 2)])
def test_a_drive_that_starts_on_a_slope_is_not_read_as_accelerating_all_along(tmp_path, slope_deg, seed):
    """The planar model levels the accelerometer by the tilt it starts with. A car that
    starts on a 4-5 deg slope and then drives on the flat read g sin(slope) (0.7-0.85 m/s^2)
    as acceleration all drive long: the fixes held its track (20 % slow between them, as on
    KITTI, which starts braking on a slope), and a 40 s outage ended 350-440 m off against a
    12-15 m sigma. The input's constant error against the fixes' change of speed is now taken
    out (it is the first tilt's, found to within 0.1 m/s^2 of g sin(slope))."""
    import sys
    from pathlib import Path

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import (
        FIVE_TURNS,
        INDUSTRIAL,
        CarProfile,
        _ramp,
        outage_rms_and_sigma,
        write_drive,
    )

    slope = np.radians(slope_deg)
    profile = CarProfile(steps=[(2, 8, 12.0)], turns=FIVE_TURNS, gamma=lambda t: slope * (1 - _ramp(t, 12.0, 6.0)))
    write_drive(tmp_path, profile, 240.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0, gnss_rate=1.0, seed=seed)
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml", vehicle="car")
    outage = [(85.0, 125.0)]
    track = fgins.smooth(dataset, "planar-kf", gnss_outage=outage, progress=False)
    rms, sigma = outage_rms_and_sigma(track, tmp_path, outage)
    assert track.info["forward_accel_offset_m_s2"] == pytest.approx(-9.81 * np.sin(slope), abs=0.1)
    assert rms < 10.0, rms
    assert rms < 2.0 * sigma, (rms, sigma)


@pytest.mark.parametrize("seed", [3, 4])
def test_a_climbing_aircraft_s_heights_are_the_planar_model_s_limit_not_the_fixes(tmp_path, seed):
    """fgins's own simulated aircraft (right ellipsoidal heights, 8 m sigma): planar-kf,
    whose height is a random walk between fixes, told the user its heights might be "an
    altitude in feet ... two datums mixed" and spoke of a road's grade (outside tester). The
    heights' scatter is named as the planar model's limit first."""
    drive = fgins.simulate("aircraft-ekf", tmp_path / "air", seed=seed, duration=300, outage_start_s=200)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        track = fgins.smooth(fgins.load(drive), "planar-kf")
    said = [w for w in track.info["fit_warnings"] if "heights scatter" in w]
    assert len(said) == 1 and "the planar filter holds its height between fixes" in said[0], said
    assert not any("road's grade changes" in w for w in track.info["fit_warnings"])
