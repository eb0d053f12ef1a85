"""Seed scenarios: complete simulated runs (dataset + truth + sensor settings).

Every scenario is ``fn(seed: int = 0, **options) -> SimRun`` in :data:`SCENARIOS`; all accept
``duration_s`` (to shorten them in tests) and ``start_time_s`` (time of the first sample).
The config tables are valid ``[imu]`` / ``[gnss]`` tables (fgins.config) that state the
simulated sensors exactly (``*_si`` keys), so estimators can be tuned with the truth.

``car-urban``, ``highway`` and ``aircraft-ekf`` also take the IMU options of
:data:`IMU_OPTION_HELP` (rate, body-axis convention, mounting, bias model, grade, GNSS
velocity); see :class:`ImuSetup`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fgins.config import ImuNoise, imu_noise_from_config
from fgins.datatypes import AccelArrayData, Dataset, ImuData, InputError, Origin, Trajectory
from fgins.geodesy import enu_to_lla
from fgins.sim import motion
from fgins.sim.baro import BaroModel, simulate_baro
from fgins.sim.gnss import BiasedStretch, DopStretch, GnssModel, GnssTruthInput, simulate_gnss
from fgins.sim.imu_errors import ImuErrorModel, apply_imu_errors_in_axes
from fgins.sim.strapdown import NavModel, exact_motion

DEG = np.pi / 180.0
MG = 1e-3 * 9.80665
GRADES = ("consumer-mems", "industrial-mems", "tactical", "navigation")
BODY_FRAMES = ("flu", "frd")
BIAS_MODELS = ("random_walk", "constant")

IMU_OPTION_HELP = {
    "imu_rate_hz": "IMU sample rate (default 100; the GNSS rate must divide it)",
    "duration_s": "length of the run in s (vectorised: 1 h at 200 Hz takes seconds)",
    "grade": f"IMU grade / preset: {' | '.join(GRADES)}",
    "body_frame": "IMU axes: flu (x fwd, y left, z up; default) | frd (x fwd, y right, z down)",
    "mounting_rpy_deg": "IMU orientation in the vehicle, [roll,pitch,yaw] ZYX, default [0,0,0]",
    "write_mounting": "write the IMU orientation (frd and/or mounting) to config.toml [smoother]",
    "bias_model": "random_walk (preset densities) | constant (turn-on bias, instability 0)",
    "gnss_velocity": "GNSS velocity output (default true)",
}
IMU_OPTIONS = set(IMU_OPTION_HELP) | {"start_time_s"}


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


def _rotation_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): maps vectors in the rotated (IMU) axes into the base axes."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _option_vector(name: str, value: Any) -> tuple[float, float, float]:
    """Three numbers from a list/tuple or a string such as "[20,-10,35]" (as ``--set`` gives)."""
    items = value
    if isinstance(value, str):
        items = [v for v in value.strip().strip("[]()").replace(" ", ",").split(",") if v]
    try:
        numbers = [float(v) for v in items]
    except (TypeError, ValueError):
        numbers = []
    if len(numbers) != 3 or not all(np.isfinite(numbers)):
        raise InputError(
            f"option {name}: expected three numbers such as [20,-10,35], got {value!r}"
        )
    return numbers[0], numbers[1], numbers[2]


def _option_bool(name: str, value: Any) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes", "on"):
        return True
    if text in ("false", "0", "no", "off"):
        return False
    raise InputError(f"option {name}: expected true or false, got {value!r}")


def _option_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    text = str(value).strip().lower()
    if text not in choices:
        raise InputError(f"option {name}: choose one of {', '.join(choices)}, got {value!r}")
    return text


# Shorter runs hold fewer than the two GNSS epochs any estimator needs (1 Hz GNSS).
MIN_DURATION_S = 5.0


def _option_float(name: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, bool):  # True would be 1.0: a typo for a number
        raise InputError(f"option {name}: expected a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"option {name}: expected a number, got {value!r}") from None
    if not low <= number <= high:  # NaN fails too
        raise InputError(f"option {name}: {number:g} is outside [{low:g}, {high:g}]")
    return number


def _start_time(options: dict[str, Any]) -> float:
    """The ``start_time_s`` option: the run's first time stamp (s; POSIX times fit)."""
    return _option_float("start_time_s", options.get("start_time_s", 0.0), -1e10, 1e10)


@dataclass(frozen=True)
class ImuSetup:
    """How the simulated IMU is sampled, oriented and corrupted.

    Frames: the motion profile moves the *vehicle* (x forward, y left, z up, as in
    fgins.mounting). ``body_frame`` is the IMU's base axis convention (flu, or frd: x forward,
    y right, z down) and ``mounting_rpy_deg`` its rotation from those base axes (roll, pitch,
    yaw; ZYX: Rz(yaw) Ry(pitch) Rx(roll) maps IMU-axis vectors into base axes). The IMU's
    orientation in the vehicle is F R(mounting) (F = diag(1, -1, -1) for frd), written to
    ``[smoother] imu_to_vehicle_rpy_deg`` (an FRD IMU alone: [180, 0, 0]; FLU with a
    mounting: the mounting itself). The IMU samples, the truth attitude and the GNSS lever
    arm are all expressed in the IMU's own axes; the truth attitude is the IMU body's
    attitude in ENU (not the vehicle's).
    """

    rate_hz: float = 100.0
    body_frame: str = "flu"
    mounting_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    write_mounting: bool = True
    bias_model: str = "random_walk"
    gnss_velocity: bool = True

    @classmethod
    def from_options(
        cls, options: dict[str, Any], *, rate_hz: float = 100.0, bias_model: str = "random_walk"
    ) -> ImuSetup:
        """Parse and range-check the ``IMU_OPTION_HELP`` options (one clear error each)."""
        return cls(
            rate_hz=_option_float("imu_rate_hz", options.get("imu_rate_hz", rate_hz), 1.0, 2000.0),
            body_frame=_option_choice("body_frame", options.get("body_frame", "flu"), BODY_FRAMES),
            mounting_rpy_deg=_option_vector(
                "mounting_rpy_deg", options.get("mounting_rpy_deg", (0.0, 0.0, 0.0))
            ),
            write_mounting=_option_bool("write_mounting", options.get("write_mounting", True)),
            bias_model=_option_choice(
                "bias_model", options.get("bias_model", bias_model), BIAS_MODELS
            ),
            gnss_velocity=_option_bool("gnss_velocity", options.get("gnss_velocity", True)),
        )

    def frame_matrix(self) -> np.ndarray:
        """Maps vectors in ``body_frame`` vehicle axes into FLU vehicle axes."""
        return np.eye(3) if self.body_frame == "flu" else np.diag([1.0, -1.0, -1.0])

    def vehicle_imu(self) -> np.ndarray:
        """R_vehicle_imu of the mounting angles."""
        return _rotation_zyx(*self.mounting_rpy_deg)

    def imu_axes(self) -> np.ndarray:
        """Maps IMU-axis vectors into the profile's FLU vehicle axes."""
        return self.frame_matrix() @ self.vehicle_imu()

    def lever_in_imu(self, lever_flu: tuple[float, float, float]) -> tuple[float, float, float]:
        """A lever arm given in FLU vehicle axes, expressed in the IMU's axes."""
        v = self.imu_axes().T @ np.asarray(lever_flu, dtype=float)
        v = np.where(np.abs(v) < 1e-12, 0.0, v)  # no -0.0 / 1e-17 noise in config.toml
        return float(v[0]), float(v[1]), float(v[2])

    @property
    def mounted(self) -> bool:
        return any(a != 0.0 for a in self.mounting_rpy_deg)

    def imu_to_vehicle_rpy_deg(self) -> tuple[float, float, float]:
        """The IMU's orientation in the FLU vehicle frame (fgins.mounting's convention) as
        [roll, pitch, yaw] deg: F R_vehicle_imu, so an FRD IMU alone is roll 180."""
        r = self.imu_axes()
        pitch = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
        if abs(r[2, 0]) > 1.0 - 1e-12:  # gimbal lock: put it all into yaw
            roll, yaw = 0.0, np.arctan2(-r[0, 1], r[1, 1])
        else:
            roll, yaw = np.arctan2(r[2, 1], r[2, 2]), np.arctan2(r[1, 0], r[0, 0])
        angles = np.round(np.degrees([roll, pitch, yaw]), 9) + 0.0  # no -0.0
        return float(angles[0]), float(angles[1]), float(angles[2])

    @property
    def rotated(self) -> bool:
        """The IMU's axes differ from the FLU vehicle's (a mounting must be stated)."""
        return self.body_frame != "flu" or self.mounted


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
    setup: ImuSetup | None = None,
) -> SimRun:
    """Truth, error-free IMU, corrupted sensors, and the settings tables for one run.

    With ``setup`` the IMU axes (body frame, mounting) follow it, the GNSS lever arm of
    ``gnss_model`` (given in FLU vehicle axes) is re-expressed in the IMU's axes, the GNSS
    velocity is dropped when ``setup.gnss_velocity`` is false, and a mounting is written as
    ``[smoother] imu_to_vehicle_rpy_deg`` unless ``setup.write_mounting`` is false. The
    caller builds ``errors`` / ``noise`` for the bias model (:func:`_bias_model`).
    """
    rng = np.random.default_rng(seed)
    nav = NavModel.at(origin)
    if setup is not None:
        gnss_model = replace(
            gnss_model,
            lever_arm_m=setup.lever_in_imu(gnss_model.lever_arm_m),
            velocity_sigma_m_per_s=gnss_model.velocity_sigma_m_per_s
            if setup.gnss_velocity
            else None,
        )
    exact = exact_motion(profile, nav, None if setup is None else setup.imu_axes())
    t = exact.t + start_time_s
    dt = float(profile.t[1] - profile.t[0])
    # Errors drawn in the vehicle's FLU axes and rotated into the IMU's (isotropic model): the
    # same seed is the same physical run in every body frame and mounting.
    gyro, accel, gyro_bias, accel_bias = apply_imu_errors_in_axes(
        rng, exact.gyro, exact.accel, dt, errors, None if setup is None else setup.imu_axes()
    )
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
        # fgins's own samples are held over their intervals (fgins.sim.strapdown).
        "imu": {
            **imu_table(imu_preset, noise, 1.0 / dt), **(imu_table_extra or {}),
            "sample_timing": "held",
        },
        "gnss": gnss_table(gnss_model),
    }
    info: dict[str, Any] = {"gnss": gnss_info, "turns": profile.turns()}
    if setup is not None:
        info["setup"] = setup
        if setup.rotated and setup.write_mounting:
            config["smoother"] = {"imu_to_vehicle_rpy_deg": list(setup.imu_to_vehicle_rpy_deg())}
    if baro_model is not None:
        # The height above the surface (a round Earth), not the tangent plane's up.
        height = enu_to_lla(exact.position, origin)[:, 2]
        baro, baro_bias = simulate_baro(rng, t, height, baro_model)
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


def _bias_model(
    noise: ImuNoise,
    setup: ImuSetup | None,
    *,
    gyro_bias: tuple[float, float, float] | None = None,
    accel_bias: tuple[float, float, float] | None = None,
) -> tuple[ImuNoise, ImuErrorModel, dict[str, Any]]:
    """(noise the ``[imu]`` table states, the simulated error model, extra ``[imu]`` keys).

    ``constant``: the truth bias is the turn-on bias only and the table says so exactly
    (bias random walk 0 = bias instability 0), the case a smoother must handle as a constant
    bias. ``random_walk``: the preset's random walk, stated as such.
    """
    if setup is not None and setup.bias_model == "constant":
        errors = ImuErrorModel.from_noise(
            noise, gyro_bias=gyro_bias, accel_bias=accel_bias, bias_random_walk=False
        )
        stated = replace(noise, gyro_bias_rw=0.0, accel_bias_rw=0.0)
        extra = {"gyro_bias_instability_deg_per_hr": 0.0, "accel_bias_instability_mg": 0.0}
        return stated, errors, extra
    errors = ImuErrorModel.from_noise(noise, gyro_bias=gyro_bias, accel_bias=accel_bias)
    return noise, errors, {}


def _preset_run(
    name: str,
    seed: int,
    options: dict[str, Any],
    *,
    preset: str,
    profile: motion.MotionProfile,
    origin: Origin,
    gnss_model: GnssModel,
    description: str,
    baro_model: BaroModel | None = None,
    setup: ImuSetup | None = None,
) -> SimRun:
    """A run whose IMU has the noise and errors of an ``[imu]`` preset (and ``setup``'s bias
    model), starting at the ``start_time_s`` option."""
    noise, errors, extra = _bias_model(imu_noise_from_config({"preset": preset}), setup)
    return simulate_run(
        name=name,
        seed=seed,
        profile=profile,
        origin=origin,
        imu_preset=preset,
        noise=noise,
        errors=errors,
        gnss_model=gnss_model,
        baro_model=baro_model,
        description=description,
        start_time_s=_start_time(options),
        imu_table_extra=extra,
        setup=setup,
    )


def _setup_description(setup: ImuSetup) -> str:
    """The non-default IMU options, for the scenario description."""
    parts = []
    if setup.body_frame != "flu":
        parts.append(f"IMU axes {setup.body_frame.upper()}")
    if setup.mounted:
        parts.append(f"IMU mounted at rpy {list(setup.mounting_rpy_deg)} deg")
    if setup.rotated:
        where = "in config.toml" if setup.write_mounting else "NOT written to config.toml"
        parts.append(
            f"IMU orientation in the vehicle {list(setup.imu_to_vehicle_rpy_deg())} deg ({where})"
        )
    parts.append(f"bias model {setup.bias_model}")
    if not setup.gnss_velocity:
        parts.append("no GNSS velocity")
    return "; ".join(parts) + "."


def aircraft_ekf(seed: int = 0, **options: Any) -> SimRun:
    """Aircraft at ~100 m/s, tactical IMU with large constant biases, 60 s outage at 500 s."""
    _check_options("aircraft-ekf", options, IMU_OPTIONS | {"outage_start_s"})
    duration = _option_float("duration_s", options.get("duration_s", 720.0), MIN_DURATION_S, 86400.0)
    # At or beyond the run's end: no outage (the scenario matrix flies without one).
    outage_start = _option_float("outage_start_s", options.get("outage_start_s", 500.0), 0.0, 1e9)
    grade = _grade("aircraft-ekf", options, default="tactical")
    # Default bias model: constant biases in the truth while the table keeps the preset's
    # small random walk as estimator tuning; bias_model=constant states 0 instead.
    setup = ImuSetup.from_options(options, bias_model="random_walk")
    explicit_bias_model = "bias_model" in options
    noise = imu_noise_from_config({"preset": grade})
    gyro_bias = accel_bias = None
    if grade == "tactical":
        gyro_bias = tuple(np.array([-50.0, 50.0, -50.0]) * DEG / 3600.0)
        accel_bias = tuple(np.array([10.0, -10.0, 10.0]) * MG)
    if explicit_bias_model:
        stated, errors, extra = _bias_model(
            noise, setup, gyro_bias=gyro_bias, accel_bias=accel_bias
        )
    else:
        stated, extra = noise, {}
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
    biases = (
        "constant biases accel [10,-10,10] mg, gyro [-50,50,-50] deg/h"
        if grade == "tactical"
        else "turn-on biases drawn from the preset"
    )
    return simulate_run(
        name="aircraft-ekf",
        seed=seed,
        profile=motion.aircraft(setup.rate_hz, duration),
        origin=Origin(47.4581, 8.5555, 432.0),
        imu_preset=grade,
        noise=stated,
        errors=errors,
        gnss_model=gnss_model,
        description=(
            "Aircraft: take-off roll, climb, coordinated turns and cruise at ~100 m/s. "
            f"{grade} IMU at {setup.rate_hz:g} Hz with {biases}; GNSS 1 Hz, sigma (5,5,8) m, "
            "velocity 0.1 m/s; "
            + (f"60 s GNSS outage from {outage_start:g} s. " if outage_start < duration
               else "no GNSS outage. ")
            + _setup_description(setup)
        ),
        initial_errors={"position_m": 50.0, "velocity_m_per_s": 0.1, "attitude_deg": 1.0},
        start_time_s=_start_time(options),
        imu_table_extra=extra,
        setup=setup,
    )


def mems_car_pdop(seed: int = 0, **options: Any) -> SimRun:
    """Consumer MEMS car, IMU 20 Hz, GNSS 2 Hz, a 30 s stretch of PDOP > 5 with biased fixes."""
    allowed = {"duration_s", "start_time_s", "bias_start_s", "bias_offset_m"}
    _check_options("mems-car-pdop", options, allowed)
    duration = _option_float("duration_s", options.get("duration_s", 300.0), MIN_DURATION_S, 86400.0)
    start = _option_float("bias_start_s", options.get("bias_start_s", 120.0), 0.0, 1e9)
    offset = _option_vector("bias_offset_m", options.get("bias_offset_m", (9.0, -7.0, 5.0)))
    gnss_model = GnssModel(
        rate_hz=2.0,
        uere_m=3.0,
        dop_stretches=(DopStretch(start, start + 30.0, 3.3), DopStretch(40.0, 60.0, 2.0)),
        biased_stretches=(BiasedStretch(start, start + 30.0, offset),),
    )
    return _preset_run(
        "mems-car-pdop",
        seed,
        options,
        preset="consumer-mems",
        profile=motion.urban_car(20.0, duration),
        origin=Origin(48.1372, 11.5755, 520.0),
        gnss_model=gnss_model,
        description=(
            "Urban car, consumer MEMS IMU 20 Hz, GNSS 2 Hz (UERE 3 m x DOP). "
            + (f"From {start:g} s for {min(30.0, duration - start):g} s the geometry degrades to "
               f"PDOP > 5 and the fixes are biased by {offset} m (ENU): a gate on PDOP should "
               "reject them." if start < duration else
               f"No stretch of PDOP > 5 (set for {start:g} s on, after the run).")
        ),
    )


def uav_loop_baro(seed: int = 0, **options: Any) -> SimRun:
    """Car on a 25 m loop at 11 km/h, consumer IMU and barometer at 20 Hz, GNSS 1 or 0.5 Hz."""
    _check_options("uav-loop-baro", options, {"duration_s", "start_time_s", "gnss_rate_hz"})
    duration = _option_float("duration_s", options.get("duration_s", 240.0), MIN_DURATION_S, 86400.0)
    gnss_rate = _option_float("gnss_rate_hz", options.get("gnss_rate_hz", 1.0), 0.0, 1e3)
    if gnss_rate not in (1.0, 0.5):
        raise InputError(f"uav-loop-baro: gnss_rate_hz must be 1 or 0.5, got {gnss_rate}")
    gnss_model = GnssModel(
        rate_hz=gnss_rate,
        uere_m=2.0,
        dop_stretches=(DopStretch(90.0, 120.0, 2.5),),
    )
    return _preset_run(
        "uav-loop-baro",
        seed,
        options,
        preset="consumer-mems",
        profile=motion.circular_loop(20.0, duration, radius_m=25.0, speed_m_per_s=11.0 / 3.6),
        origin=Origin(52.52, 13.405, 60.0),
        gnss_model=gnss_model,
        baro_model=BaroModel(rate_hz=20.0, noise_m=0.3, bias_rw_m_per_sqrt_s=0.01),
        description=(
            "Loop of radius 25 m at 11 km/h; consumer IMU and barometer at 20 Hz, GNSS "
            f"{gnss_rate:g} Hz with UERE 2 m x DOP (HDOP ~1"
            + (f", 2.5 from 90 to {min(120.0, duration):g} s)." if duration > 90.0 else ").")
        ),
    )


def _grade(name: str, options: dict[str, Any], default: str = "consumer-mems") -> str:
    grade = str(options.get("grade", default))
    if grade not in GRADES:
        raise InputError(
            f"scenario {name}: grade must be one of {', '.join(GRADES)}, got {grade!r}"
        )
    return grade


def _dop_text(stretches: tuple[DopStretch, ...], duration_s: float, default: str) -> str:
    """"HDOP 3.5 at 60-95 s and 7 at 180-200 s" for the stretches a run of ``duration_s``
    reaches (a shortened run's description names no stretch it does not hold), or
    ``default``."""
    held = [f"{s.hdop:g} at {s.start_s:g}-{min(s.end_s, duration_s):g} s" for s in stretches
            if s.start_s < duration_s]  # fmt: skip
    return f"HDOP {' and '.join(held)}" if held else default


def car_urban(seed: int = 0, **options: Any) -> SimRun:
    """City drive with stops and junction turns; urban stretches with HDOP 3-7."""
    _check_options("car-urban", options, IMU_OPTIONS)
    grade = _grade("car-urban", options)
    setup = ImuSetup.from_options(options)
    duration = _option_float("duration_s", options.get("duration_s", 300.0), MIN_DURATION_S, 86400.0)
    gnss_model = GnssModel(
        rate_hz=1.0,
        uere_m=3.0,
        lever_arm_m=(0.5, 0.0, 1.2),
        velocity_sigma_m_per_s=0.2,
        dop_stretches=(DopStretch(60.0, 95.0, 3.5), DopStretch(180.0, 200.0, 7.0)),
        outlier_fraction=0.02,
        outlier_size_m=25.0,
    )
    return _preset_run(
        "car-urban",
        seed,
        options,
        preset=grade,
        profile=motion.urban_car(setup.rate_hz, duration),
        origin=Origin(48.1372, 11.5755, 520.0),
        gnss_model=gnss_model,
        description=(
            f"Urban car, {grade} IMU {setup.rate_hz:g} Hz, GNSS 1 Hz (UERE 3 m x DOP, "
            f"{_dop_text(gnss_model.dop_stretches, duration, 'open sky')}), velocity 0.2 m/s, "
            "antenna lever arm (0.5, 0, 1.2) m (vehicle FLU), 2 % outliers of 25 m. "
            + _setup_description(setup)
        ),
        setup=setup,
    )


def highway(seed: int = 0, **options: Any) -> SimRun:
    """Motorway drive at ~30 m/s with gentle curves and grades, open sky."""
    _check_options("highway", options, IMU_OPTIONS)
    grade = _grade("highway", options)
    setup = ImuSetup.from_options(options)
    duration = _option_float("duration_s", options.get("duration_s", 240.0), MIN_DURATION_S, 86400.0)
    gnss_model = GnssModel(
        rate_hz=1.0,
        uere_m=2.5,
        lever_arm_m=(0.0, 0.0, 1.5),
        velocity_sigma_m_per_s=0.1,
        dop_stretches=(DopStretch(150.0, 165.0, 2.5),),
    )
    return _preset_run(
        "highway",
        seed,
        options,
        preset=grade,
        profile=motion.highway(setup.rate_hz, duration),
        origin=Origin(50.11, 8.68, 110.0),
        gnss_model=gnss_model,
        description=(
            f"Highway at 27-32 m/s, {grade} IMU {setup.rate_hz:g} Hz, GNSS 1 Hz (UERE 2.5 m x "
            f"DOP, {_dop_text(gnss_model.dop_stretches, duration, 'open sky')}), velocity 0.1 m/s. "
            + _setup_description(setup)
        ),
        setup=setup,
    )


GYROFREE_GNSS_RATES = (1.0, 0.2)
GYROFREE_MOTIONS = ("car", "aircraft")
AIRCRAFT_GYROFREE_CRUISE_M_S = 60.0


def gyrofree_cube(seed: int = 0, **options: Any) -> SimRun:
    """Car with a gyro-free IMU: six accelerometers on the faces of a cube, GNSS 1 or 0.2 Hz.

    The dataset's IMU is the *front-end output* (specific force and integrated rate solved from
    the six simulated readings), never the true gyro; ``dataset.accel_array`` holds the raw
    readings and geometry, ``dataset.imu_config`` the equivalent IMU noise. Options:
    ``grade`` (navigation | tactical | automotive, fgins.sim.accel_array.GRADES),
    ``gnss_rate_hz`` (1 or 0.2), ``half_edge_m`` (cube half-edge, default 0.1 m),
    ``rate_hz`` (array sample rate, default 100), ``accelerometers`` (6, the study's cube, or
    12: two per face, :meth:`fgins.factors.accel_array.AccelArray.cube`), ``motion`` (``car``,
    the study's urban drive, or ``aircraft``: :func:`fgins.sim.motion.aircraft`'s take-off,
    climb and coordinated turns at 60 m/s), ``duration_s``, ``start_time_s``.
    """
    from fgins.factors.accel_array import AccelArray
    from fgins.io.accel_array_csv import accel_array_table, derive_imu, rest_calibration
    from fgins.sim.accel_array import GRADES as ARRAY_GRADES
    from fgins.sim.accel_array import array_readings, draw_array_errors, resolve_grade

    allowed = {
        "duration_s", "start_time_s", "grade", "gnss_rate_hz", "half_edge_m", "rate_hz",
        "accelerometers", "motion",
    }  # fmt: skip
    _check_options("gyrofree-cube", options, allowed)
    grade_name = str(options.get("grade", "tactical"))
    if grade_name not in ARRAY_GRADES:
        raise InputError(
            f"scenario gyrofree-cube: grade must be one of {', '.join(ARRAY_GRADES)}, "
            f"got {grade_name!r}"
        )
    grade = resolve_grade(grade_name)
    gnss_rate = _option_float("gnss_rate_hz", options.get("gnss_rate_hz", 1.0), 0.0, 1e3)
    if gnss_rate not in GYROFREE_GNSS_RATES:
        raise InputError(f"scenario gyrofree-cube: gnss_rate_hz must be 1 or 0.2, got {gnss_rate}")
    duration = _option_float("duration_s", options.get("duration_s", 300.0), MIN_DURATION_S, 86400.0)
    rate_hz = _option_float("rate_hz", options.get("rate_hz", 100.0), 1.0, 2000.0)
    if rate_hz not in (50.0, 100.0, 200.0):
        raise InputError(f"scenario gyrofree-cube: rate_hz must be 50, 100 or 200, got {rate_hz}")
    start_time = _start_time(options)
    count = _option_float("accelerometers", options.get("accelerometers", 6), 6.0, 12.0)
    if count not in (6.0, 12.0):
        raise InputError(f"scenario gyrofree-cube: accelerometers must be 6 or 12, got {count:g}")
    array = AccelArray.cube(
        _option_float("half_edge_m", options.get("half_edge_m", 0.1), 0.01, 10.0),
        per_face=1 if count == 6.0 else 2,
    )

    motion_name = str(options.get("motion", "car"))
    if motion_name not in GYROFREE_MOTIONS:
        raise InputError(
            f"scenario gyrofree-cube: motion must be one of {', '.join(GYROFREE_MOTIONS)}, "
            f"got {motion_name!r}"
        )

    rng = np.random.default_rng(seed)
    origin = Origin(48.1372, 11.5755, 520.0)
    profile = (
        motion.urban_car(rate_hz, duration)
        if motion_name == "car"
        else motion.aircraft(rate_hz, duration, cruise_m_per_s=AIRCRAFT_GYROFREE_CRUISE_M_S)
    )
    nav = NavModel.at(origin)
    exact = exact_motion(profile, nav)
    t = exact.t + start_time
    errors = draw_array_errors(rng, len(array), grade)
    readings = array_readings(array, t, exact.gyro, exact.accel, rng, grade, errors=errors)
    raw = AccelArrayData(
        t=t,
        readings=readings,
        positions=array.positions,
        axes=array.axes,
        noise_density=grade.noise_density,
        bias_sigma=grade.residual_bias,
        grade=grade.name,
    )
    # The front end calibrates the alpha bias over the 10 s standstill the drive starts with.
    imu, imu_config = derive_imu(raw)
    truth = Trajectory(
        t=t,
        position=exact.position,
        velocity=exact.velocity,
        rotation=exact.rotation,
        origin=origin,
        method="truth",
        gyro_bias=imu.gyro - exact.gyro,  # the front end's rate error, for tests
        accel_bias=imu.accel - exact.accel,
    )
    gnss_model = GnssModel(rate_hz=gnss_rate, uere_m=2.0)
    body_rate = exact.gyro - np.einsum("nji,j->ni", exact.rotation, nav.earth_rate)
    gnss, gnss_info = simulate_gnss(
        rng, GnssTruthInput(t, exact.position, exact.velocity, exact.rotation, body_rate),
        origin, gnss_model,
    )  # fmt: skip
    config: dict[str, dict[str, Any]] = {
        "imu": dict(imu_config),
        "gnss": gnss_table(gnss_model),
        "accel_array": accel_array_table(raw),
    }
    name = "gyrofree-cube"
    dataset = Dataset(
        imu=imu,
        gnss=gnss,
        origin=origin,
        name=name,
        imu_config=dict(config["imu"]),
        gnss_config=dict(config["gnss"]),
        vehicle=profile.vehicle,
        metadata={"simulated": True, "seed": seed, "scenario": name},
        accel_array=raw,
    )
    return SimRun(
        dataset=dataset,
        truth=truth,
        config=config,
        description=(
            f"{'Urban car' if motion_name == 'car' else 'Aircraft'} with a gyro-free IMU: {len(array)} {grade.name}-grade accelerometers on the faces "
            f"of a cube (half-edge {array.positions.max():g} m, face-diagonal axes) at "
            f"{rate_hz:g} Hz; GNSS {gnss_rate:g} Hz, UERE 2 m x DOP, position only. The IMU is "
            "the front-end output (rate = integral of the solved angular acceleration, its bias "
            "calibrated over the initial 10 s standstill)."
        ),
        info={
            "gnss": gnss_info,
            "grade": grade.name,
            "gnss_rate_hz": gnss_rate,
            "array_errors": errors,  # drawn residual bias / scale factor per accelerometer
            "rest_calibration": rest_calibration(raw),
        },
    )


SCENARIOS: dict[str, Callable[..., SimRun]] = {
    "aircraft-ekf": aircraft_ekf,
    "mems-car-pdop": mems_car_pdop,
    "uav-loop-baro": uav_loop_baro,
    "car-urban": car_urban,
    "highway": highway,
    "gyrofree-cube": gyrofree_cube,
}

# Scenarios that take the IMU options of IMU_OPTION_HELP.
WITH_IMU_OPTIONS = ("aircraft-ekf", "car-urban", "highway")


def scenario_list() -> str:
    """The text of ``fgins sim list``: scenarios, then the ``--set`` options."""
    lines = []
    for name, function in SCENARIOS.items():
        doc = (function.__doc__ or "").strip().splitlines()
        lines.append(f"{name:18s} {doc[0] if doc else ''}")
    lines.append("")
    lines.append(f"--set KEY=VALUE options of {', '.join(WITH_IMU_OPTIONS)}:")
    for key, text in IMU_OPTION_HELP.items():
        lines.append(f"  {key:18s} {text}")
    lines.append(
        "  e.g. fgins sim car-urban -o DIR --set body_frame=frd --set mounting_rpy_deg=[20,-10,35]"
    )
    lines.append(
        "Other options: gyrofree-cube grade, gnss_rate_hz, half_edge_m, rate_hz, accelerometers, motion; uav-loop-baro "
        "gnss_rate_hz; mems-car-pdop bias_start_s, bias_offset_m; aircraft-ekf outage_start_s."
    )
    return "\n".join(lines)
