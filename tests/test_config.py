"""Config value checking: every key of every section, whatever the source, by type and range.

The schemas are checked against the dataclasses they describe (every field has a rule that
matches its declared type), then every key is fed values of the wrong kind and out of range;
each must be a ConfigError naming the source, the key and the value, and each default and
every simulator scenario's / KITTI's own settings must pass unchanged.
"""

from __future__ import annotations

import math
import typing
from dataclasses import fields

import pytest

from fgins import cli
from fgins.config import (
    GNSS_SCHEMA,
    IMU_PRESETS,
    IMU_SCHEMA,
    SMOOTHER_SCHEMA,
    VEHICLES,
    GnssConfig,
    SmootherConfig,
    config_for_dataset,
    imu_noise_from_config,
    load_config,
)
from fgins.datatypes import ConfigError, FginsError

SECTIONS = {"imu": IMU_SCHEMA, "gnss": GNSS_SCHEMA, "smoother": SMOOTHER_SCHEMA}


def _write(tmp_path, text: str):
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)


def test_every_field_has_a_rule_of_its_declared_type():
    kinds = {bool: "bool", int: "int", float: "number", str: "str"}
    for cls, schema in ((GnssConfig, GNSS_SCHEMA), (SmootherConfig, SMOOTHER_SCHEMA)):
        hints = typing.get_type_hints(cls)
        assert {f.name for f in fields(cls)} == set(schema), cls.__name__
        for f in fields(cls):
            hint = hints[f.name]
            args = typing.get_args(hint)
            optional = type(None) in args
            base = next((a for a in args if a is not type(None)), hint) if optional else hint
            expected = kinds.get(base) or ("vec3" if typing.get_origin(base) is tuple else "table")
            assert schema[f.name].kind == expected, f.name
            assert schema[f.name].optional == optional, f.name
    assert set(IMU_SCHEMA) >= set(next(iter(IMU_PRESETS.values())))


def test_defaults_and_presets_pass():
    GnssConfig()
    SmootherConfig()
    for preset in IMU_PRESETS:
        noise = imu_noise_from_config({"preset": preset})
        assert all(getattr(noise, f.name) > 0 for f in fields(noise))


def _bad_values(check) -> list[tuple[object, str]]:
    """Values a key of this kind must refuse, with the phrase the error must contain."""
    if check.kind == "number":
        bad = [("abc", "expected a number"), (True, "got a boolean"), ([1.0], "expected a number")]
        bad += [(math.nan, "finite"), (math.inf, "finite")]
        if check.low is not None:
            below = check.low if check.strict else check.low - 1.0
            bad.append((below, f"must be {'>' if check.strict else '>='}"))
        return bad
    if check.kind == "int":
        return [("3", "whole number"), (2.5, "whole number"), (True, "whole number")]
    if check.kind == "bool":
        return [(1, "true or false"), ("yes", "true or false")]
    if check.kind == "str":
        return [("boat", "expected one of"), (3, "expected one of")]
    if check.kind == "vec3":
        bad = [([1.0, 2.0], "3 numbers"), ([1.0, "x", 2.0], "expected numbers")]
        bad += [([1.0, math.nan, 2.0], "finite"), ([True, 1.0, 1.0], "got a boolean")]
        if check.low is not None:
            below = check.low if check.strict else check.low / 2 - 1.0
            bad.append(([below, 1.0, 1.0], f"must be {'>' if check.strict else '>='}"))
        if check.abs_max is not None:
            bad.append(([0.0, 0.0, 10 * check.abs_max], "must be within"))
        return bad
    if check.kind == "table":
        return [(3.0, "expected a table")]
    raise AssertionError(f"no rule for kind {check.kind}")


CASES = [
    (section, key, value, phrase)
    for section, schema in SECTIONS.items()
    for key, check in schema.items()
    for value, phrase in _bad_values(check)
]


@pytest.mark.parametrize(("section", "key", "value", "phrase"), CASES)
def test_a_bad_value_names_file_key_and_value(tmp_path, section, key, value, phrase):
    path = _write(tmp_path, f"[{section}]\n{key} = {_toml(value)}\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"config {path}: [{section}].{key} = "), message
    assert phrase in message, message
    assert "\n" not in message


def test_zero_bias_instability_is_a_constant_bias_not_an_error():
    noise = imu_noise_from_config(
        {
            "preset": "tactical",
            "gyro_bias_instability_deg_per_hr": 0,
            "accel_bias_instability_mg": 0,
        }
    )
    assert noise.gyro_bias_rw == 0.0 and noise.accel_bias_rw == 0.0
    tactical = imu_noise_from_config({"preset": "tactical"})
    assert noise.gyro_noise == tactical.gyro_noise and noise.accel_noise == tactical.accel_noise
    direct = imu_noise_from_config(
        {"gyro_bias_rw_rad_per_s_per_sqrt_s": 0.0, "accel_bias_rw_m_per_s2_per_sqrt_s": 0}
    )
    assert direct.gyro_bias_rw == 0.0 and direct.accel_bias_rw == 0.0


@pytest.mark.parametrize(
    "key",
    [
        "gyro_arw_deg_per_sqrt_hr",
        "accel_vrw_m_per_s_per_sqrt_hr",
        "gyro_noise_rad_per_s_per_sqrt_hz",
        "accel_noise_m_per_s2_per_sqrt_hz",
    ],
)
def test_zero_white_noise_says_what_to_do(key):
    with pytest.raises(ConfigError, match=rf"\[imu\]\.{key} = 0: must be > 0 \(zero white noise"):
        imu_noise_from_config({key: 0})


def test_datasheet_values_still_convert_in_closed_form(tmp_path):
    path = _write(
        tmp_path,
        "[imu]\ngyro_arw_deg_per_sqrt_hr = 0.6\ngyro_bias_instability_deg_per_hr = 3\n"
        "bias_correlation_time_s = 400\n[gnss]\nsigma_m = 0.5\nlever_arm_m = [1, 0, 2]\n"
        "uere_m = { dgps = 0.8 }\n[smoother]\nimu_to_vehicle_rpy_deg = [0, 1, 2]\n"
        "batch_max_iterations = 7\n",
    )
    config = load_config(path)
    noise = config.imu_noise()
    assert noise.gyro_noise == pytest.approx(0.6 * math.pi / 180 / 60)
    assert noise.gyro_bias_rw == pytest.approx(3 * math.pi / 180 / 3600 / math.sqrt(400))
    assert config.gnss.sigma_m == (0.5, 0.5, 0.5)
    assert config.gnss.lever_arm_m == (1.0, 0.0, 2.0)
    assert config.gnss.uere_m["dgps"] == 0.8 and config.gnss.uere_m["autonomous"] == 3.0
    assert config.smoother.imu_to_vehicle_rpy_deg == (0.0, 1.0, 2.0)
    assert config.smoother.batch_max_iterations == 7
    assert isinstance(config.smoother.batch_max_iterations, int)


def test_the_source_of_a_bad_value_is_named(tmp_path):
    with pytest.raises(ConfigError, match=r"^sensor settings of drive7: \[gnss\]\.sigma_m = "):
        load_config(dataset_gnss={"sigma_m": [0, 0, 0]}, dataset_name="drive7")
    with pytest.raises(ConfigError, match=r"^sensor settings of drive7: \[imu\]\.gyro_noise"):
        load_config(dataset_imu={"gyro_noise_rad_per_s_per_sqrt_hz": "x"}, dataset_name="drive7")
    with pytest.raises(ConfigError, match=r"imu preset \(--imu-preset\) = \"potato\""):
        load_config(imu_preset="potato")
    # A valid file still overrides the dataset's own values (precedence unchanged).
    path = _write(tmp_path, "[gnss]\nsigma_m = [1, 1, 2]\n")
    config = load_config(path, dataset_gnss={"sigma_m": [0.3, 0.3, 0.5], "pdop_max": None})
    assert config.gnss.sigma_m == (1.0, 1.0, 2.0) and config.gnss.pdop_max is None


def test_unknown_keys_suggest_the_nearest(tmp_path):
    with pytest.raises(ConfigError, match="did you mean gyro_arw_deg_per_sqrt_hr"):
        load_config(_write(tmp_path, "[imu]\ngyro_arw_deg_per_hr = 0.3\n"))
    with pytest.raises(ConfigError, match=r"\[imu\] = 5: expected a table"):
        load_config(_write(tmp_path, "imu = 5\n"))


def test_values_set_in_code_are_checked_too():
    with pytest.raises(ConfigError, match=r"\[gnss\]\.sigma_m = \[0, 0, 0\]: must be >= 0\.001"):
        GnssConfig(sigma_m=(0, 0, 0))
    with pytest.raises(ConfigError, match=r"vehicle = \"boat\""):
        SmootherConfig(vehicle="boat")
    assert SmootherConfig(imu_to_vehicle_rpy_deg=[1, 2, 3]).imu_to_vehicle_rpy_deg == (
        1.0,
        2.0,
        3.0,
    )


def test_vehicle_choices_agree_and_are_checked():
    from fgins.sim.scenarios import SCENARIOS

    parser = cli.build_parser()
    smooth = next(a for a in parser._subparsers._group_actions[0].choices["smooth"]._actions
                  if "--vehicle" in a.option_strings)  # fmt: skip
    assert tuple(smooth.choices) == VEHICLES
    dataset = SCENARIOS["car-urban"](seed=0, duration_s=10).dataset
    with pytest.raises(ConfigError, match=r"vehicle \(--vehicle\) = \"boat\": expected one of car"):
        config_for_dataset(dataset, vehicle="boat")
    dataset.vehicle = "boat"
    with pytest.raises(ConfigError, match="sensor settings of"):
        config_for_dataset(dataset)
    assert issubclass(ConfigError, FginsError)


def test_every_scenario_and_kitti_settings_pass():
    """The settings that ship with data (simulator config.toml tables, KITTI's metadata,
    the accelerometer-array equivalent noise) are valid under the same rules."""
    from fgins.io.kitti import read_kitti
    from fgins.sim.scenarios import SCENARIOS

    for name, scenario in SCENARIOS.items():
        dataset = scenario(seed=1, duration_s=10).dataset
        config = config_for_dataset(dataset)
        assert all(
            math.isfinite(getattr(config.imu_noise(), f.name)) for f in fields(config.imu_noise())
        ), name
    config_for_dataset(read_kitti()).imu_noise()


def test_both_gnss_kernels_are_an_error_not_a_silent_choice(tmp_path):
    """huber_k and cauchy_k together used Cauchy without a word."""
    path = _write(tmp_path, "[gnss]\nhuber_k = 1.5\ncauchy_k = 3.0\n")
    with pytest.raises(ConfigError, match="huber_k and cauchy_k both given"):
        load_config(path)


@pytest.mark.parametrize("table", ["GnssConfig", "SmootherConfig"])
def test_every_setting_is_read_somewhere(table):
    """A key the config accepts but no code reads changes nothing without a word
    (``outage_keyframe_interval_s`` was one): every field of the [gnss] and [smoother]
    tables is read outside config.py."""
    import dataclasses
    import re
    from pathlib import Path

    import fgins.config as config_module

    root = Path(config_module.__file__).parent
    sources = "\n".join(
        path.read_text()
        for path in root.rglob("*.py")
        if path.name != "config.py" and ".venv" not in path.parts and "tests" not in path.parts
    )
    unread = [
        field.name
        for field in dataclasses.fields(getattr(config_module, table))
        if not re.search(rf"\.{field.name}\b", sources)
    ]
    assert not unread, unread


def test_the_default_gnss_kernel_is_huber_at_4_sigma_and_can_be_turned_off(tmp_path):
    """Huber k = 4 unless the file or the caller says otherwise: ``huber_k = 0`` in a file
    (TOML has no null), ``--robust none`` / ``robust="none"``; a file's ``cauchy_k`` alone
    takes precedence over the default Huber."""
    from fgins.api import configure
    from fgins.io.kitti import read_kitti

    assert load_config(None).gnss.huber_k == 4.0
    assert load_config(_write(tmp_path, "[gnss]\nhuber_k = 0\n")).gnss.huber_k is None
    assert load_config(_write(tmp_path, "[gnss]\nhuber_k = 2.5\n")).gnss.huber_k == 2.5
    cauchy = load_config(_write(tmp_path, "[gnss]\ncauchy_k = 3.0\n")).gnss
    assert cauchy.cauchy_k == 3.0  # kernel_weights and the noise model take Cauchy first
    with pytest.raises(ConfigError, match="huber_k"):
        load_config(_write(tmp_path, "[gnss]\nhuber_k = -1\n"))
    dataset = read_kitti()
    assert configure(dataset).gnss.huber_k == 4.0
    off = configure(dataset, robust="none").gnss
    assert off.huber_k is None and off.cauchy_k is None
    args = cli.build_parser().parse_args(["smooth", "x.csv", "-o", "y.csv", "--robust", "none"])
    assert args.robust == "none"


@pytest.mark.parametrize(
    "key",
    ["nhc_misalignment_walk_deg_per_sqrt_s", "nhc_misalignment_vertical_walk_deg_per_sqrt_s",
     "nhc_misalignment_correlation_s"],
)  # fmt: skip
def test_a_misalignment_setting_without_its_state_is_refused(tmp_path, key):
    """Without nhc_misalignment_prior_deg there is no misalignment state: its walk or its
    correlation time alone was accepted and changed nothing (the same track to the bit)."""
    with pytest.raises(ConfigError, match=rf"\[smoother\]\.{key} = 0\.1: has no effect while"):
        load_config(_write(tmp_path, f"[smoother]\n{key} = 0.1\n"))
    config = load_config(_write(tmp_path, f"[smoother]\nnhc_misalignment_prior_deg = 0.5\n{key} = 0.1\n"))
    assert getattr(config.smoother, key) == 0.1


@pytest.mark.parametrize(
    ("file", "robust", "huber_k", "cauchy_k"),
    [("", "huber", 4.0, None), ("", "cauchy", 4.0, 3.0), ("cauchy_k = 0.5", "cauchy", 4.0, 0.5),
     ("cauchy_k = 20.0", "cauchy", None, 20.0), ("huber_k = 1.0", "huber", 1.0, None),
     ("huber_k = 1.0", "cauchy", 1.0, 3.0), ("cauchy_k = 0.5", "huber", 4.0, None),
     ("huber_k = 0", "huber", 4.0, None), ("huber_k = 1.0", "none", None, None)],
)  # fmt: skip
def test_the_robust_flag_chooses_the_kernel_and_the_file_its_width(tmp_path, file, robust, huber_k, cauchy_k):
    """``--robust cauchy`` with ``cauchy_k = 0.5`` (or 20) in the file ran at k = 3, the
    same fit to the bit, unsaid (outside tester); ``--robust huber`` likewise dropped a
    file's ``huber_k``. The flag chooses the kernel, the file's key for that kernel its
    width; without one the flag's own (Huber 4, the default kernel's: it had been 2, so
    naming the default kernel halved its width, outside tester; Cauchy 3). Where Cauchy is
    chosen the Huber width is not used (Cauchy takes precedence)."""
    from fgins.config import GnssConfig

    assert GnssConfig().huber_k == 4.0  # --robust huber is the default kernel
    from fgins.api import configure
    from fgins.io.kitti import read_kitti

    gnss = configure(read_kitti(), _write(tmp_path, f"[gnss]\n{file}\n"), robust=robust).gnss
    assert gnss.cauchy_k == cauchy_k
    if cauchy_k is None:
        assert gnss.huber_k == huber_k
