"""The simulator: exact IMU/truth consistency (incl. GTSAM preintegration), error statistics,
GNSS DOP scaling, scenarios and the output folder."""

from __future__ import annotations

import tomllib
from pathlib import Path

import gtsam
import numpy as np
import pytest

from fgins.config import GnssConfig, imu_noise_from_config
from fgins.datatypes import InputError, Origin, OutputError
from fgins.factors.imu import with_gravity
from fgins.geodesy import lla_to_enu, so3_log
from fgins.io.csv_pair import read_csv_dataset
from fgins.io.trajectory_csv import read_trajectory_csv
from fgins.sim import motion
from fgins.sim.baro import BaroModel, height_from_pressure, pressure_from_height, simulate_baro
from fgins.sim.gnss import (
    BiasedStretch,
    DopStretch,
    GnssModel,
    GnssTruthInput,
    simulate_gnss,
)
from fgins.sim.imu_errors import ImuErrorModel, SensorErrors, apply_imu_errors
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.strapdown import NavModel, exact_motion, mechanize
from fgins.sim.writer import dumps_toml, write_sim_dir

ORIGIN = Origin(48.0, 11.0, 500.0)


def _angle(r_a: np.ndarray, r_b: np.ndarray) -> float:
    return float(np.linalg.norm(so3_log(r_a.T @ r_b)))


# --- exact IMU ------------------------------------------------------------------------------


@pytest.mark.parametrize("build", [motion.urban_car, motion.aircraft])
def test_step_by_step_mechanization_reproduces_truth(build) -> None:
    nav = NavModel.at(ORIGIN)
    exact = exact_motion(build(100.0, 60.0), nav)
    rot, vel, pos = mechanize(
        exact.t, exact.gyro, exact.accel, exact.rotation[0], exact.velocity[0],
        exact.position[0], nav,
    )  # fmt: skip
    assert np.abs(pos - exact.position).max() < 1e-8
    assert np.abs(vel - exact.velocity).max() < 1e-9
    assert max(_angle(a, b) for a, b in zip(rot[::500], exact.rotation[::500], strict=True)) < 1e-12


def _gtsam_chain(exact, nav: NavModel, start: int, steps: int, chunk: int, coriolis: bool):
    """Integrate the error-free IMU with PreintegratedCombinedMeasurements, ``chunk`` samples
    per preintegration, predicting from the true state at ``start``."""
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(-nav.gravity[2])
    if coriolis:
        params.setOmegaCoriolis(nav.earth_rate)
    state = gtsam.NavState(
        gtsam.Rot3(exact.rotation[start]), exact.position[start], exact.velocity[start]
    )
    bias = gtsam.imuBias.ConstantBias()
    dt = float(exact.t[1] - exact.t[0])
    k = start
    while k < start + steps:
        # Gravity where the chunk lies: the simulator's round Earth takes it where each
        # sample starts; the smoother at its interval's middle.
        where = exact.position[k] if chunk == 1 else exact.position[k : k + chunk].mean(axis=0)
        pim = gtsam.PreintegratedCombinedMeasurements(with_gravity(params, nav.gravity_at(where)))
        for j in range(k, k + chunk):
            pim.integrateMeasurement(exact.accel[j], exact.gyro[j], dt)
        state = pim.predict(state, bias)
        k += chunk
    position_error = float(np.abs(state.position() - exact.position[k]).max())
    return position_error, _angle(state.attitude().matrix(), exact.rotation[k])


@pytest.mark.parametrize("build", [motion.urban_car, motion.highway, motion.aircraft])
@pytest.mark.parametrize("chunk", [1, 100])
def test_gtsam_preintegration_reproduces_truth_without_earth_rate(build, chunk) -> None:
    # GTSAM's preintegration + predict is the discrete model exactly when omegaCoriolis is off:
    # 60 s, per sample or in 1-s keyframes.
    nav = NavModel.at(ORIGIN, with_earth_rate=False)
    exact = exact_motion(build(100.0, 200.0), nav)
    pos_err, att_err = _gtsam_chain(exact, nav, 12000, 6000, chunk, coriolis=False)
    # Tangent-space preintegration over 1-s chunks adds O(dt^2) per step under fast attitude
    # changes (aircraft turns); per-sample chaining is exact. One gravity per 1-s chunk (the
    # round Earth's changes by 1.5 ug per 1 m travelled) leaves g' T^3 / 12 per chunk: 0.2 mm
    # over the minute at highway speed.
    tolerance = 1e-6 if chunk == 1 else 5e-3 if build is motion.aircraft else 1e-3
    assert pos_err < tolerance
    assert att_err < 1e-6


@pytest.mark.parametrize("build", [motion.urban_car, motion.circular_loop])
def test_gtsam_preintegration_with_coriolis_reproduces_truth(build) -> None:
    # With omegaCoriolis = w_ie GTSAM 4.3 integrates the Coriolis term with higher-order terms
    # (-dt^2 w x g, -1.5 dt^2 w x R f per step) that the first-order model of the estimators
    # omits; both agree as dt -> 0 and stay within 1 mm / 1 urad over 10 s at 100 Hz.
    nav = NavModel.at(ORIGIN)
    exact = exact_motion(build(100.0, 120.0), nav)
    pos_err, att_err = _gtsam_chain(exact, nav, 2000, 1000, 1, coriolis=True)
    assert pos_err < 1e-3
    assert att_err < 1e-6


def test_car_velocity_stays_along_body_x_and_aircraft_turns_are_coordinated() -> None:
    nav = NavModel.at(ORIGIN)
    car = exact_motion(motion.urban_car(100.0, 200.0), nav)
    body_v = np.einsum("nji,nj->ni", car.rotation, car.velocity)
    assert np.abs(body_v[:, 1:]).max() < 1e-9
    assert body_v[:, 0].max() > 10.0
    # Turning happens: heading changes by more than 90 degrees over the drive.
    yaw_rate = car.gyro[:, 2]
    assert np.abs(yaw_rate).max() > 0.2
    plane = exact_motion(motion.aircraft(100.0, 400.0), nav)
    turning = np.abs(plane.gyro[:, 2]) > 0.02
    # Coordinated: the lateral specific force is small next to the centripetal acceleration.
    speed = np.linalg.norm(plane.velocity, axis=1)
    centripetal = speed[turning] * np.linalg.norm(plane.gyro[turning], axis=1)
    assert centripetal.mean() > 1.0
    lateral = np.abs(plane.accel[turning, 1])
    assert np.percentile(lateral, 95) < 0.1 * centripetal.mean()


# --- IMU errors ------------------------------------------------------------------------------


def test_white_noise_and_bias_random_walk_match_densities() -> None:
    rng = np.random.default_rng(7)
    dt, n = 0.01, 200_000
    model = ImuErrorModel(
        gyro=SensorErrors(noise_density=1e-3, bias_rw=2e-5, turn_on_bias=(0.01, -0.02, 0.03)),
        accel=SensorErrors(noise_density=2e-2, bias_rw=4e-4, turn_on_sigma=0.1),
    )
    zeros = np.zeros((n, 3))
    gyro, accel, gyro_bias, accel_bias = apply_imu_errors(rng, zeros, zeros, dt, model)
    for measured, bias, errors in ((gyro, gyro_bias, model.gyro), (accel, accel_bias, model.accel)):
        white = measured - bias
        assert np.allclose(white.std(axis=0), errors.noise_density / np.sqrt(dt), rtol=0.02)
        steps = np.diff(bias, axis=0)
        assert np.allclose(steps.std(axis=0), errors.bias_rw * np.sqrt(dt), rtol=0.02)
    assert np.allclose(gyro_bias[0], [0.01, -0.02, 0.03])


def test_turn_on_bias_spread_and_scale_factor() -> None:
    rng = np.random.default_rng(3)
    model = ImuErrorModel(gyro=SensorErrors(turn_on_sigma=0.05, scale_factor=(0.01, 0, -0.02)))
    true = np.tile([1.0, 2.0, 3.0], (10, 1))
    starts = []
    for _ in range(2000):
        gyro, _, bias, _ = apply_imu_errors(rng, true, true, 0.01, model)
        starts.append(bias[0])
    assert np.allclose(np.std(starts, axis=0), 0.05, rtol=0.06)
    assert np.allclose(gyro - bias, true * [1.01, 1.0, 0.98])


def test_imu_noise_from_preset_is_what_gets_simulated() -> None:
    noise = imu_noise_from_config({"preset": "industrial-mems"})
    model = ImuErrorModel.from_noise(noise)
    assert model.gyro.noise_density == noise.gyro_noise
    assert model.accel.bias_rw == noise.accel_bias_rw


# --- GNSS and baro ---------------------------------------------------------------------------


def _standing_truth(seconds: float, rate: float) -> GnssTruthInput:
    n = int(seconds * rate)
    return GnssTruthInput(
        t=np.arange(n) / rate,
        position=np.tile([10.0, -5.0, 2.0], (n, 1)),
        velocity=np.zeros((n, 3)),
        rotation=np.tile(np.eye(3), (n, 1, 1)),
        body_rate=np.zeros((n, 3)),
    )


def test_gnss_noise_scales_with_dop() -> None:
    truth = _standing_truth(12_000.0, 10.0)
    stretches = (DopStretch(3000.0, 6000.0, 3.0), DopStretch(6000.0, 9000.0, 6.0))
    model = GnssModel(rate_hz=10.0, uere_m=2.0, dop_stretches=stretches)
    gnss, info = simulate_gnss(np.random.default_rng(11), truth, ORIGIN, model)
    error = lla_to_enu(gnss.lla, ORIGIN) - truth.position[0]
    for low, high in ((0.8, 1.4), (2.5, 3.5), (5.0, 7.0)):
        in_bin = (gnss.hdop >= low) & (gnss.hdop < high)
        assert in_bin.sum() > 5000
        # Normalised by the reported DOP: unit variance per axis if sigma = UERE x DOP.
        east_north = error[in_bin, :2] / (2.0 * gnss.hdop[in_bin, None])
        up = error[in_bin, 2] / (2.0 * gnss.vdop[in_bin])
        assert np.allclose(east_north.std(axis=0), 1.0, rtol=0.04)
        assert np.std(up) == pytest.approx(1.0, rel=0.04)
        assert np.allclose(gnss.std[in_bin, 0], 2.0 * gnss.hdop[in_bin])
    assert np.allclose(gnss.pdop, np.hypot(gnss.hdop, gnss.vdop), atol=0.011)
    assert info.removed_epochs == 0


def test_gnss_outliers_bias_outages_and_lever_arm() -> None:
    truth = _standing_truth(2000.0, 10.0)
    truth.rotation[:] = motion.euler_to_rotation(np.array(0.0), np.array(0.0), np.array(1.0))
    model = GnssModel(
        rate_hz=1.0,
        sigma_m=(0.01, 0.01, 0.01),
        lever_arm_m=(1.0, 0.0, 2.0),
        biased_stretches=(BiasedStretch(100.0, 130.0, (10.0, -5.0, 0.0)),),
        outlier_fraction=0.1,
        outlier_size_m=30.0,
        outages=((500.0, 560.0),),
        velocity_sigma_m_per_s=0.05,
    )
    gnss, info = simulate_gnss(np.random.default_rng(5), truth, ORIGIN, model)
    rel_t = gnss.t - info.epoch_t[0]
    assert not np.any((rel_t >= 500.0) & (rel_t < 560.0))
    assert info.removed_epochs == 60 and len(gnss) == 2000 - 60
    antenna = truth.position[0] + truth.rotation[0] @ [1.0, 0.0, 2.0]
    error = lla_to_enu(gnss.lla, ORIGIN) - antenna
    jumps = np.linalg.norm(error, axis=1) > 25.0
    assert 0.07 < jumps.mean() < 0.13
    biased = (rel_t >= 100.0) & (rel_t < 130.0) & ~jumps
    assert np.allclose(np.median(error[biased], axis=0), [10.0, -5.0, 0.0], atol=0.05)
    clean = ~jumps & ~((rel_t >= 100.0) & (rel_t < 130.0))
    assert np.abs(error[clean]).max() < 0.06
    assert np.abs(gnss.velocity).max() < 0.3


def test_gnss_rate_must_divide_imu_rate() -> None:
    with pytest.raises(InputError, match="does not divide"):
        simulate_gnss(
            np.random.default_rng(0), _standing_truth(10.0, 100.0), ORIGIN, GnssModel(rate_hz=3.0)
        )


def test_baro_pressure_heights_and_noise() -> None:
    assert pressure_from_height(np.array(0.0)) == pytest.approx(101325.0)
    # ISA table value at 1000 m: 89875 Pa.
    assert pressure_from_height(np.array(1000.0)) == pytest.approx(89875.0, rel=2e-4)
    t = np.arange(40_000) / 20.0
    height = 300.0 + 5.0 * np.sin(t / 30.0)
    model = BaroModel(rate_hz=20.0, noise_m=0.4, bias_rw_m_per_sqrt_s=0.0, initial_bias_m=2.0)
    baro, bias = simulate_baro(np.random.default_rng(2), t, height, model)
    residual = height_from_pressure(baro.pressure) - height
    assert np.allclose(bias, 2.0)
    assert residual.mean() == pytest.approx(2.0, abs=0.01)
    assert residual.std() == pytest.approx(0.4, rel=0.03)
    assert np.allclose(baro.height, height_from_pressure(baro.pressure))


# --- scenarios -------------------------------------------------------------------------------


def test_aircraft_ekf_scenario_promises() -> None:
    run = SCENARIOS["aircraft-ekf"](seed=1)
    data, truth = run.dataset, run.truth
    assert data.imu.rate_hz == pytest.approx(100.0)
    assert truth.t[-1] - truth.t[0] >= 700.0
    assert np.allclose(truth.accel_bias, np.array([10.0, -10.0, 10.0]) * 9.80665e-3)
    assert np.allclose(truth.gyro_bias, np.radians([-50.0, 50.0, -50.0]) / 3600.0)
    rel_t = data.gnss.t - data.t0
    assert np.allclose(np.diff(rel_t[rel_t < 500.0]), 1.0)
    assert not np.any((rel_t >= 500.0) & (rel_t < 560.0))
    assert run.outages == [(500.0, 560.0)]
    assert np.allclose(data.gnss.std, [5.0, 5.0, 8.0])
    assert np.allclose(data.gnss.velocity_std, 0.1)
    assert run.initial_errors == {"position_m": 50.0, "velocity_m_per_s": 0.1, "attitude_deg": 1.0}
    speed = np.linalg.norm(truth.velocity, axis=1)
    assert 90.0 < np.median(speed[truth.t > 200.0]) < 110.0
    assert truth.position[:, 2].max() > 300.0  # it climbs


def test_mems_car_pdop_has_a_biased_high_pdop_stretch() -> None:
    run = SCENARIOS["mems-car-pdop"](seed=2)
    data = run.dataset
    assert data.imu.rate_hz == pytest.approx(20.0)
    assert np.allclose(np.diff(data.gnss.t), 0.5)
    high = data.gnss.pdop > 5.0
    assert 25.0 <= high.sum() / 2.0 <= 35.0
    error = data.gnss_enu() - run.truth.at(data.gnss.t)
    horizontal_bias = np.linalg.norm(np.median(error[high], axis=0)[:2])
    assert 8.0 <= horizontal_bias <= 15.0
    assert np.linalg.norm(np.median(error[~high], axis=0)[:2]) < 1.0


@pytest.mark.parametrize("rate", [1.0, 0.5])
def test_uav_loop_baro_rates_and_radius(rate: float) -> None:
    run = SCENARIOS["uav-loop-baro"](seed=0, gnss_rate_hz=rate, duration_s=120.0)
    data = run.dataset
    assert data.baro is not None and np.allclose(np.diff(data.baro.t), 0.05)
    assert np.allclose(np.diff(data.gnss.t), 1.0 / rate)
    steady = run.truth.t > 20.0
    pos = run.truth.position[steady, :2]
    radius = np.linalg.norm(pos - (pos.max(axis=0) + pos.min(axis=0)) / 2.0, axis=1)
    assert np.allclose(radius, 25.0, atol=0.05)
    speed = np.linalg.norm(run.truth.velocity[steady], axis=1)
    assert np.allclose(speed, 11.0 / 3.6)


@pytest.mark.parametrize("name", ["car-urban", "highway"])
@pytest.mark.parametrize("grade", ["consumer-mems", "industrial-mems"])
def test_car_scenarios(name: str, grade: str) -> None:
    run = SCENARIOS[name](seed=4, grade=grade, duration_s=120.0)
    data, truth = run.dataset, run.truth
    assert data.imu.rate_hz == pytest.approx(100.0)
    assert np.allclose(np.diff(data.gnss.t), 1.0)
    assert truth.t[-1] == pytest.approx(120.0 - 0.01)
    body_v = np.einsum("nji,nj->ni", truth.rotation, truth.velocity)
    assert np.abs(body_v[:, 1]).max() < 1e-6
    assert imu_noise_from_config(run.config["imu"]) == imu_noise_from_config({"preset": grade})
    GnssConfig.from_dict(run.config["gnss"])


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_every_scenario_is_reproducible_and_consistent(name: str) -> None:
    first = SCENARIOS[name](seed=9, duration_s=60.0)
    again = SCENARIOS[name](seed=9, duration_s=60.0)
    other = SCENARIOS[name](seed=10, duration_s=60.0)
    assert np.array_equal(first.dataset.imu.gyro, again.dataset.imu.gyro)
    assert not np.array_equal(first.dataset.imu.gyro, other.dataset.imu.gyro)
    assert np.allclose(first.truth.t, first.dataset.imu.t)
    assert first.dataset.imu_config == first.config["imu"]
    assert first.dataset.gnss_config == first.config["gnss"]
    GnssConfig.from_dict(first.config["gnss"])
    imu_noise_from_config(first.config["imu"])


def test_bad_scenario_options_are_one_clear_error() -> None:
    with pytest.raises(InputError, match="unknown option"):
        SCENARIOS["highway"](seed=0, durration_s=10.0)
    with pytest.raises(InputError, match="grade"):
        SCENARIOS["car-urban"](grade="navigation-grade")
    with pytest.raises(InputError, match="gnss_rate_hz"):
        SCENARIOS["uav-loop-baro"](gnss_rate_hz=3.0)


# --- writer ----------------------------------------------------------------------------------


def test_write_sim_dir_round_trip(tmp_path: Path) -> None:
    run = SCENARIOS["uav-loop-baro"](seed=3, duration_s=60.0)
    write_sim_dir(run, tmp_path / "out")
    folder = tmp_path / "out"
    names = {"imu.csv", "gnss.csv", "baro.csv", "config.toml", "truth.csv"}
    assert {p.name for p in folder.iterdir()} == names
    config = tomllib.loads((folder / "config.toml").read_text())
    assert config["imu"] == run.config["imu"]
    assert config["gnss"] == run.config["gnss"]
    assert config["origin"] == {"lat": 52.52, "lon": 13.405, "alt": 60.0}
    assert config["scenario"]["name"] == "uav-loop-baro" and config["scenario"]["seed"] == 3
    truth = read_trajectory_csv(folder / "truth.csv")
    assert np.abs(truth.position - run.truth.position).max() < 1e-4
    # Bias columns carry 5 significant digits.
    assert np.allclose(truth.accel_bias, run.truth.accel_bias, rtol=1e-4, atol=0)
    assert (
        max(
            _angle(a, b)
            for a, b in zip(truth.rotation[::50], run.truth.rotation[::50], strict=True)
        )
        < 1e-5
    )
    dataset = read_csv_dataset([folder])
    assert np.allclose(dataset.imu.gyro, run.dataset.imu.gyro, rtol=1e-9, atol=1e-15)
    # gnss.csv carries 1e-9 deg and 0.1 mm of altitude.
    assert np.allclose(dataset.gnss.lla[:, :2], run.dataset.gnss.lla[:, :2], rtol=0, atol=1e-8)
    assert np.allclose(dataset.gnss.lla[:, 2], run.dataset.gnss.lla[:, 2], rtol=0, atol=1e-4)
    assert dataset.baro is not None and len(dataset.baro.t) == len(run.dataset.baro.t)


def test_toml_emitter_round_trips_awkward_values() -> None:
    tables = {
        "a": {"s": 'quote " and \\ back\nslash', "f": 1e-5, "i": -3, "b": True, "big": 1e300},
        "b": {"nested": {"x": [1.0, 2.0], "y": "z"}, "empty": [], "arrays": [[1.5, 2.5]]},
    }
    assert tomllib.loads(dumps_toml(tables)) == tables


# --- IMU rate, body-axis conventions, mounting, bias model (issue 12) ------------------------

FRD = np.diag([1.0, -1.0, -1.0])


def _ypr(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """R_vehicle_imu of mounting angles, built by GTSAM (independent of the simulator)."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    return gtsam.Rot3.Ypr(y, p, r).matrix()


@pytest.mark.parametrize("frame, z_sign", [("flu", 1.0), ("frd", -1.0)])
def test_specific_force_at_rest_points_up_and_left_turn_rate_sign(frame, z_sign) -> None:
    run = SCENARIOS["car-urban"](seed=0, duration_s=60.0, body_frame=frame, grade="navigation")
    imu, truth = run.dataset.imu, run.truth
    g = 9.80665
    rest = (imu.t - imu.t[0]) < 9.0  # the drive starts standing
    # At rest the accelerometer measures the reaction to gravity: up, i.e. +z in FLU, -z in FRD.
    assert np.allclose(imu.accel[rest].mean(axis=0), [0.0, 0.0, z_sign * g], atol=2e-3)
    # The first junction turn is a 90-degree LEFT turn (37-45 s): positive yaw rate about an
    # up axis, negative about a down axis.
    turning = ((imu.t - imu.t[0]) > 39.0) & ((imu.t - imu.t[0]) < 43.0)
    assert z_sign * imu.gyro[turning, 2].mean() > np.radians(10.0)
    # The truth attitude is the IMU's: the body x axis is the travel direction in both frames
    # and the body z axis points up (FLU) or down (FRD) on level ground.
    body_z_up = truth.rotation[rest][:, 2, 2]
    assert np.allclose(body_z_up, z_sign, atol=1e-9)
    moving = np.linalg.norm(truth.velocity, axis=1) > 5.0
    forward = np.einsum("nji,nj->ni", truth.rotation[moving], truth.velocity[moving])
    assert np.abs(forward[:, 1:]).max() < 1e-9 and forward[:, 0].min() > 5.0


def test_frd_and_mounting_are_the_flu_samples_rotated() -> None:
    base = SCENARIOS["highway"](seed=5, duration_s=60.0)
    frd = SCENARIOS["highway"](seed=5, duration_s=60.0, body_frame="frd")
    mounted = SCENARIOS["car-urban"](seed=5, duration_s=60.0, mounting_rpy_deg="[20,-10,35]")
    flat = SCENARIOS["car-urban"](seed=5, duration_s=60.0)
    # Truth: R_n_imu = R_n_vehicle F (FRD), R_n_vehicle R_vehicle_imu (mounting); positions equal.
    assert np.allclose(frd.truth.rotation, base.truth.rotation @ FRD, atol=1e-12)
    r_vi = _ypr(20.0, -10.0, 35.0)
    assert np.allclose(mounted.truth.rotation, flat.truth.rotation @ r_vi, atol=1e-12)
    assert np.allclose(mounted.truth.position, flat.truth.position, atol=1e-9)
    # The samples rotate as vectors, omega_imu = A^T omega_vehicle (rows: omega @ A), errors
    # included: they are drawn in the vehicle's axes, so one seed is one physical run.
    for a, b, axes in ((frd, base, FRD), (mounted, flat, r_vi)):
        assert np.allclose(a.dataset.imu.gyro, b.dataset.imu.gyro @ axes, rtol=0, atol=1e-12)
        assert np.allclose(a.dataset.imu.accel, b.dataset.imu.accel @ axes, rtol=0, atol=1e-11)
        assert np.allclose(a.truth.gyro_bias, b.truth.gyro_bias @ axes, rtol=0, atol=1e-15)
        assert np.allclose(a.truth.accel_bias, b.truth.accel_bias @ axes, rtol=0, atol=1e-14)
        # The GNSS fixes are the same draws of the same antenna positions.
        assert np.allclose(a.dataset.gnss.lla, b.dataset.gnss.lla, rtol=0, atol=1e-9)
    # The lever arm of the antenna is the same physical point, written in the IMU's axes.
    lever_flat = np.array(flat.config["gnss"]["lever_arm_m"])
    lever_mounted = np.array(mounted.config["gnss"]["lever_arm_m"])
    assert np.allclose(r_vi @ lever_mounted, lever_flat, atol=1e-12)
    assert frd.config["gnss"]["lever_arm_m"] == [0.0, 0.0, -1.5]
    assert mounted.config["smoother"] == {"imu_to_vehicle_rpy_deg": [20.0, -10.0, 35.0]}
    # The vehicle frame is FLU (fgins.mounting): an FRD IMU is stated as roll 180.
    assert frd.config["smoother"] == {"imu_to_vehicle_rpy_deg": [180.0, 0.0, 0.0]}
    assert "smoother" not in flat.config and "smoother" not in base.config


@pytest.mark.parametrize("mounting", [(20, -10, 35), (0, 0, 90), (180, 0, -30), (5, 89.9, 10)])
def test_written_orientation_is_the_imu_axes_in_the_flu_vehicle(mounting) -> None:
    """FRD plus a mounting: the [smoother] angles, turned into R_vi by GTSAM's Ypr, are
    F R(mounting), and the truth is R_n_vehicle R_vi."""
    options = {"duration_s": 20.0, "body_frame": "frd", "mounting_rpy_deg": list(mounting)}
    run = SCENARIOS["car-urban"](seed=0, **options)
    flat = SCENARIOS["car-urban"](seed=0, duration_s=20.0)
    written = _ypr(*run.config["smoother"]["imu_to_vehicle_rpy_deg"])
    assert np.allclose(written, FRD @ _ypr(*mounting), atol=1e-9)
    assert np.allclose(run.truth.rotation, flat.truth.rotation @ written, atol=1e-9)


@pytest.mark.parametrize(
    "frame, mounting", [("flu", (0, 0, 0)), ("frd", (0, 0, 0)), ("frd", (20, -10, 35))]
)
def test_rotated_exact_imu_is_consistent_with_strapdown_and_gtsam(frame, mounting) -> None:
    """In any IMU axes the error-free samples reproduce the truth through the step-by-step
    mechanization and through GTSAM's per-sample preintegration."""
    axes = (FRD if frame == "frd" else np.eye(3)) @ _ypr(*mounting)
    nav = NavModel.at(ORIGIN)
    exact = exact_motion(motion.aircraft(100.0, 125.0), nav, imu_axes=axes)
    k = slice(9500, None)  # the climbing, banked 60-degree turn at 100-120 s
    rot, vel, pos = mechanize(
        exact.t[k], exact.gyro[k], exact.accel[k], exact.rotation[9500], exact.velocity[9500],
        exact.position[9500], nav,
    )  # fmt: skip
    assert np.abs(pos - exact.position[k]).max() < 1e-7
    assert np.abs(vel - exact.velocity[k]).max() < 1e-8
    assert (
        max(_angle(a, b) for a, b in zip(rot[::250], exact.rotation[k][::250], strict=True)) < 1e-11
    )
    nav0 = NavModel.at(ORIGIN, with_earth_rate=False)
    exact0 = exact_motion(motion.aircraft(100.0, 125.0), nav0, imu_axes=axes)
    pos_err, att_err = _gtsam_chain(exact0, nav0, 9500, 2500, 1, coriolis=False)
    assert pos_err < 1e-6 and att_err < 1e-6


def test_written_imu_integrates_to_written_truth(tmp_path: Path) -> None:
    """imu.csv minus truth.csv's biases, strapdown-integrated from truth.csv's first row,
    follows truth.csv (navigation grade: the white noise is far below the tolerance)."""
    options = {"duration_s": 60.0, "grade": "navigation", "body_frame": "frd"}
    run = SCENARIOS["car-urban"](seed=8, mounting_rpy_deg=[20, -10, 35], **options)
    write_sim_dir(run, tmp_path / "drive")
    dataset = read_csv_dataset([tmp_path / "drive"])
    truth = read_trajectory_csv(tmp_path / "drive" / "truth.csv")
    nav = NavModel.at(dataset.origin)
    rot, vel, pos = mechanize(
        dataset.imu.t, dataset.imu.gyro - truth.gyro_bias, dataset.imu.accel - truth.accel_bias,
        truth.rotation[0], truth.velocity[0], truth.position[0], nav,
    )  # fmt: skip
    assert np.abs(pos - truth.position).max() < 0.2
    assert np.abs(vel - truth.velocity).max() < 0.01
    assert max(_angle(a, b) for a, b in zip(rot[::100], truth.rotation[::100], strict=True)) < 3e-4
    table = tomllib.loads((tmp_path / "drive" / "config.toml").read_text())
    assert np.allclose(
        _ypr(*table["smoother"]["imu_to_vehicle_rpy_deg"]), FRD @ _ypr(20, -10, 35), atol=1e-9
    )
    assert table["scenario"]["body_frame"] == "frd"
    assert table["scenario"]["turns"][0][0] == pytest.approx(37.0, abs=1.0)


def test_write_mounting_false_leaves_the_mounting_out(tmp_path: Path) -> None:
    run = SCENARIOS["car-urban"](
        seed=0, duration_s=30.0, mounting_rpy_deg="20,-10,35", write_mounting="false"
    )
    write_sim_dir(run, tmp_path / "d")
    table = tomllib.loads((tmp_path / "d" / "config.toml").read_text())
    assert "smoother" not in table
    # The data are still rotated: at rest the specific force is not along the IMU's z axis.
    f = run.dataset.imu.accel[:500].mean(axis=0)
    assert abs(f[2]) < 0.95 * np.linalg.norm(f)


@pytest.mark.parametrize("name", ["car-urban", "highway", "aircraft-ekf"])
def test_constant_bias_model_states_zero_instability(name) -> None:
    run = SCENARIOS[name](seed=1, duration_s=60.0, bias_model="constant")
    assert np.ptp(run.truth.gyro_bias, axis=0).max() == 0.0
    assert np.ptp(run.truth.accel_bias, axis=0).max() == 0.0
    assert np.abs(run.truth.gyro_bias[0]).max() > 0.0  # a turn-on bias is there
    imu = run.config["imu"]
    assert imu["gyro_bias_instability_deg_per_hr"] == 0.0
    assert imu["accel_bias_instability_mg"] == 0.0
    noise = imu_noise_from_config(imu)
    assert noise.gyro_bias_rw == 0.0 and noise.accel_bias_rw == 0.0
    walk = SCENARIOS[name](seed=1, duration_s=60.0, bias_model="random_walk")
    assert np.ptp(walk.truth.gyro_bias, axis=0).min() > 0.0
    assert imu_noise_from_config(walk.config["imu"]).gyro_bias_rw > 0.0


@pytest.mark.parametrize("grade", ["tactical", "navigation"])
def test_grades_and_gnss_velocity_option(grade) -> None:
    run = SCENARIOS["highway"](seed=2, duration_s=30.0, grade=grade, gnss_velocity=False)
    assert imu_noise_from_config(run.config["imu"]) == imu_noise_from_config({"preset": grade})
    velocity = run.dataset.gnss.velocity
    assert velocity is None or not np.isfinite(velocity).any()
    assert GnssConfig.from_dict(run.config["gnss"]).use_velocity is False


@pytest.mark.parametrize("rate", [50, 200, 400])
def test_imu_rate_option(rate) -> None:
    run = SCENARIOS["highway"](seed=0, duration_s=20.0, imu_rate_hz=rate)
    dt = np.diff(run.dataset.imu.t)
    assert np.allclose(dt, 1.0 / rate, rtol=1e-9, atol=1e-12)
    assert len(run.dataset.imu) == 20 * rate
    assert run.config["imu"]["rate_hz"] == pytest.approx(rate)
    assert len(run.dataset.gnss) == 20


def test_long_high_rate_drive_is_generated_quickly() -> None:
    """An hour at 200 Hz is vectorised: here 20 min, linear in length (bounded per sample)."""
    import time

    start = time.perf_counter()
    run = SCENARIOS["highway"](seed=0, duration_s=1200.0, imu_rate_hz=200)
    elapsed = time.perf_counter() - start
    assert len(run.dataset.imu) == 240_000
    assert elapsed < 10.0  # ~0.6 s here; a per-sample Python loop would take minutes


def test_bad_imu_options_are_one_clear_error() -> None:
    bad = [
        {"body_frame": "ned"},
        {"mounting_rpy_deg": "[1,2]"},
        {"mounting_rpy_deg": "a,b,c"},
        {"bias_model": "gauss-markov"},
        {"write_mounting": "maybe"},
        {"imu_rate_hz": 0},
        {"imu_rate_hz": 150.5},  # the 1 Hz GNSS does not divide it
        {"duration_s": -5},
        {"grade": "military"},
    ]
    for options in bad:
        with pytest.raises(InputError, match=r"option|grade|GNSS rate"):
            SCENARIOS["car-urban"](seed=0, **{"duration_s": 10.0, **options})


def test_sim_never_writes_over_a_folder_it_did_not_write(tmp_path: Path) -> None:
    """``fgins sim -o FOLDER`` overwrote imu.csv, gnss.csv, config.toml and truth.csv of
    whatever folder it was given (an outside tester lost a drive that way), and left an
    earlier scenario's baro.csv behind, which the next smooth then used (566 -> 627 dof).
    Now: a folder with anything but an earlier sim's files is refused, nothing written; an
    earlier sim folder is rewritten whole."""
    own = tmp_path / "drive"
    own.mkdir()
    (own / "imu.csv").write_text("my data\n")
    (own / "notes.txt").write_text("keep\n")
    with pytest.raises(OutputError, match=r"not empty .* not written by fgins sim"):
        write_sim_dir(SCENARIOS["car-urban"](seed=1, duration_s=20), own)
    assert (own / "imu.csv").read_text() == "my data\n"
    assert sorted(p.name for p in own.iterdir()) == ["imu.csv", "notes.txt"]

    folder = tmp_path / "sim"
    write_sim_dir(SCENARIOS["uav-loop-baro"](seed=1, duration_s=20), folder)
    assert (folder / "baro.csv").exists()
    write_sim_dir(SCENARIOS["car-urban"](seed=1, duration_s=20), folder)
    assert not (folder / "baro.csv").exists()
    assert read_csv_dataset([folder]).baro is None


@pytest.mark.parametrize("name", ["aircraft-ekf", "mems-car-pdop", "uav-loop-baro", "car-urban", "highway"])
def test_a_shortened_run_describes_only_what_it_holds(name) -> None:
    """A run cut to 70 s names no stretch or outage time beyond it (outside tester: a 150 s
    car-urban said 'HDOP 7 at 180-200 s')."""
    import re

    description = SCENARIOS[name](0, duration_s=70.0).description
    times = [float(x) for pair in re.findall(r"(\d+(?:\.\d+)?)-(\d+(?:\.\d+)?) s", description) for x in pair]
    times += [float(x) for x in re.findall(r"(?:from|at) (\d+(?:\.\d+)?)(?: s| to)", description)]
    assert all(t <= 70.0 for t in times), description
