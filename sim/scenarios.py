"""Seed scenarios: complete simulated runs (dataset + truth + sensor settings).

Every scenario is ``fn(seed: int = 0, **options) -> SimRun`` in :data:`SCENARIOS`; all accept
``duration_s`` (to shorten them in tests) and ``start_time_s`` (time of the first sample).
The config tables are valid ``[imu]`` / ``[gnss]`` tables (fgins.config) that state the
simulated sensors exactly (``*_si`` keys), so estimators can be tuned with the truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fgins.config import ImuNoise, imu_noise_from_config
from fgins.datatypes import Dataset, ImuData, InputError, Origin, Trajectory
from fgins.sim import motion
from fgins.sim.baro import BaroModel, simulate_baro
from fgins.sim.gnss import BiasedStretch, DopStretch, GnssModel, GnssTruthInput, simulate_gnss
from fgins.sim.imu_errors import ImuErrorModel, apply_imu_errors
from fgins.sim.strapdown import NavModel, exact_motion

DEG = np.pi / 180.0
MG = 1e-3 * 9.80665
GRADES = ("consumer-mems", "industrial-mems")


@dataclass
class SimRun:
    """A simulated run: the dataset the estimators see, the truth, and the settings."""

    dataset: Dataset
    truth: Trajectory
    config: dict[str, dict[str, Any]]
    description: str
    outages: list[tuple[float, float]] = field(default_factory=list)
    initial_errors: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


def imu_table(preset: str, noise: ImuNoise, rate_hz: float) -> dict[str, Any]:
    """An ``[imu]`` table that reproduces ``noise`` exactly through imu_noise_from_config."""
    return {
        "preset": preset,
        "gyro_noise_rad_per_s_per_sqrt_hz": noise.gyro_noise,
        "accel_noise_m_per_s2_per_sqrt_hz": noise.accel_noise,
        "gyro_bias_rw_rad_per_s_per_sqrt_s": noise.gyro_bias_rw,
        "accel_bias_rw_m_per_s2_per_sqrt_s": noise.accel_bias_rw,
        "gyro_turn_on_bias_deg_per_s": noise.gyro_bias_prior / DEG,
        "accel_turn_on_bias_mg": noise.accel_bias_prior / MG,
        "rate_hz": rate_hz,
    }


def gnss_table(model: GnssModel) -> dict[str, Any]:
    """A ``[gnss]`` table (fgins.config.GnssConfig keys) describing ``model``."""
    table: dict[str, Any] = {"lever_arm_m": list(model.lever_arm_m)}
    if model.sigma_m is not None:
        table["sigma_m"] = list(model.sigma_m)
    else:
        table["uere_m"] = {"autonomous": model.uere_m}
    if model.velocity_sigma_m_per_s is not None:
        table["velocity_sigma_m_per_s"] = model.velocity_sigma_m_per_s
    else:
        table["use_velocity"] = False
    return table


def _check_options(name: str, options: dict[str, Any], allowed: set[str]) -> None:
    unknown = set(options) - allowed
    if unknown:
        raise InputError(
            f"scenario {name}: unknown option(s) {', '.join(sorted(unknown))}; "
            f"allowed: {', '.join(sorted(allowed))}"
        )


def simulate_run(
    *,
    name: str,
    seed: int,
    profile: motion.MotionProfile,
    origin: Origin,
    imu_preset: str,
    noise: ImuNoise,
    errors: ImuErrorModel,
    gnss_model: GnssModel,
    baro_model: BaroModel | None = None,
    description: str = "",
    initial_errors: dict[str, float] | None = None,
    start_time_s: float = 0.0,
    imu_table_extra: dict[str, Any] | None = None,
) -> SimRun:
    """Truth, error-free IMU, corrupted sensors, and the settings tables for one run."""
    rng = np.random.default_rng(seed)
    nav = NavModel.at(origin)
    exact = exact_motion(profile, nav)
    t = exact.t + start_time_s
    dt = float(profile.t[1] - profile.t[0])
    gyro, accel, gyro_bias, accel_bias = apply_imu_errors(rng, exact.gyro, exact.accel, dt, errors)
    truth = Trajectory(
        t=t,
        position=exact.position,
        velocity=exact.velocity,
        rotation=exact.rotation,
        origin=origin,
        method="truth",
        gyro_bias=gyro_bias,
        accel_bias=accel_bias,
    )
    body_rate = exact.gyro - np.einsum("nji,j->ni", exact.rotation, nav.earth_rate)
    gnss, gnss_info = simulate_gnss(
        rng, GnssTruthInput(t, exact.position, exact.velocity, exact.rotation, body_rate),
        origin, gnss_model,
    )  # fmt: skip
    baro = None
    config: dict[str, dict[str, Any]] = {
        "imu": {**imu_table(imu_preset, noise, 1.0 / dt), **(imu_table_extra or {})},
        "gnss": gnss_table(gnss_model),
    }
    info: dict[str, Any] = {"gnss": gnss_info}
    if baro_model is not None:
        baro, baro_bias = simulate_baro(rng, t, exact.position[:, 2] + origin.alt, baro_model)
        config["baro"] = baro_model.config_table()
        info["baro_bias_m"] = baro_bias
    dataset = Dataset(
        imu=ImuData(t=t, gyro=gyro, accel=accel),
        gnss=gnss,
        origin=origin,
        baro=baro,
        name=name,
        imu_config=dict(config["imu"]),
        gnss_config=dict(config["gnss"]),
        vehicle=profile.vehicle,
        metadata={"simulated": True, "seed": seed, "scenario": name},
    )
    outages = [(float(a), float(b)) for a, b in gnss_model.outages if a < t[-1] - t[0]]
    return SimRun(
        dataset=dataset,
        truth=truth,
        config=config,
        description=description,
        outages=outages,
        initial_errors=dict(initial_errors or {}),
        info=info,
    )


def aircraft_ekf(seed: int = 0, **options: Any) -> SimRun:
    """Aircraft at ~100 m/s, tactical IMU with large constant biases, 60 s outage at 500 s."""
    _check_options("aircraft-ekf", options, {"duration_s", "start_time_s", "outage_start_s"})
    duration = float(options.get("duration_s", 720.0))
    outage_start = float(options.get("outage_start_s", 500.0))
    rate = 100.0
    noise = imu_noise_from_config({"preset": "tactical"})
    gyro_bias = tuple(np.array([-50.0, 50.0, -50.0]) * DEG / 3600.0)
    accel_bias = tuple(np.array([10.0, -10.0, 10.0]) * MG)
    # Constant biases: the truth has no bias random walk (the table keeps the preset's small
    # random walk as estimator tuning).
    errors = ImuErrorModel.from_noise(
        noise, gyro_bias=gyro_bias, accel_bias=accel_bias, bias_random_walk=False
    )
    gnss_model = GnssModel(
        rate_hz=1.0,
        sigma_m=(5.0, 5.0, 8.0),
        velocity_sigma_m_per_s=0.1,
        open_sky_hdop=0.9,
        outages=((outage_start, outage_start + 60.0),),
    )
    return simulate_run(
        name="aircraft-ekf",
        seed=seed,
        profile=motion.aircraft(rate, duration),
        origin=Origin(47.4581, 8.5555, 432.0),
        imu_preset="tactical",
        noise=noise,
        errors=errors,
        gnss_model=gnss_model,
        description=(
            "Aircraft: take-off roll, climb, coordinated turns and cruise at ~100 m/s. Tactical "
            "IMU at 100 Hz with constant biases accel [10,-10,10] mg, gyro [-50,50,-50] deg/h; "
            "GNSS 1 Hz, sigma (5,5,8) m, velocity 0.1 m/s; 60 s GNSS outage from 500 s."
        ),
        initial_errors={"position_m": 50.0, "velocity_m_per_s": 0.1, "attitude_deg": 1.0},
        start_time_s=float(options.get("start_time_s", 0.0)),
    )


def mems_car_pdop(seed: int = 0, **options: Any) -> SimRun:
    """Consumer MEMS car, IMU 20 Hz, GNSS 2 Hz, a 30 s stretch of PDOP > 5 with biased fixes."""
    allowed = {"duration_s", "start_time_s", "bias_start_s", "bias_offset_m"}
    _check_options("mems-car-pdop", options, allowed)
    duration = float(options.get("duration_s", 300.0))
    start = float(options.get("bias_start_s", 120.0))
    offset_values = [float(v) for v in options.get("bias_offset_m", (9.0, -7.0, 5.0))]
    if len(offset_values) != 3:
        raise InputError("mems-car-pdop: bias_offset_m needs 3 values (east, north, up) in m")
    offset = (offset_values[0], offset_values[1], offset_values[2])
    noise = imu_noise_from_config({"preset": "consumer-mems"})
    gnss_model = GnssModel(
        rate_hz=2.0,
        uere_m=3.0,
        dop_stretches=(DopStretch(start, start + 30.0, 3.3), DopStretch(40.0, 60.0, 2.0)),
        biased_stretches=(BiasedStretch(start, start + 30.0, offset),),
    )
    return simulate_run(
        name="mems-car-pdop",
        seed=seed,
        profile=motion.urban_car(20.0, duration),
        origin=Origin(48.1372, 11.5755, 520.0),
        imu_preset="consumer-mems",
        noise=noise,
        errors=ImuErrorModel.from_noise(noise),
        gnss_model=gnss_model,
        description=(
            "Urban car, consumer MEMS IMU 20 Hz, GNSS 2 Hz (UERE 3 m x DOP). From "
            f"{start:g} s for 30 s the geometry degrades to PDOP > 5 and the fixes are biased "
            f"by {offset} m (ENU): a gate on PDOP should reject them."
        ),
        start_time_s=float(options.get("start_time_s", 0.0)),
    )


def uav_loop_baro(seed: int = 0, **options: Any) -> SimRun:
    """Car on a 25 m loop at 11 km/h, consumer IMU and barometer at 20 Hz, GNSS 1 or 0.5 Hz."""
    _check_options("uav-loop-baro", options, {"duration_s", "start_time_s", "gnss_rate_hz"})
    duration = float(options.get("duration_s", 240.0))
    gnss_rate = float(options.get("gnss_rate_hz", 1.0))
    if gnss_rate not in (1.0, 0.5):
        raise InputError(f"uav-loop-baro: gnss_rate_hz must be 1 or 0.5, got {gnss_rate}")
    noise = imu_noise_from_config({"preset": "consumer-mems"})
    gnss_model = GnssModel(
        rate_hz=gnss_rate,
        uere_m=2.0,
        dop_stretches=(DopStretch(90.0, 120.0, 2.5),),
    )
    return simulate_run(
        name="uav-loop-baro",
        seed=seed,
        profile=motion.circular_loop(20.0, duration, radius_m=25.0, speed_m_per_s=11.0 / 3.6),
        origin=Origin(52.52, 13.405, 60.0),
        imu_preset="consumer-mems",
        noise=noise,
        errors=ImuErrorModel.from_noise(noise),
        gnss_model=gnss_model,
        baro_model=BaroModel(rate_hz=20.0, noise_m=0.3, bias_rw_m_per_sqrt_s=0.01),
        description=(
            "Loop of radius 25 m at 11 km/h; consumer IMU and barometer at 20 Hz, GNSS "
            f"{gnss_rate:g} Hz with UERE 2 m x DOP (HDOP ~1, 2.5 from 90 to 120 s)."
        ),
        start_time_s=float(options.get("start_time_s", 0.0)),
    )


def _grade(name: str, options: dict[str, Any]) -> str:
    grade = str(options.get("grade", "consumer-mems"))
    if grade not in GRADES:
        raise InputError(f"scenario {name}: grade must be one of {', '.join(GRADES)}")
    return grade


def car_urban(seed: int = 0, **options: Any) -> SimRun:
    """City drive with stops and junction turns; urban stretches with HDOP 3-7."""
    _check_options("car-urban", options, {"duration_s", "start_time_s", "grade"})
    grade = _grade("car-urban", options)
    duration = float(options.get("duration_s", 300.0))
    noise = imu_noise_from_config({"preset": grade})
    gnss_model = GnssModel(
        rate_hz=1.0,
        uere_m=3.0,
        lever_arm_m=(0.5, 0.0, 1.2),
        velocity_sigma_m_per_s=0.2,
        dop_stretches=(DopStretch(60.0, 95.0, 3.5), DopStretch(180.0, 200.0, 7.0)),
        outlier_fraction=0.02,
        outlier_size_m=25.0,
    )
    return simulate_run(
        name="car-urban",
        seed=seed,
        profile=motion.urban_car(100.0, duration),
        origin=Origin(48.1372, 11.5755, 520.0),
        imu_preset=grade,
        noise=noise,
        errors=ImuErrorModel.from_noise(noise),
        gnss_model=gnss_model,
        description=(
            f"Urban car, {grade} IMU 100 Hz, GNSS 1 Hz (UERE 3 m x DOP, HDOP 3.5 at 60-95 s and "
            "7 at 180-200 s), velocity 0.2 m/s, antenna lever arm (0.5, 0, 1.2) m, 2 % outliers "
            "of 25 m."
        ),
        start_time_s=float(options.get("start_time_s", 0.0)),
    )


def highway(seed: int = 0, **options: Any) -> SimRun:
    """Motorway drive at ~30 m/s with gentle curves and grades, open sky."""
    _check_options("highway", options, {"duration_s", "start_time_s", "grade"})
    grade = _grade("highway", options)
    duration = float(options.get("duration_s", 240.0))
    noise = imu_noise_from_config({"preset": grade})
    gnss_model = GnssModel(
        rate_hz=1.0,
        uere_m=2.5,
        lever_arm_m=(0.0, 0.0, 1.5),
        velocity_sigma_m_per_s=0.1,
        dop_stretches=(DopStretch(150.0, 165.0, 2.5),),
    )
    return simulate_run(
        name="highway",
        seed=seed,
        profile=motion.highway(100.0, duration),
        origin=Origin(50.11, 8.68, 110.0),
        imu_preset=grade,
        noise=noise,
        errors=ImuErrorModel.from_noise(noise),
        gnss_model=gnss_model,
        description=(
            f"Highway at 27-32 m/s, {grade} IMU 100 Hz, GNSS 1 Hz (UERE 2.5 m x DOP, an "
            "overpass stretch with HDOP 2.5 at 150-165 s), velocity 0.1 m/s."
        ),
        start_time_s=float(options.get("start_time_s", 0.0)),
    )


SCENARIOS: dict[str, Callable[..., SimRun]] = {
    "aircraft-ekf": aircraft_ekf,
    "mems-car-pdop": mems_car_pdop,
    "uav-loop-baro": uav_loop_baro,
    "car-urban": car_urban,
    "highway": highway,
}
