"""Run configuration and sensor presets.

Users write datasheet units with the unit in the key name (DESIGN.md); this module is the one
place that converts them to SI. Every key is optional over a preset.
"""

from __future__ import annotations

import difflib
import math
import numbers
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from fgins.datatypes import ConfigError, Dataset

STANDARD_GRAVITY = 9.80665
DEG = math.pi / 180.0

# Datasheet-unit IMU presets. Bias instability is turned into a bias random walk with a
# correlation time (first-order Gauss-Markov approximated as a random walk over the span that
# matters for outage bridging).
# gyro_scale_sigma_percent: the 1-sigma scale-factor error of such a gyro (datasheets:
# consumer MEMS +-1-3 %, industrial 0.1-0.5 %, tactical 100-500 ppm, navigation < 10 ppm):
# what the smoother's sigmas take of the scale its data leave open (fgins.graph.gyro_scale).
IMU_PRESETS: dict[str, dict[str, float]] = {
    "consumer-mems": {
        "gyro_arw_deg_per_sqrt_hr": 0.3,
        "gyro_bias_instability_deg_per_hr": 10.0,
        "gyro_turn_on_bias_deg_per_s": 0.5,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.1,
        "accel_bias_instability_mg": 0.1,
        "accel_turn_on_bias_mg": 10.0,
        "gyro_scale_sigma_percent": 2.0,
    },
    "industrial-mems": {
        "gyro_arw_deg_per_sqrt_hr": 0.15,
        "gyro_bias_instability_deg_per_hr": 2.0,
        "gyro_turn_on_bias_deg_per_s": 0.05,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.05,
        "accel_bias_instability_mg": 0.03,
        "accel_turn_on_bias_mg": 3.0,
        "gyro_scale_sigma_percent": 0.5,
    },
    "tactical": {
        "gyro_arw_deg_per_sqrt_hr": 0.05,
        "gyro_bias_instability_deg_per_hr": 0.5,
        "gyro_turn_on_bias_deg_per_s": 50.0 / 3600.0,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.03,
        "accel_bias_instability_mg": 0.01,
        "accel_turn_on_bias_mg": 10.0,
        "gyro_scale_sigma_percent": 0.05,
    },
    "navigation": {
        "gyro_arw_deg_per_sqrt_hr": 0.002,
        "gyro_bias_instability_deg_per_hr": 0.005,
        "gyro_turn_on_bias_deg_per_s": 0.01 / 3600.0,
        "accel_vrw_m_per_s_per_sqrt_hr": 0.002,
        "accel_bias_instability_mg": 0.005,
        "accel_turn_on_bias_mg": 0.025,
        "gyro_scale_sigma_percent": 0.001,
    },
}

# ---------------------------------------------------------------------------------------------
# Value checking. Every config value, whatever its source (a TOML file, a dataset's own
# settings, a CLI or API choice), goes through check_value() against one Check, so the rules
# live in the schemas below, not in per-key code. An error names the source, the key and the
# value: "config run.toml: [imu].gyro_arw_deg_per_sqrt_hr = "abc": expected a number".

VEHICLES = ("car", "aircraft", "uav", "pedestrian", "other")


@dataclass(frozen=True)
class Check:
    """What one config value must be.

    ``kind`` is "number", "int", "bool", "str", "vec3" (3 numbers; a scalar when
    ``scalar_ok``) or "table" (str -> number, keys from ``choices``). Numbers are finite;
    ``low`` bounds them from below (exclusive when ``strict``), ``abs_max`` in magnitude.
    ``hint`` is appended to a range error: what to do instead; ``high_hint``, when given,
    replaces it for a value beyond ``abs_max`` (``hint`` then speaks of the low side only).
    """

    kind: str
    low: float | None = None
    strict: bool = False
    abs_max: float | None = None
    optional: bool = False
    choices: tuple[str, ...] = ()
    scalar_ok: bool = False
    hint: str = ""
    high_hint: str = ""
    axes: str = "[x, y, z]"  # what a vec3's three numbers are, as an error names them


def _show(value: object) -> str:
    """A value as the user wrote it (TOML spelling)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_show(v)}" for k, v in value.items()) + "}"
    if isinstance(value, numbers.Real):
        number = float(value)
        if math.isnan(number):
            return "nan"
        if math.isinf(number):
            return "inf" if number > 0 else "-inf"
        return str(int(number)) if isinstance(value, numbers.Integral) else repr(number)
    return repr(value)


_TYPE_NAMES = {
    "bool": "a boolean",
    "bool_": "a boolean",
    "str": "a string",
    "list": "a list",
    "tuple": "a list",
    "dict": "a table",
    "NoneType": "nothing",
}


def _is_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _fail(where: str, name: str, value: object, problem: str) -> ConfigError:
    return ConfigError(f"{where}{name} = {_show(value)}: {problem}")


def _number(where: str, name: str, value: object, check: Check, shown: object = None) -> float:
    shown = value if shown is None else shown
    if not _is_number(value):
        article = "a number" if check.kind != "vec3" else "numbers"
        kind = _TYPE_NAMES.get(type(value).__name__, type(value).__name__)
        hint = " (write it without quotes)" if isinstance(value, str) else ""
        raise _fail(where, name, shown, f"expected {article}, got {kind}{hint}")
    number = float(value)
    if not math.isfinite(number):
        raise _fail(where, name, shown, "expected a finite number")
    if check.low is not None and (number <= check.low if check.strict else number < check.low):
        problem = f"must be {'>' if check.strict else '>='} {check.low:g}"
        raise _fail(where, name, shown, problem + (f" ({check.hint})" if check.hint else ""))
    if check.abs_max is not None and abs(number) > check.abs_max:
        problem = (
            f"must be {'>' if check.strict else '>='} {check.low:g} and <= {check.abs_max:g}"
            if check.low is not None and check.low >= 0
            else f"must be within +-{check.abs_max:g}"
        )
        hint = check.high_hint or check.hint
        raise _fail(where, name, shown, problem + (f" ({hint})" if hint else ""))
    return number


def check_value(where: str, name: str, value: object, check: Check) -> Any:
    """``value`` converted to its kind (float, int, bool, str, 3-tuple, dict), or a
    :class:`ConfigError` naming ``where`` (the source, e.g. "config run.toml: "), ``name``
    (e.g. "[imu].gyro_arw_deg_per_sqrt_hr") and the value."""
    if value is None:
        if check.optional:
            return None
        raise _fail(where, name, value, f"a value is required ({_expected(check)})")
    if check.kind == "number":
        return _number(where, name, value, check)
    if check.kind == "int":
        if not _is_number(value) or float(value) != math.floor(float(value)):
            raise _fail(where, name, value, "expected a whole number")
        return int(_number(where, name, value, check))
    if check.kind == "bool":
        if not isinstance(value, (bool, np.bool_)):
            raise _fail(where, name, value, "expected true or false")
        return bool(value)
    if check.kind == "str":
        if not isinstance(value, str) or (check.choices and value not in check.choices):
            raise _fail(where, name, value, f"expected one of {', '.join(check.choices)}")
        return value
    if check.kind == "vec3":
        given = value
        if check.scalar_ok and _is_number(value):
            value = [value] * 3
        if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != 3:
            raise _fail(where, name, value, f"expected {_expected(check)}")
        return tuple(_number(where, name, v, check, shown=given) for v in value)
    if check.kind == "table":
        if not isinstance(value, dict):
            raise _fail(where, name, value, "expected a table")
        unknown = sorted(set(value) - set(check.choices))
        if unknown:
            raise _fail(
                where, f"{name}.{unknown[0]}", value[unknown[0]],
                f"unknown key; valid keys are {', '.join(check.choices)}",
            )  # fmt: skip
        return {
            k: _number(where, f"{name}.{k}", v, replace(check, kind="number"))
            for k, v in value.items()
        }
    return value  # a kind without rules (a field type added later): passed through


def _expected(check: Check) -> str:
    if check.kind == "vec3":
        return f"3 numbers {check.axes}" + (" or one number" if check.scalar_ok else "")
    return {"number": "a number", "int": "a whole number", "bool": "true or false"}.get(
        check.kind, check.kind
    )


def check_table(
    where: str, section: str, table: object, schema: dict[str, Check]
) -> dict[str, Any]:
    """Every key of one ``[section]`` table checked against ``schema`` (unknown keys are an
    error, with the nearest valid key suggested)."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise _fail(where, f"[{section}]", table, "expected a table of key = value settings")
    checked: dict[str, Any] = {}
    for key, value in table.items():
        if key not in schema:
            close = difflib.get_close_matches(str(key), list(schema), n=1, cutoff=0.5)
            suggestion = f"; did you mean {close[0]}?" if close else ""
            raise ConfigError(
                f"{where}[{section}]: unknown key(s) {key}{suggestion} "
                f"(valid keys: {', '.join(sorted(schema))})"
            )
        checked[key] = check_value(where, f"[{section}].{key}", value, schema[key])
    return checked


def _schema_from_fields(cls: type, rules: dict[str, Check]) -> dict[str, Check]:
    """A Check per dataclass field, its kind from the declared type and its range from
    ``rules`` (a field without a rule still gets its type checked, numbers finite)."""
    schema: dict[str, Check] = {}
    for name, hint in typing.get_type_hints(cls).items():
        if name not in {f.name for f in fields(cls)}:
            continue
        args = typing.get_args(hint)
        optional = isinstance(hint, types.UnionType) and type(None) in args
        if optional:
            hint = next(a for a in args if a is not type(None))
        origin = typing.get_origin(hint)
        if hint is bool:
            kind = "bool"
        elif hint is int:
            kind = "int"
        elif hint is float:
            kind = "number"
        elif hint is str:
            kind = "str"
        elif origin is tuple and len(typing.get_args(hint)) == 3:
            kind = "vec3"
        elif origin is dict:
            kind = "table"
        else:
            kind = "any"
        rule = rules.get(name, Check(kind))
        schema[name] = replace(rule, kind=kind, optional=optional or rule.optional)
    return schema


POSITIVE = Check("number", low=0.0, strict=True)
NON_NEGATIVE = Check("number", low=0.0)
WHITE_NOISE_HINT = (
    "zero white noise makes the IMU factors singular; give the datasheet value, or a small "
    "one such as 1% of the preset's for a near-perfect sensor"
)
BIAS_HINT = "0 means a constant bias; a negative density is meaningless"
TURN_ON_HINT = (
    "it is the prior sigma of the initial bias; use a small value for a bias calibrated out"
)
# Past the upper bound the low side's hints (zero noise, negative densities) do not apply.
IMU_HIGH_HINT = "far beyond any IMU that exists: a unit mix-up or a typo?"


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
    "sample_timing",
    "noise_from_data",
    "turn_on_bias_from_data",
    "gyro_scale_sigma_percent",
}

MAX_BRIDGED_IMU_GAP_S = 60.0
GAP_HINT = (
    "no IMU factor carries attitude and velocity across a longer gap: split the log at the gap "
    "and smooth each part"
)

IMU_SAMPLE_TIMINGS = ("instant", "held", "mean")  # fgins.factors.imu_samples.SAMPLE_TIMINGS
# [imu] keys that describe the data, not the sensor's noise: kept under a user's preset.
IMU_DATA_KEYS = ("sample_timing",)


def _imu_bound(base: Check, abs_max: float, hint: str) -> Check:
    """A noise or bias value of ``base`` (positive, non-negative) up to ``abs_max``: ``hint``
    for the low side, :data:`IMU_HIGH_HINT` beyond the bound."""
    return replace(base, abs_max=abs_max, hint=hint, high_hint=IMU_HIGH_HINT)


# Upper bounds far beyond any IMU that exists (the worst MEMS: ARW ~5 deg/sqrt(h), bias
# instability ~100 deg/h, turn-on ~5 deg/s, 100 mg; the SI densities and turn-on also cover
# the rates an accelerometer array derives, whose bias ramps to 2 rad/s): a value past them
# is a unit or a typo
# (an ARW of 1e30 made every sigma meaningless with chi2/dof 0.04, and nothing said).
IMU_SCHEMA: dict[str, Check] = {
    "preset": Check("str", choices=tuple(IMU_PRESETS)),
    "gyro_arw_deg_per_sqrt_hr": _imu_bound(POSITIVE, 100.0, WHITE_NOISE_HINT),
    "accel_vrw_m_per_s_per_sqrt_hr": _imu_bound(POSITIVE, 100.0, WHITE_NOISE_HINT),
    "gyro_noise_rad_per_s_per_sqrt_hz": _imu_bound(POSITIVE, 1.0, WHITE_NOISE_HINT),
    "accel_noise_m_per_s2_per_sqrt_hz": _imu_bound(POSITIVE, 2.0, WHITE_NOISE_HINT),
    # Zero bias instability / random walk is valid: a constant bias (the smoother models it).
    "gyro_bias_instability_deg_per_hr": _imu_bound(NON_NEGATIVE, 1e4, BIAS_HINT),
    "accel_bias_instability_mg": _imu_bound(NON_NEGATIVE, 1e3, BIAS_HINT),
    "gyro_bias_rw_rad_per_s_per_sqrt_s": _imu_bound(NON_NEGATIVE, 1.0, BIAS_HINT),
    "accel_bias_rw_m_per_s2_per_sqrt_s": _imu_bound(NON_NEGATIVE, 0.5, BIAS_HINT),
    # The turn-on bias is the prior sigma of the initial bias: 0 would be a hard constraint.
    "gyro_turn_on_bias_deg_per_s": _imu_bound(POSITIVE, 1000.0, TURN_ON_HINT),
    "accel_turn_on_bias_mg": _imu_bound(POSITIVE, 1e4, TURN_ON_HINT),
    "bias_correlation_time_s": POSITIVE,
    "integration_sigma_m_per_s2_per_sqrt_hz": NON_NEGATIVE,
    "gyro_scale_sigma_percent": replace(
        POSITIVE, abs_max=10.0, high_hint="beyond any gyro's scale error (MEMS datasheets: within 3 %)"
    ),
    "rate_hz": POSITIVE,
    # What a sample stands for in time (fgins.factors.imu_samples): "instant" (a reading at
    # its time stamp, the default), "held" (the interval's increments to the next one over its
    # length, in the axes at its start) or "mean" (the plain mean of the readings over it).
    "sample_timing": Check("str", choices=IMU_SAMPLE_TIMINGS),
    # false: keep the configured white noise even where the data at rest show more
    # (fgins.noise_at_rest).
    "noise_from_data": Check("bool"),
    # false: keep the configured turn-on bias sigmas even where the solved biases lie far
    # beyond them (fgins.corrections.with_turn_on_bias_widened).
    "turn_on_bias_from_data": Check("bool"),
}
assert set(IMU_SCHEMA) == IMU_KEYS | {"preset"}


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
    gyro_scale_sigma: float = 0.02  # the gyro's scale-factor error, 1-sigma (fraction)

    def scaled(self, factor: float) -> ImuNoise:
        """White noise inflated by ``factor`` (for stretches of filled-in samples)."""
        return replace(
            self, gyro_noise=self.gyro_noise * factor, accel_noise=self.accel_noise * factor
        )

    def suspect(self, factor: float, span_s: float) -> ImuNoise:
        """White noise for a suspect stretch (a gap, linearly interpolated samples) of
        ``span_s`` seconds: ``factor`` times the sensor's, and at least what the motion the
        stretch hides can do. A filled stretch in a turn misses the turn's rate changes: up
        to ~0.1 rad/s (and ~0.5 m/s^2) over the whole stretch, i.e. densities of
        0.1 sqrt(T) rad/s/sqrt(Hz) (0.5 sqrt(T) m/s^2/sqrt(Hz)). A fixed factor alone is too
        tight for a good sensor (the KITTI drive's stretches in turns hide 9-11 deg of yaw
        where 30x its noise allows 0.65 deg)."""
        root = math.sqrt(max(span_s, 0.0))
        return replace(
            self,
            gyro_noise=max(self.gyro_noise * factor, SUSPECT_RATE_ERROR_RAD_S * root),
            accel_noise=max(self.accel_noise * factor, SUSPECT_ACCEL_ERROR_M_S2 * root),
        )


SUSPECT_RATE_ERROR_RAD_S = 0.1
SUSPECT_ACCEL_ERROR_M_S2 = 0.5


# A bias instability of zero means a constant bias. Neither estimator can take it literally:
# GTSAM's CombinedImuFactor carries the bias random walk in its noise, which a zero walk
# makes singular (NaN error, LM stalls at its start), and a filter whose bias covariance
# only shrinks locks in the linearisation errors of its first minutes. So a constant bias is
# a random walk that moves it by at most this fraction of its turn-on sigma over the whole
# run, the same for the graph and the Kalman baselines (a comparison then isolates the
# estimator; the baselines used an exact constant, the graph 0.1 %, and EKF+RTS then beat the
# batch by 24 % on the constant-bias car as soon as the filters got any floor). Measured
# (batch / EKF+RTS / EKF inside the outages):
#   consumer IMU, 1 deg/s and 40 mg biases (outside tester's drive): 0.1 %: 0.44 m (NEES
#   1.5) / 0.78 (4.3) / 25 (15);  1 %: 0.38 (0.94) / 0.52 (1.6) / 24 (11);  10 %: 0.44
#   (0.57) / 0.47 (0.62) / 10 (0.85);
#   rolling aircraft (tests/test_imu_samples.py), batch: 0.46 / 0.47 / 0.61 m;
#   constant-bias car, 5 seeds summed, batch/EKF+RTS: 1.011 / 1.014 / 1.013.
# 1 %: the batch's best or near it everywhere; the forward EKF stays optimistic on the
# consumer drive (a filter's own limit, said by nothing but its NEES).
CONSTANT_BIAS_DRIFT_FRACTION = 0.01


def constant_bias_noise(noise: ImuNoise, span_s: float) -> tuple[ImuNoise, list[str]]:
    """``noise`` with zero (or vanishing) bias random walks replaced by the constant-bias
    floor (:data:`CONSTANT_BIAS_DRIFT_FRACTION`); a real walk is kept as given, even below
    the floor. Returns the noise and one note per floored sensor, for the run summary."""
    span_s = max(float(span_s), 1.0)
    notes: list[str] = []
    changes: dict[str, float] = {}
    for name, walk, prior, unit in (
        ("gyro", noise.gyro_bias_rw, noise.gyro_bias_prior, "rad/s/sqrt(s)"),
        ("accel", noise.accel_bias_rw, noise.accel_bias_prior, "m/s^2/sqrt(s)"),
    ):
        floor = CONSTANT_BIAS_DRIFT_FRACTION * max(prior, 1e-9) / math.sqrt(span_s)
        # Only a zero (or numerically negligible) walk is a constant bias.
        if walk < 1e-5 * floor:
            changes[f"{name}_bias_rw"] = floor
            notes.append(
                f"{name} bias instability {walk:.3g} {unit}: modelled as a constant bias "
                f"(random-walk floor {floor:.3g} {unit}: it moves < "
                f"{100 * CONSTANT_BIAS_DRIFT_FRACTION:g} % of its {prior:.3g} prior sigma over "
                f"the {span_s:.0f} s run)"
            )
    return (replace(noise, **changes) if changes else noise), notes


def imu_noise_from_config(imu: dict[str, Any] | None = None, *, where: str = "") -> ImuNoise:
    """Datasheet-unit ``[imu]`` table (over its preset) -> :class:`ImuNoise` in SI.

    Every value is checked first (:data:`IMU_SCHEMA`); ``where`` names the source in errors.
    """
    imu = dict(imu or {})
    preset_name = imu.pop("preset", "consumer-mems")
    if isinstance(preset_name, str) and preset_name not in IMU_PRESETS:
        raise ConfigError(
            f"{where}[imu].preset = {_show(preset_name)}: unknown IMU preset; choose one of "
            f"{', '.join(IMU_PRESETS)}"
        )
    check_value(where, "[imu].preset", preset_name, IMU_SCHEMA["preset"])
    checked = check_table(where, "imu", imu, IMU_SCHEMA)
    values: dict[str, float] = {**IMU_PRESETS[preset_name], **checked}
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
    noise = ImuNoise(
        gyro_noise=gyro_noise,
        accel_noise=accel_noise,
        gyro_bias_rw=gyro_bias_rw,
        accel_bias_rw=accel_bias_rw,
        gyro_bias_prior=values["gyro_turn_on_bias_deg_per_s"] * DEG,
        accel_bias_prior=values["accel_turn_on_bias_mg"] * 1e-3 * STANDARD_GRAVITY,
        integration_sigma=values.get("integration_sigma_m_per_s2_per_sqrt_hz", 1e-4),
        gyro_scale_sigma=values["gyro_scale_sigma_percent"] / 100.0,
    )
    # Each input was finite and in range; a product of huge ones could still overflow.
    derived = [getattr(noise, f.name) for f in fields(noise)]
    if not all(math.isfinite(v) for v in derived):
        raise ConfigError(f"{where}[imu]: the values give a non-finite noise model: {noise}")
    return noise


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
    # Huber at 4 sigma by default: a multipath fix (tens of metres among metre-level fixes)
    # pulls no harder than a 4-sigma one, while a Gaussian fix is almost never touched (GTSAM
    # applies the kernel to the whitened 3-D residual's norm: 0.1 % of chi(3) lies beyond 4,
    # LARGE_RESIDUAL_SIGMA; at k = 3 it is 2.9 %, which cost the batch 5 % on a clean 10 Hz
    # drive). Scenario matrix, batch pooled outage RMS without a kernel -> Huber 4: urban car
    # with 2 % 25 m outliers 0.890 -> 0.869 m, 110 s urban cars 1.184 -> 1.168 and (no GNSS
    # velocity) 1.338 -> 1.236 m, mounted 1.045 -> 0.996 m; outlier-free highway and
    # aircraft unchanged (0.690, 1.091 m).
    # ``--robust none`` or ``huber_k = 0`` keeps every fix at full weight.
    huber_k: float | None = 4.0
    cauchy_k: float | None = None  # redescending: rejects gross jumps (takes precedence)
    use_velocity: bool = True
    velocity_sigma_m_per_s: float | None = None
    # Fixes that fit time stamps late or early against the IMU's, or an antenna elsewhere
    # than lever_arm_m (fgins.graph.reports.lever_arm_report): the fixes are moved, or the
    # arm they fit is taken, and the drive solved again (batch, iSAM2); false: only said.
    time_offset_from_data: bool = True
    lever_arm_from_data: bool = True
    # Fixes that scatter more than twice their sigmas about the solution (fgins.gnss_scatter):
    # the sigmas scaled by that scatter and the drive solved again (batch, iSAM2); false:
    # only said.
    sigma_from_fit: bool = True
    # Fixes a robust solution leaves beyond 4 sigma, and the solution without them (its
    # uncertainty included) too, are left out (fgins.graph.gnss_faults: a run of multipath
    # fixes that the kernel only bounds); false: kept at the kernel's weight.
    fault_exclusion: bool = True
    course_min_speed_m_per_s: float = 3.0

    def __post_init__(self) -> None:
        # Values set in code (not through from_dict) are checked too, then normalised.
        for name, value in check_fields(self, GNSS_SCHEMA, "gnss").items():
            setattr(self, name, value)
        if isinstance(self.uere_m, dict):  # the missing fix types from the defaults, as a file's
            self.uere_m = {**DEFAULT_UERE_M, **self.uere_m}
        if self.huber_k == 0.0:  # TOML has no null: 0 turns the default kernel off
            self.huber_k = None

    @classmethod
    def from_dict(cls, table: dict[str, Any] | None, *, where: str = "") -> GnssConfig:
        """A ``[gnss]`` table (every key optional) -> :class:`GnssConfig`, every value
        checked; ``where`` names the source in errors ("config run.toml: ")."""
        checked = check_table(where, "gnss", table, GNSS_SCHEMA)
        if "uere_m" in checked:
            checked["uere_m"] = {**DEFAULT_UERE_M, **checked["uere_m"]}
        return cls(**checked)


def check_fields(instance: object, schema: dict[str, Check], section: str) -> dict[str, Any]:
    """The checked, normalised value of every field of a config dataclass instance."""
    return {
        f.name: check_value("", f"[{section}].{f.name}", getattr(instance, f.name), schema[f.name])
        for f in fields(instance)  # type: ignore[arg-type]
        if f.name in schema
    }


# The non-holonomic point lies within this of the IMU (m, each axis): no vehicle is longer.
NHC_LEVER_MAX_M = 20.0


@dataclass
class SmootherConfig:
    """Keyframing and solver settings shared by batch and iSAM2."""

    # Keyframes fill GNSS gaps (outages, slow receivers) at most this far apart. (An
    # ``outage_keyframe_interval_s`` was accepted but never read: a setting that does nothing
    # is now an unknown key.)
    max_keyframe_interval_s: float = 1.0
    # GNSS faster than this (20 Hz) is decimated: shorter IMU factors carry a near-singular
    # bias random-walk block. Up to 20 Hz every fix is a keyframe, as every fix is an update
    # in the Kalman baselines: at 0.2 s (the old floor) a 10 Hz receiver lost half its fixes,
    # and batch was 1.2-1.6x EKF+RTS inside outages on an independent simulator's cars.
    min_keyframe_interval_s: float = 0.05
    # The non-holonomic constraint and the wheel speed go in at keyframes at least this far
    # apart, in the graph and in the Kalman baselines alike: their errors (side slip, mounting,
    # wheel slip) are correlated over seconds, so the same sigma at 10 Hz would claim far more
    # than they carry.
    vehicle_constraint_interval_s: float = 0.2
    suspect_noise_factor: float = 30.0
    # IMU gaps are bridged with inflated noise up to these lengths. Beyond, neither the graph
    # nor the Kalman baselines can carry attitude and velocity across (measured on simulated
    # urban drives: 25-30 s gaps left the EKF 50-360 m off at 0 % in its 3-sigma, a 10 s gap
    # without GNSS stopped the batch from converging), so the run is refused with the gap named.
    max_imu_gap_s: float = 10.0
    max_unaided_imu_gap_s: float = 5.0  # the part of a gap with no usable GNSS fix either
    initial_heading_deg: float | None = None
    # Vehicle type decides the land-vehicle constraints: "car" turns on NHC and ZUPT.
    vehicle: str = "other"
    use_nhc: bool | None = None  # None: on for cars
    use_zupt: bool | None = None  # None: on for cars
    # Side slip and mounting error are correlated over seconds (KITTI: autocorrelation 0.35
    # at 1 s, 0.2 at 3 s), so constraints 1 s apart do not average them down: 0.2 m/s, not
    # the ~0.1 m/s a single sample shows.
    nhc_sigma_lateral_m_per_s: float = 0.2
    nhc_sigma_vertical_m_per_s: float = 0.2
    # What a car's velocity at the IMU really has besides white slip, lateral and vertical
    # per unit of forward speed: a residual mounting error nobody measured, crab, slowly
    # varying slip. A white-noise NHC books such an angle, through the turns, as along-track
    # velocity (accelerometer bias): a 1.5-3 deg unknown mounting makes a 35 s urban outage
    # 1.3-4x worse than no NHC. It can be estimated as a state: prior (deg; 0, the default,
    # turns it off), lateral and vertical random walks (0: one constant angle for the drive,
    # reported in the run summary). Off by default because a free angle also absorbs heading
    # and gyro-bias error where there is none to find: on a slip-free simulated highway the
    # constant state settles at -0.35 deg and the outage RMS goes 0.905 -> 1.100 m; a drifting
    # one (0.1 deg/sqrt(s)) costs 15-35 % on slip-free simulated cars. On KITTI (30/50/60 s
    # outages every 10 s) the drifting state gives 10 of 124 windows > 10 % worse than no car
    # constraints instead of 16, the constant one 16. Use it for an IMU whose mounting is
    # known only to a few degrees (`nhc_misalignment_prior_deg = 3`).
    nhc_misalignment_prior_deg: float = 0.0
    nhc_misalignment_walk_deg_per_sqrt_s: float = 0.0
    nhc_misalignment_vertical_walk_deg_per_sqrt_s: float = 0.0
    # > 0: the misalignment is a first-order Gauss-Markov process with this correlation time
    # (s) and nhc_misalignment_prior_deg as its stationary sigma (a slowly varying crab).
    nhc_misalignment_correlation_s: float = 0.0
    # Where the constraint holds (a non-slip point: the rear axle's centre) relative to the
    # IMU, vehicle axes (forward, left, up), m: yaw rate x forward offset is lateral
    # velocity at the IMU. KITTI: 0 fits best (0.3 m either way is worse in the sweep).
    nhc_lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # A forward offset the drive's turns put significantly elsewhere (5 sigma and 0.5 m) is
    # taken from them and the drive solved again (fgins.corrections.with_nhc_lever_corrected);
    # false keeps the configured one (a warning still says it does not fit).
    nhc_lever_from_data: bool = True
    imu_to_vehicle_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # A car's mounting (given or the default) whose forward axis the drive's turns put more
    # than 0.5 deg off is refined by a batch solve with a constant misalignment state and
    # replaced where that turns it significantly (fgins.corrections.mounting_from_drive); false
    # keeps a given mounting as it is (the checks still warn, and refuse > 10 deg).
    mounting_from_data: bool = True
    zupt_sigma_m_per_s: float = 0.02
    zupt_max_speed_m_per_s: float = 1.5  # the predicted speed must agree that it is a stop
    odometer_sigma_m_per_s: float = 0.1
    odometer_scale_sigma: float = 0.05  # prior on the wheel-speed scale-factor error
    baro_sigma_m: float = 0.5
    baro_bias_walk_m_per_sqrt_s: float = 0.05
    isam2_relinearize_threshold: float = 0.1
    batch_max_iterations: int = 100
    # The batch estimates the gyro's per-axis scale errors from its solution and corrects
    # those both significant and above 0.2 % (fgins.graph.gyro_scale); false: never.
    estimate_gyro_scale: bool = True

    def __post_init__(self) -> None:
        for name, value in check_fields(self, SMOOTHER_SCHEMA, "smoother").items():
            setattr(self, name, value)

    @property
    def nhc(self) -> bool:
        return self.use_nhc if self.use_nhc is not None else self.vehicle == "car"

    @property
    def zupt(self) -> bool:
        return self.use_zupt if self.use_zupt is not None else self.vehicle == "car"


SIGMA_HINT = "a 1-sigma error; 0 would make the measurement infinitely certain"
GNSS_SIGMA_HINT = (
    "a 1-sigma error in metres (m/s); no receiver is better than a millimetre (RTK: ~1 cm), "
    "and 0 would make the measurement infinitely certain"
)
# A configured GNSS sigma below this is a unit mix-up: 1e-9 m pinned the track to every fix
# and the solve diverged with the blame on the IMU noise.
MIN_GNSS_SIGMA = 1e-3
GNSS_SCHEMA = _schema_from_fields(
    GnssConfig,
    {
        "lever_arm_m": Check("vec3", abs_max=100.0, hint="metres, antenna in the IMU frame"),
        "uere_m": Check("table", low=0.0, strict=True, choices=tuple(DEFAULT_UERE_M)),
        "sigma_m": Check("vec3", low=MIN_GNSS_SIGMA, scalar_ok=True, hint=GNSS_SIGMA_HINT),
        "default_sigma_m": Check("vec3", low=MIN_GNSS_SIGMA, scalar_ok=True, hint=GNSS_SIGMA_HINT),
        "min_sigma_m": Check("number", low=0.0, strict=True, hint=SIGMA_HINT),
        "pdop_max": Check("number", low=0.0, strict=True),
        "min_fix_quality": Check("int", low=0.0, abs_max=9.0),
        "huber_k": replace(NON_NEGATIVE, hint="0 turns the kernel off"),
        "cauchy_k": POSITIVE,
        "velocity_sigma_m_per_s": Check("number", low=MIN_GNSS_SIGMA, hint=GNSS_SIGMA_HINT),
        "course_min_speed_m_per_s": NON_NEGATIVE,
    },
)
SMOOTHER_SCHEMA = _schema_from_fields(
    SmootherConfig,
    {
        "max_keyframe_interval_s": POSITIVE,
        "min_keyframe_interval_s": NON_NEGATIVE,
        "vehicle_constraint_interval_s": NON_NEGATIVE,
        "suspect_noise_factor": Check("number", low=1.0),
        # Beyond a minute no IMU factor carries attitude and velocity across a gap (its
        # inflated noise must cover any motion): raised to 3000 s to bridge an engine-off
        # stop, the batch's checks re-solved a meaningless drive for minutes and EKF+RTS
        # wrote a track 198 m off (outside tester).
        "max_imu_gap_s": replace(POSITIVE, abs_max=MAX_BRIDGED_IMU_GAP_S, high_hint=GAP_HINT),
        "max_unaided_imu_gap_s": replace(POSITIVE, abs_max=MAX_BRIDGED_IMU_GAP_S, high_hint=GAP_HINT),
        "initial_heading_deg": Check("number", abs_max=360.0),
        "vehicle": Check("str", choices=VEHICLES),
        "nhc_sigma_lateral_m_per_s": replace(POSITIVE, hint=SIGMA_HINT),
        "nhc_sigma_vertical_m_per_s": replace(POSITIVE, hint=SIGMA_HINT),
        "nhc_misalignment_prior_deg": Check("number", low=0.0, abs_max=30.0, hint="degrees"),
        "nhc_misalignment_walk_deg_per_sqrt_s": NON_NEGATIVE,
        "nhc_misalignment_vertical_walk_deg_per_sqrt_s": NON_NEGATIVE,
        "nhc_misalignment_correlation_s": NON_NEGATIVE,
        "nhc_lever_arm_m": Check("vec3", abs_max=NHC_LEVER_MAX_M, hint="metres, vehicle axes"),
        "imu_to_vehicle_rpy_deg": Check("vec3", abs_max=360.0, hint="degrees", axes="[roll, pitch, yaw]"),
        "zupt_sigma_m_per_s": replace(POSITIVE, hint=SIGMA_HINT),
        "zupt_max_speed_m_per_s": NON_NEGATIVE,
        "odometer_sigma_m_per_s": replace(POSITIVE, hint=SIGMA_HINT),
        "odometer_scale_sigma": replace(POSITIVE, hint=SIGMA_HINT),
        "baro_sigma_m": replace(POSITIVE, hint=SIGMA_HINT),
        "baro_bias_walk_m_per_sqrt_s": POSITIVE,
        "isam2_relinearize_threshold": NON_NEGATIVE,
        "batch_max_iterations": Check("int", low=1.0),
    },
)


@dataclass
class RunConfig:
    """Everything a run is configured with: sensor settings plus smoother settings."""

    imu: dict[str, Any] = field(default_factory=dict)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    explicit_smoother_keys: frozenset[str] = frozenset()
    # [gnss] keys a configuration gave (a flag such as --robust keeps their values).
    explicit_gnss_keys: frozenset[str] = frozenset()

    def imu_noise(self) -> ImuNoise:
        return imu_noise_from_config(self.imu)

    @property
    def imu_sample_timing(self) -> str:
        """"instant", "held" or "mean" (:mod:`fgins.factors.imu_samples`)."""
        return str(self.imu.get("sample_timing", "instant"))

    def checked(self) -> RunConfig:
        """A copy with every value checked again, as a file's would be: a RunConfig is
        mutable, and one changed in code after it was made (``config.gnss.huber_k = -1``)
        reached the solver unchecked (GTSAM's own RuntimeError, or ``vehicle = "boat"``
        taken). A :class:`ConfigError` names the key."""
        if not isinstance(self.imu, dict):
            raise ConfigError(f"[imu]: must be a table (dict), not {type(self.imu).__name__}")
        if not isinstance(self.gnss, GnssConfig) or not isinstance(self.smoother, SmootherConfig):
            raise ConfigError("RunConfig.gnss / .smoother must be GnssConfig / SmootherConfig")
        imu_noise_from_config(self.imu)
        gnss = GnssConfig(**{f.name: getattr(self.gnss, f.name) for f in fields(GnssConfig)})
        smoother = _checked_smoother(
            "", {f.name: getattr(self.smoother, f.name) for f in fields(SmootherConfig)}
        )
        return replace(self, imu=dict(self.imu), gnss=gnss, smoother=smoother)


def read_config_table(path: str | Path) -> dict[str, Any]:
    """The TOML table of a config file; a file that cannot be read is a :class:`ConfigError`."""
    try:
        # utf-8-sig: a leading byte-order mark (Windows editors) is not TOML, but the CSV
        # readers accept it, so the config reader does too.
        return tomllib.loads(Path(path).read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ConfigError(f"config file {path} not found") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a folder; give a .toml file") from None
    except UnicodeDecodeError:
        raise ConfigError(f"config file {path}: not a text (TOML) file") from None
    except OSError as exc:
        raise ConfigError(f"config file {path}: cannot read it ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path}: {exc}") from None


def load_config(
    path: str | Path | None = None,
    *,
    dataset_imu: dict[str, Any] | None = None,
    dataset_gnss: dict[str, Any] | None = None,
    imu_preset: str | None = None,
    dataset_name: str = "",
    dataset_smoother: dict[str, Any] | None = None,
    dataset_imu_source: str = "",
) -> RunConfig:
    """Merge (lowest first) the dataset's own settings, a TOML file and a CLI preset.

    Every value of every source is checked (type, range, known key) before anything is
    merged, so an error names the source it came from; errors are :class:`ConfigError`.
    The dataset's ``[imu]`` values the user replaces (a preset, or the same key) are not
    used and not checked; an error about the others says how to replace them.
    ``dataset_imu_source`` says where the dataset's ``[imu]`` values came from (e.g. "the
    sensor_msgs/Imu covariances of /imu").
    """
    table: dict[str, Any] = {} if path is None else read_config_table(path)
    file_where = f"config {path}: "
    unknown = set(table) - {"imu", "gnss", "smoother"}
    if unknown:
        sim_folder = (
            "; [origin] and [scenario] are the config.toml of a folder fgins sim wrote: if it "
            "is one, give the folder as the input instead (its config is read with it)"
            if {"origin", "scenario"} & unknown
            else ""
        )
        raise ConfigError(
            f"config {path}: unknown section(s) {', '.join(sorted(unknown))} "
            f"(valid: [imu], [gnss], [smoother]){sim_folder}"
        )
    data_where = f"sensor settings of {dataset_name or 'the input'}: "
    # Each source alone: its values must be valid, whatever the others say (the dataset's
    # [imu] values where they are used: a preset or the same key of the user's replaces them).
    user_imu = check_table(file_where, "imu", table.get("imu"), IMU_SCHEMA)
    for pair in IMU_SYNONYMS:
        if pair <= set(user_imu):
            first, second = sorted(pair)
            raise ConfigError(
                f"{file_where}[imu]: {first} and {second} both given; they set the same noise "
                "in other units (one would be ignored): keep one"
            )
    if imu_preset is not None:
        check_value("", "imu preset (--imu-preset)", imu_preset, IMU_SCHEMA["preset"])
    if "preset" in user_imu or imu_preset:
        # A preset chosen by the user replaces the dataset's own numbers entirely; what the
        # data say about their own sampling is not a noise number and stays.
        imu = {
            key: value for key, value in (dataset_imu or {}).items() if key in IMU_DATA_KEYS
        }
    else:
        imu = _checked_dataset_imu(data_where, dataset_imu, user_imu, dataset_imu_source)
    imu.update(user_imu)
    if imu_preset:
        imu["preset"] = imu_preset
    imu_noise_from_config(imu, where=file_where if path is not None else data_where)
    gnss_table = {
        **check_table(data_where, "gnss", dataset_gnss, GNSS_SCHEMA),
        **check_table(file_where, "gnss", table.get("gnss"), GNSS_SCHEMA),
    }
    if "uere_m" in gnss_table:
        gnss_table["uere_m"] = {**DEFAULT_UERE_M, **gnss_table["uere_m"]}
    file_gnss = table.get("gnss") or {}
    if isinstance(file_gnss, dict) and {"huber_k", "cauchy_k"} <= set(file_gnss):
        raise ConfigError(
            f"{file_where}[gnss]: huber_k and cauchy_k both given; the GNSS kernel is one or "
            "the other (Huber bounds an outlier's pull, Cauchy rejects it): keep one"
        )
    # The data's own [smoother] settings (a sim folder's IMU mounting) under the user's.
    data_smoother = check_table(data_where, "smoother", dataset_smoother, SMOOTHER_SCHEMA)
    smoother_table = check_table(file_where, "smoother", table.get("smoother"), SMOOTHER_SCHEMA)
    return RunConfig(
        imu=imu,
        gnss=GnssConfig(**gnss_table),
        smoother=_checked_smoother(file_where, {**data_smoother, **smoother_table}),
        explicit_smoother_keys=frozenset(smoother_table),
        explicit_gnss_keys=frozenset(gnss_table),
    )


# Keys that set the same quantity in other units: a user's value of one replaces the data's
# value of the other (an MCAP's covariances give gyro_noise_..., a user writes gyro_arw_...;
# the data's used to win, silently).
IMU_SYNONYMS = (
    frozenset({"gyro_arw_deg_per_sqrt_hr", "gyro_noise_rad_per_s_per_sqrt_hz"}),
    frozenset({"accel_vrw_m_per_s_per_sqrt_hr", "accel_noise_m_per_s2_per_sqrt_hz"}),
    frozenset({"gyro_bias_instability_deg_per_hr", "gyro_bias_rw_rad_per_s_per_sqrt_s"}),
    frozenset({"accel_bias_instability_mg", "accel_bias_rw_m_per_s2_per_sqrt_s"}),
)


def _checked_dataset_imu(
    where: str, dataset_imu: dict[str, Any] | None, user_imu: dict[str, Any], source: str
) -> dict[str, Any]:
    """The dataset's own ``[imu]`` values the user does not replace, checked; an error
    names where they came from (the user never wrote them) and how to replace them."""
    replaced = set(user_imu) | {
        other for key in user_imu for group in IMU_SYNONYMS if key in group for other in group
    }
    kept = {k: v for k, v in (dataset_imu or {}).items() if k not in replaced}
    if source:
        where = f"{where}{source} give "
    try:
        return check_table(where, "imu", kept, IMU_SCHEMA)
    except ConfigError as exc:
        raise ConfigError(
            f"{exc}; replace the data's values with --imu-preset NAME "
            f"({', '.join(IMU_PRESETS)}) or --config FILE.toml with an [imu] table "
            "(preset = NAME, or this key)"
        ) from None


def _checked_smoother(where: str, table: dict[str, Any]) -> SmootherConfig:
    """SmootherConfig from checked values, plus the checks that involve two keys."""
    smoother = SmootherConfig(**table)
    if smoother.min_keyframe_interval_s > smoother.max_keyframe_interval_s:
        raise ConfigError(
            f"{where}[smoother].min_keyframe_interval_s = {_show(smoother.min_keyframe_interval_s)}"
            f": must not exceed max_keyframe_interval_s = {_show(smoother.max_keyframe_interval_s)}"
        )
    if smoother.nhc_misalignment_prior_deg == 0.0:
        # The misalignment state exists only with a prior; its walk or correlation alone was
        # taken and silently did nothing.
        for key in (
            "nhc_misalignment_walk_deg_per_sqrt_s",
            "nhc_misalignment_vertical_walk_deg_per_sqrt_s",
            "nhc_misalignment_correlation_s",
        ):
            if getattr(smoother, key) > 0.0:
                raise ConfigError(
                    f"{where}[smoother].{key} = {_show(getattr(smoother, key))}: has no effect "
                    "while nhc_misalignment_prior_deg = 0 (no misalignment state); give "
                    "nhc_misalignment_prior_deg > 0 (its sigma, degrees) as well"
                )
    return smoother


def check_vehicle(where: str, vehicle: object, name: str = "vehicle") -> str:
    """A vehicle type from the CLI, the API or a dataset, or a :class:`ConfigError`."""
    return check_value(where, name, vehicle, SMOOTHER_SCHEMA["vehicle"])


# How the line saying that the default IMU preset was guessed begins (a run whose own
# configuration has an [imu] table leaves it out of its warnings).
PRESET_GUESSED = "imu: the data say nothing about the IMU's noise"


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
        dataset_name=dataset.name,
        dataset_smoother=dataset.smoother_config,
        dataset_imu_source=str(dataset.metadata.get("imu_config_source") or ""),
    )
    if vehicle is not None:
        check_vehicle("", vehicle, name="vehicle (--vehicle)")
    if dataset.vehicle:  # "" or None: the data do not say
        check_vehicle(f"sensor settings of {dataset.name or 'the input'}: ", dataset.vehicle)
    chosen = vehicle or dataset.vehicle
    if chosen and "vehicle" not in config.explicit_smoother_keys:
        config.smoother.vehicle = chosen
    if vehicle:
        config.smoother.vehicle = vehicle
    if not config.imu:
        # Neither the data nor the user said anything about the IMU's noise: the default
        # preset is a guess, and results depend on it. Say so once, where it is chosen.
        line = (
            f"{PRESET_GUESSED} and no --imu-preset/--config "
            "[imu] was given; using the consumer-mems preset. Override with --imu-preset NAME "
            f"({', '.join(IMU_PRESETS)}) or --config FILE.toml with an [imu] table"
        )
        if line not in dataset.warnings:
            dataset.warnings.append(line)
    if (line := _guessed_gnss_sigma(config, dataset)) is not None and line not in dataset.warnings:
        dataset.warnings.append(line)
    _check_stated_rate(config, dataset)
    return config


def _guessed_gnss_sigma(config: RunConfig, dataset: Dataset) -> str | None:
    """One line when no fix carries a sigma or a DOP and none was configured: every fix's
    sigma is then ``default_sigma_m``, a guess the results depend on (an independent
    simulator's 1.5 m fixes smoothed at the default 3 m: outage NEES 0.25, nothing said)."""
    gnss = config.gnss
    if gnss.sigma_m is not None or tuple(gnss.default_sigma_m) != GnssConfig().default_sigma_m:
        return None
    fixes = dataset.gnss
    if len(fixes) == 0:
        return None

    def given(values: np.ndarray | None) -> bool:
        return values is not None and bool(np.any(np.isfinite(values) & (values > 0)))

    if any(given(values) for values in (fixes.std, fixes.hdop, fixes.vdop, fixes.pdop)):
        return None
    shown = ", ".join(f"{x:g}" for x in gnss.default_sigma_m)
    return (
        "gnss: the fixes carry no sigma (std columns, GST, a covariance) and no DOP, and none "
        f"was configured: each is taken as [{shown}] m east/north/up ([gnss] default_sigma_m; "
        "set [gnss] sigma_m to the receiver's); the summary's GNSS scatter says how well that fits"
    )


def _check_stated_rate(config: RunConfig, dataset: Dataset) -> None:
    """A stated ``[imu] rate_hz`` that the samples contradict: the noise model is in
    densities (per sqrt(Hz)) and does not use it, but a mismatch means the wrong file, the
    wrong time unit or a decimated log, which the user should hear about."""
    stated = config.imu.get("rate_hz")
    if not stated or len(dataset.imu) < 2:
        return
    actual = float(dataset.imu.rate_hz)
    if math.isfinite(actual) and abs(actual / float(stated) - 1.0) > 0.1:
        line = (
            f"imu: [imu] rate_hz = {_show(stated)} but the IMU samples come at {actual:.4g} Hz "
            "(median spacing); the data's rate is used (noise densities do not depend on it): "
            "check the file, its time unit or the setting"
        )
        if line not in dataset.warnings:
            dataset.warnings.append(line)
