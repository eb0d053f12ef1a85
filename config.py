"""Run configuration and sensor presets.

Users write datasheet units with the unit in the key name (DESIGN.md); this module is the one
place that converts them to SI. Every key is optional over a preset.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from fgins.datatypes import Dataset, FginsError

STANDARD_GRAVITY = 9.80665
DEG = math.pi / 180.0

# Datasheet-unit IMU presets. Bias instability is turned into a bias random walk with a
# correlation time (first-order Gauss-Markov approximated as a random walk over the span that
# matters for outage bridging).
IMU_PRESETS: dict[str, dict[str, float]] = {
    "consumer-mems": {
        "gyro_arw_deg_per_sqrt_hr": 0.3,
        "gyro_bias_instability_deg_per_hr": 10.0,
        "gyro_turn_on_bias_deg_per_s": 0.5,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.1,
        "accel_bias_instability_mg": 0.1,
        "accel_turn_on_bias_mg": 10.0,
    },
    "industrial-mems": {
        "gyro_arw_deg_per_sqrt_hr": 0.15,
        "gyro_bias_instability_deg_per_hr": 2.0,
        "gyro_turn_on_bias_deg_per_s": 0.05,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.05,
        "accel_bias_instability_mg": 0.03,
        "accel_turn_on_bias_mg": 3.0,
    },
    "tactical": {
        "gyro_arw_deg_per_sqrt_hr": 0.05,
        "gyro_bias_instability_deg_per_hr": 0.5,
        "gyro_turn_on_bias_deg_per_s": 50.0 / 3600.0,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.03,
        "accel_bias_instability_mg": 0.01,
        "accel_turn_on_bias_mg": 10.0,
    },
    "navigation": {
        "gyro_arw_deg_per_sqrt_hr": 0.002,
        "gyro_bias_instability_deg_per_hr": 0.005,
        "gyro_turn_on_bias_deg_per_s": 0.01 / 3600.0,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.002,
        "accel_bias_instability_mg": 0.005,
        "accel_turn_on_bias_mg": 0.025,
    },
}

# Keys accepted in [imu] besides "preset". The *_si keys let data sources that already know
# continuous-time densities (KITTI metadata, the simulator) state them exactly.
IMU_KEYS = {
    "gyro_arw_deg_per_sqrt_hr",
    "gyro_bias_instability_deg_per_hr",
    "gyro_turn_on_bias_deg_per_s",
    "accel_vrw_m_per_s_per_sqrt_hr",
    "accel_bias_instability_mg",
    "accel_turn_on_bias_mg",
    "bias_correlation_time_s",
    "gyro_noise_rad_per_s_per_sqrt_hz",
    "accel_noise_m_per_s2_per_sqrt_hz",
    "gyro_bias_rw_rad_per_s_per_sqrt_s",
    "accel_bias_rw_m_per_s2_per_sqrt_s",
    "integration_sigma_m_per_s2_per_sqrt_hz",
    "rate_hz",
}


@dataclass(frozen=True)
class ImuNoise:
    """IMU error model in SI, continuous time.

    White noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)), bias random-walk densities
    (rad/s/sqrt(s), m/s^2/sqrt(s)) and the 1-sigma turn-on bias used as the initial bias prior.
    """

    gyro_noise: float
    accel_noise: float
    gyro_bias_rw: float
    accel_bias_rw: float
    gyro_bias_prior: float
    accel_bias_prior: float
    integration_sigma: float = 1e-4

    def scaled(self, factor: float) -> ImuNoise:
        """White noise inflated by ``factor`` (for stretches of filled-in samples)."""
        return replace(
            self, gyro_noise=self.gyro_noise * factor, accel_noise=self.accel_noise * factor
        )


def imu_noise_from_config(imu: dict[str, Any] | None = None) -> ImuNoise:
    """Datasheet-unit ``[imu]`` table (over its preset) -> :class:`ImuNoise` in SI."""
    imu = dict(imu or {})
    preset_name = str(imu.pop("preset", "consumer-mems"))
    if preset_name not in IMU_PRESETS:
        raise FginsError(
            f"unknown IMU preset {preset_name!r}; choose one of {', '.join(IMU_PRESETS)}"
        )
    unknown = set(imu) - IMU_KEYS
    if unknown:
        raise FginsError(f"[imu]: unknown key(s) {', '.join(sorted(unknown))}")
    values: dict[str, float] = {**IMU_PRESETS[preset_name], **{k: float(v) for k, v in imu.items()}}
    tau = values.get("bias_correlation_time_s", 600.0)
    gyro_noise = values.get(
        "gyro_noise_rad_per_s_per_sqrt_hz", values["gyro_arw_deg_per_sqrt_hr"] * DEG / 60.0
    )
    accel_noise = values.get(
        "accel_noise_m_per_s2_per_sqrt_hz", values["accel_vrw_m_per_s_per_sqrt_hr"] / 60.0
    )
    gyro_bias_rw = values.get(
        "gyro_bias_rw_rad_per_s_per_sqrt_s",
        values["gyro_bias_instability_deg_per_hr"] * DEG / 3600.0 / math.sqrt(tau),
    )
    accel_bias_rw = values.get(
        "accel_bias_rw_m_per_s2_per_sqrt_s",
        values["accel_bias_instability_mg"] * 1e-3 * STANDARD_GRAVITY / math.sqrt(tau),
    )
    return ImuNoise(
        gyro_noise=gyro_noise,
        accel_noise=accel_noise,
        gyro_bias_rw=gyro_bias_rw,
        accel_bias_rw=accel_bias_rw,
        gyro_bias_prior=values["gyro_turn_on_bias_deg_per_s"] * DEG,
        accel_bias_prior=values["accel_turn_on_bias_mg"] * 1e-3 * STANDARD_GRAVITY,
        integration_sigma=values.get("integration_sigma_m_per_s2_per_sqrt_hz", 1e-4),
    )


# UERE (m, 1 sigma) per NMEA fix quality: GNSS sigma = UERE x DOP.
DEFAULT_UERE_M = {
    "autonomous": 3.0,  # quality 1
    "dgps": 1.0,  # quality 2 (and 9, WAAS/SBAS)
    "rtk_fixed": 0.05,  # quality 4
    "rtk_float": 0.5,  # quality 5
}


@dataclass
class GnssConfig:
    """GNSS measurement model settings (SI).

    ``sigma_m`` forces a constant horizontal/vertical sigma; otherwise per-epoch sigmas come
    from the data (covariance/GST), else UERE x DOP, else ``default_sigma_m``.
    """

    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    uere_m: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_UERE_M))
    sigma_m: tuple[float, float, float] | None = None
    default_sigma_m: tuple[float, float, float] = (3.0, 3.0, 5.0)
    min_sigma_m: float = 0.01
    pdop_max: float | None = 5.0
    min_fix_quality: int = 1
    huber_k: float | None = None
    cauchy_k: float | None = None  # redescending: rejects gross jumps (takes precedence)
    use_velocity: bool = True
    velocity_sigma_m_per_s: float | None = None
    course_min_speed_m_per_s: float = 3.0

    @classmethod
    def from_dict(cls, table: dict[str, Any] | None) -> GnssConfig:
        table = dict(table or {})
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise FginsError(f"[gnss]: unknown key(s) {', '.join(sorted(unknown))}")
        for key in ("lever_arm_m", "sigma_m", "default_sigma_m"):
            if table.get(key) is not None:
                value = table[key]
                if isinstance(value, (int, float)):
                    value = (float(value), float(value), float(value))
                if len(value) != 3:
                    raise FginsError(f"[gnss].{key} must have 3 values (east/x, north/y, up/z)")
                table[key] = tuple(float(v) for v in value)
        if "uere_m" in table:
            table["uere_m"] = {**DEFAULT_UERE_M, **table["uere_m"]}
        return cls(**table)


@dataclass
class SmootherConfig:
    """Keyframing and solver settings shared by batch and iSAM2."""

    outage_keyframe_interval_s: float = 1.0
    max_keyframe_interval_s: float = 1.0
    # GNSS faster than this is decimated: very short IMU factors carry a near-singular bias
    # random-walk block, and high-rate GNSS errors are strongly time-correlated anyway.
    min_keyframe_interval_s: float = 0.2
    suspect_noise_factor: float = 30.0
    initial_heading_deg: float | None = None
    # Vehicle type decides the land-vehicle constraints: "car" turns on NHC and ZUPT.
    vehicle: str = "other"
    use_nhc: bool | None = None  # None: on for cars
    use_zupt: bool | None = None  # None: on for cars
    nhc_sigma_lateral_m_per_s: float = 0.1  # slip and the IMU's offset from the rear axle
    nhc_sigma_vertical_m_per_s: float = 0.2
    imu_to_vehicle_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    zupt_sigma_m_per_s: float = 0.02
    zupt_max_speed_m_per_s: float = 1.5  # the predicted speed must agree that it is a stop
    odometer_sigma_m_per_s: float = 0.1
    odometer_scale_sigma: float = 0.05  # prior on the wheel-speed scale-factor error
    baro_sigma_m: float = 0.5
    baro_bias_walk_m_per_sqrt_s: float = 0.05
    isam2_relinearize_threshold: float = 0.1
    batch_max_iterations: int = 100

    @property
    def nhc(self) -> bool:
        return self.use_nhc if self.use_nhc is not None else self.vehicle == "car"

    @property
    def zupt(self) -> bool:
        return self.use_zupt if self.use_zupt is not None else self.vehicle == "car"


@dataclass
class RunConfig:
    """Everything a run is configured with: sensor settings plus smoother settings."""

    imu: dict[str, Any] = field(default_factory=dict)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    explicit_smoother_keys: frozenset[str] = frozenset()

    def imu_noise(self) -> ImuNoise:
        return imu_noise_from_config(self.imu)


def load_config(
    path: str | Path | None = None,
    *,
    dataset_imu: dict[str, Any] | None = None,
    dataset_gnss: dict[str, Any] | None = None,
    imu_preset: str | None = None,
) -> RunConfig:
    """Merge (lowest first) the dataset's own settings, a TOML file and a CLI preset."""
    table: dict[str, Any] = {}
    if path is not None:
        try:
            table = tomllib.loads(Path(path).read_text())
        except FileNotFoundError:
            raise FginsError(f"config file {path} not found") from None
        except tomllib.TOMLDecodeError as exc:
            raise FginsError(f"config file {path}: {exc}") from None
    unknown = set(table) - {"imu", "gnss", "smoother"}
    if unknown:
        raise FginsError(f"config {path}: unknown section(s) {', '.join(sorted(unknown))}")
    imu = {**(dataset_imu or {})}
    user_imu = dict(table.get("imu", {}))
    if "preset" in user_imu or imu_preset:
        # A preset chosen by the user replaces the dataset's own numbers entirely.
        imu = {}
    imu.update(user_imu)
    if imu_preset:
        imu["preset"] = imu_preset
    imu_noise_from_config(imu)  # validate early: one clear error before any work
    gnss = GnssConfig.from_dict({**(dataset_gnss or {}), **table.get("gnss", {})})
    smoother_table = table.get("smoother", {})
    known = {f.name for f in fields(SmootherConfig)}
    if set(smoother_table) - known:
        raise FginsError(
            f"[smoother]: unknown key(s) {', '.join(sorted(set(smoother_table) - known))}"
        )
    if "imu_to_vehicle_rpy_deg" in smoother_table:
        smoother_table["imu_to_vehicle_rpy_deg"] = tuple(smoother_table["imu_to_vehicle_rpy_deg"])
    return RunConfig(
        imu=imu,
        gnss=gnss,
        smoother=SmootherConfig(**smoother_table),
        explicit_smoother_keys=frozenset(smoother_table),
    )


def config_for_dataset(
    dataset: Dataset,
    path: str | Path | None = None,
    *,
    imu_preset: str | None = None,
    vehicle: str | None = None,
) -> RunConfig:
    """The run configuration of a dataset: its own sensor settings and vehicle type, then a
    TOML file, then command-line choices."""
    config = load_config(
        path,
        dataset_imu=dataset.imu_config,
        dataset_gnss=dataset.gnss_config,
        imu_preset=imu_preset,
    )
    chosen = vehicle or dataset.vehicle
    if chosen and "vehicle" not in config.explicit_smoother_keys:
        config.smoother.vehicle = chosen
    if vehicle:
        config.smoother.vehicle = vehicle
    if not config.imu:
        # Neither the data nor the user said anything about the IMU's noise: the default
        # preset is a guess, and results depend on it. Say so once, where it is chosen.
        line = (
            "imu: the data say nothing about the IMU's noise and no --imu-preset/--config "
            "[imu] was given; using the consumer-mems preset. Override with --imu-preset NAME "
            f"({', '.join(IMU_PRESETS)}) or --config FILE.toml with an [imu] table"
        )
        if line not in dataset.warnings:
            dataset.warnings.append(line)
    return config
