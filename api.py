"""The public Python API of fgins: load a drive, smooth it, write or tabulate the result.

Everything the ``fgins`` command does goes through these functions (the CLI only parses
arguments and prints), so a program gets exactly the CLI's results and its one-line errors:

>>> import fgins
>>> dataset = fgins.load("demo:kitti")                         # doctest: +SKIP
>>> track = fgins.smooth(dataset, "batch", gnss_outage=[(60, 90)])  # doctest: +SKIP
>>> track.write("track.csv"); track.to_dataframe().head()      # doctest: +SKIP

Errors are :class:`fgins.FginsError` subclasses (:class:`~fgins.InputError`,
:class:`~fgins.ConfigError`, :class:`~fgins.OutputError`) whose message is the line the CLI
prints after ``fgins: error:``. Findings of the readers (gaps, filled stretches, corrupt
lines) arrive as :class:`FginsWarning` through Python's :mod:`warnings` and stay listed in
``Dataset.warnings``.

This module imports only the data model at import time; GTSAM, matplotlib and pandas are
imported by the functions that need them.
"""

from __future__ import annotations

import copy
import math
import numbers
import os
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fgins.datatypes import (
    ConfigError,
    Dataset,
    FginsError,
    InputError,
    OutputError,
    Trajectory,
)

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

    from fgins.config import RunConfig

__all__ = [
    "DEFAULT_BENCH_METHODS",
    "INPUT_FOLDER_FILES",
    "OUTPUT_SUFFIXES",
    "ConfigError",
    "FginsError",
    "FginsWarning",
    "InputError",
    "OutputError",
    "bench",
    "check_methods",
    "check_output",
    "configure",
    "load",
    "plot",
    "simulate",
    "smooth",
    "summary",
    "to_dataframe",
    "write",
]

#: Trajectory output formats, chosen by the file extension.
OUTPUT_SUFFIXES = (".csv", ".geojson", ".kml", ".mcap", ".tum")
#: Figure formats of :func:`plot` (and ``--plot``), chosen by the file extension.
PLOT_SUFFIXES = (".png", ".pdf", ".svg")
#: File names a folder input (``fgins sim`` output) is read from: an output never takes one of
#: these names inside an input folder (it would become an input of the next run).
INPUT_FOLDER_FILES = (
    "imu.csv", "gnss.csv", "baro.csv", "wheel.csv", "accel_array.csv", "config.toml", "truth.csv",
)  # fmt: skip
DEFAULT_BENCH_METHODS = ("batch", "isam2", "ekf", "ekf-rts")
ROBUST_KERNELS = ("huber", "cauchy", "none")
# --robust huber / cauchy without a width in the configuration (sigmas): Huber's is the
# default kernel's (it had been 2, so naming the default kernel halved its width and
# down-weighted 23 % of honest fixes: outside tester).
ROBUST_HUBER_K = 4.0  # fgins.config.GnssConfig.huber_k
ROBUST_CAUCHY_K = 3.0


class FginsWarning(UserWarning):
    """A counted, non-fatal finding about the input (gap, filled stretch, corrupt lines...)."""


Window = tuple[float, float]


# ---------------------------------------------------------------------------------------------
# Argument checks of the public functions


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _is_bool(value: Any) -> bool:
    """A bool, numpy's too (a mask's element, ``np.True_``, is one)."""
    return isinstance(value, bool) or (type(value).__name__ in ("bool_", "bool") and hasattr(value, "dtype"))


def _is_number(value: Any) -> bool:
    return _is_real(value) and math.isfinite(float(value))


def _is_path(value: Any) -> bool:
    return isinstance(value, (str, os.PathLike)) and isinstance(os.fspath(value), str)


def _is_config(value: Any) -> bool:
    from fgins.config import RunConfig

    return _is_path(value) or isinstance(value, RunConfig)


#: Argument kinds of :func:`_check_arguments`: kind -> (test, what a value must be).
_ARGUMENT_KINDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "bool": (_is_bool, "True or False"),
    "number": (_is_number, "a finite real number"),
    "real": (_is_real, "a real number"),  # finite or not: the callee says which are usable
    "seed": (
        lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 0,
        "a non-negative integer",
    ),
    "text": (lambda v: isinstance(v, str), "a string"),
    "path": (_is_path, "a path (str or os.PathLike)"),
    "config": (_is_config, "a TOML path or a fgins.config.RunConfig"),
    "dataset": (lambda v: isinstance(v, Dataset), "a Dataset (from fgins.load)"),
    "trajectory": (lambda v: isinstance(v, Trajectory), "a Trajectory (from fgins.smooth)"),
}


def _check_arguments(function: str, **arguments: tuple[Any, str]) -> None:
    """Check the arguments of the public ``function``: each ``name=(value, kind)`` with a kind
    of :data:`_ARGUMENT_KINDS`, ``"kind?"`` also allowing None. A wrong one is an
    :class:`InputError` naming it and what it must be (not a TypeError deep inside)."""
    for name, (value, kind) in arguments.items():
        optional = kind.endswith("?")
        if optional and value is None:
            continue
        test, what = _ARGUMENT_KINDS[kind.removesuffix("?")]
        if not test(value):
            shown = repr(value)
            shown = shown if len(shown) <= 60 else shown[:57] + "..."
            raise InputError(
                f"{function}(): {name} must be {what}{' or None' if optional else ''}, "
                f"not {type(value).__name__} {shown}"
            )


# ---------------------------------------------------------------------------------------------
# Configuration and input


def configure(
    dataset: Dataset,
    config: str | os.PathLike[str] | RunConfig | None = None,
    *,
    imu_preset: str | None = None,
    vehicle: str | None = None,
    robust: str | None = None,
) -> RunConfig:
    """The run configuration of ``dataset``: its own sensor settings, then a TOML file, then
    the explicit choices (the CLI's ``--config``, ``--imu-preset``, ``--vehicle``, ``--robust``).

    Parameters
    ----------
    dataset : Dataset
        What the configuration is for (its ``imu_config``/``gnss_config``/``vehicle`` are the
        lowest layer).
    config : path or RunConfig, optional
        A TOML file with ``[imu]``, ``[gnss]``, ``[smoother]`` tables (datasheet units in the
        key names, see the README), or a ready :class:`fgins.config.RunConfig` (used as is).
    imu_preset : str, optional
        ``consumer-mems``, ``industrial-mems``, ``tactical`` or ``navigation``: replaces the
        dataset's own IMU numbers.
    vehicle : str, optional
        ``car`` (turns on the land-vehicle constraints), ``aircraft``, ``uav``, ``pedestrian``,
        ``other``.
    robust : {"huber", "cauchy", "none"}, optional
        Robust GNSS kernel: Huber with k = 4 sigma, Cauchy with k = 3 sigma (or the width
        the configuration's ``huber_k`` / ``cauchy_k`` gives), or none (every fix at full
        weight). Without it, the configuration's (default Huber, k = 4 sigma).

    Returns
    -------
    RunConfig

    Raises
    ------
    ConfigError
        Unknown key, unreadable file, unknown preset or kernel (the message names it).
    """
    from fgins.config import IMU_PRESETS, RunConfig, config_for_dataset

    _check_arguments(
        "configure", dataset=(dataset, "dataset"), config=(config, "config?"),
        imu_preset=(imu_preset, "text?"), vehicle=(vehicle, "text?"), robust=(robust, "text?"),
    )  # fmt: skip
    if isinstance(config, RunConfig):
        return config
    if imu_preset is not None and imu_preset not in IMU_PRESETS:
        raise ConfigError(
            f"imu preset {imu_preset!r} unknown; choose one of {', '.join(sorted(IMU_PRESETS))}"
        )
    if robust is not None and robust not in ROBUST_KERNELS:
        raise ConfigError(
            f"robust kernel {robust!r} unknown; choose one of {', '.join(ROBUST_KERNELS)}"
        )
    try:
        run_config = config_for_dataset(dataset, config, imu_preset=imu_preset, vehicle=vehicle)
    except FginsError as exc:
        if type(exc) is FginsError:  # config.py raises the base class; say what it is about
            raise ConfigError(str(exc)) from None
        raise
    # The flag chooses the kernel; a width the configuration gives for that kernel is kept
    # (``--robust cauchy`` with ``cauchy_k = 0.5`` had run at 3, unsaid).
    gnss, given = run_config.gnss, run_config.explicit_gnss_keys
    if robust == "huber":
        keep = "huber_k" in given and gnss.huber_k is not None
        gnss.huber_k, gnss.cauchy_k = (gnss.huber_k if keep else ROBUST_HUBER_K), None
    elif robust == "cauchy":
        gnss.cauchy_k = gnss.cauchy_k if "cauchy_k" in given else ROBUST_CAUCHY_K
    elif robust == "none":
        run_config.gnss.huber_k, run_config.gnss.cauchy_k = None, None
    return run_config


def load(
    *inputs: str | os.PathLike[str],
    config: str | os.PathLike[str] | RunConfig | None = None,
    imu_preset: str | None = None,
    vehicle: str | None = None,
    robust: str | None = None,
    time_offset: float = 0.0,
    imu_topic: str | None = None,
    gnss_topic: str | None = None,
    progress: bool = False,
) -> Dataset:
    """Read a drive or flight into a :class:`~fgins.datatypes.Dataset`, checked and configured.

    Parameters
    ----------
    *inputs : str or path
        What ``fgins smooth`` accepts: ``"demo:kitti"`` (the KITTI drive in the gtsam wheel);
        an MCAP file (ROS 2, ROS 1 or Foxglove); a ROS 1 ``.bag`` or a ROS 2 bag folder; a
        u-blox UBX log; an NMEA file plus an IMU CSV; ``imu.csv`` and
        ``gnss.csv`` (plus ``baro.csv``/``wheel.csv``, any order, recognised by header); or a
        folder written by ``fgins sim``.
    config, imu_preset, vehicle, robust
        The run configuration, see :func:`configure`. It is resolved and validated here (one
        clear error before any work) and kept in ``dataset.metadata["run_config"]``, which
        :func:`smooth` uses unless given another.
    time_offset : float, default 0.0
        Seconds added to the GNSS times, whatever the format (to put the receiver's clock
        on the IMU's: -18 for GPS time against UTC).
    imu_topic, gnss_topic : str, optional
        MCAP topics to use instead of the ones chosen by message schema.
    progress : bool, default False
        Progress bar while reading large MCAP files (on stderr).

    Returns
    -------
    Dataset
        SI units, GNSS positions geodetic (deg, deg, ellipsoidal m), ENU origin set.

    Raises
    ------
    InputError
        Missing file, unrecognised input, unusable data (the message says what and where).
    ConfigError
        Invalid configuration.

    Warns
    -----
    FginsWarning
        One per reader finding (also in ``dataset.warnings``).

    Example
    -------
    >>> import fgins
    >>> kitti = fgins.load("demo:kitti")
    >>> len(kitti.imu), len(kitti.gnss)
    (46968, 470)
    """
    from fgins.io.inputs import load_dataset

    if len(inputs) == 1 and isinstance(inputs[0], (list, tuple)):
        inputs = tuple(inputs[0])  # load(["imu.csv", "gnss.csv"]) as well
    _check_arguments("load", **{f"inputs[{i}]": (item, "path") for i, item in enumerate(inputs)})
    _check_arguments(
        "load", config=(config, "config?"), imu_preset=(imu_preset, "text?"),
        vehicle=(vehicle, "text?"), robust=(robust, "text?"), time_offset=(time_offset, "real"),
        imu_topic=(imu_topic, "text?"), gnss_topic=(gnss_topic, "text?"),
        progress=(progress, "bool"),
    )  # fmt: skip
    items = [os.fspath(item) for item in inputs]
    dataset = load_dataset(
        items, time_offset_s=float(time_offset), imu_topic=imu_topic, gnss_topic=gnss_topic,
        progress=progress, vehicle=vehicle or _configured(config, "smoother", "vehicle"),
        sample_timing=_configured(config, "imu", "sample_timing"),
    )  # fmt: skip
    dataset.metadata["inputs"] = items
    dataset.metadata["run_config"] = configure(
        dataset, config, imu_preset=imu_preset, vehicle=vehicle, robust=robust
    )
    # The explicit choices, kept so that a TOML file given to smooth() later is layered under
    # them as the CLI's --config is under its flags (they were dropped: the Huber kernel came
    # back after robust="none").
    dataset.metadata["run_choices"] = {
        key: value
        for key, value in (("imu_preset", imu_preset), ("vehicle", vehicle), ("robust", robust))
        if value is not None
    }
    for message in dataset.warnings:
        warnings.warn(message, FginsWarning, stacklevel=2)
    return dataset


def _configured(
    config: str | os.PathLike[str] | RunConfig | None, table: str, key: str
) -> str | None:
    """``config``'s ``[table] key`` when it is text (the input checks need the vehicle, a
    multirotor need not yaw with its track, and the IMU's sample timing before the run
    configuration is resolved), or None. A file that cannot be read gives None here;
    :func:`configure` then reports it properly."""
    from fgins.config import RunConfig, read_config_table

    if config is None:
        return None
    if isinstance(config, RunConfig):
        resolved = {("smoother", "vehicle"): config.smoother.vehicle,
                    ("imu", "sample_timing"): config.imu_sample_timing}  # fmt: skip
        return resolved[table, key]
    try:
        read = read_config_table(config)
    except ConfigError:
        return None
    section = read.get(table)
    value = section.get(key) if isinstance(section, dict) else None  # not a table: configure says so
    return value if isinstance(value, str) else None


def _simulate(
    scenario: str,
    output_dir: str | os.PathLike[str],
    seed: int = 0,
    duration: float | None = None,
    options: dict[str, Any] | None = None,
) -> tuple[Path, Any]:
    """Simulate and write; (folder, the scenario run with its dataset and truth)."""
    _check_arguments(
        "simulate", scenario=(scenario, "text"), output_dir=(output_dir, "path"),
        seed=(seed, "seed"), duration=(duration, "number?"),
    )  # fmt: skip
    try:
        from fgins.sim.scenarios import SCENARIOS
        from fgins.sim.writer import check_out_dir, write_sim_dir
    except ImportError:
        raise FginsError("the simulator is not available in this build") from None
    check_sim_output(output_dir, check_out_dir)
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    options = dict(options or {})
    if duration is not None:
        options["duration_s"] = duration
    try:
        run = SCENARIOS[scenario](seed=seed, **options)
    except TypeError as exc:
        raise ConfigError(f"scenario {scenario}: {exc}") from None
    epochs = len(run.dataset.gnss)
    if epochs < 2:
        # A folder load() would refuse (one fix anchors neither position nor heading): said
        # now, not when it is read.
        raise ConfigError(
            f"scenario {scenario}: {epochs} GNSS epoch in {float(run.dataset.imu.t[-1] - run.dataset.imu.t[0]):.1f} s; a run "
            "needs at least 2: give a longer duration or a higher gnss_rate_hz"
        )
    folder = Path(output_dir)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder")
    try:
        write_sim_dir(run, folder)
    except OSError as exc:  # the system refused the place (it named the writer's staging folder)
        raise OutputError(
            f"{_shortened(str(folder))}: cannot write the simulation there "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
    return folder, run


def simulate(
    scenario: str,
    output_dir: str | os.PathLike[str],
    *,
    seed: int = 0,
    duration: float | None = None,
    **options: Any,
) -> Path:
    """Simulate a drive or flight with exact truth and write it as a folder :func:`load` reads.

    Parameters
    ----------
    scenario : str
        ``car-urban``, ``highway``, ``mems-car-pdop``, ``uav-loop-baro``, ``aircraft-ekf``,
        ``gyrofree-cube`` (``fgins sim list`` describes them).
    output_dir : path
        Folder for ``imu.csv``, ``gnss.csv`` (and other sensors' CSVs), ``config.toml`` and
        ``truth.csv`` (the trajectory CSV layout).
    seed : int, default 0
        Random seed of the sensor errors.
    duration : float, optional
        Shorten the scenario to this many seconds.
    **options
        Scenario options, as ``fgins sim --set KEY=VALUE`` (e.g. ``grade="tactical"``).

    Returns
    -------
    pathlib.Path
        ``output_dir``.

    Example
    -------
    >>> drive = fgins.simulate("car-urban", tmp_path / "drive", duration=60)  # doctest: +SKIP
    """
    return _simulate(scenario, output_dir, seed, duration, options)[0]


# ---------------------------------------------------------------------------------------------
# Smoothing


def _windows(gnss_outage: str | Iterable[Sequence[float]] | None) -> list[Window]:
    """Outage windows as checked (start, end) seconds after t0."""
    from fgins.outages import parse_windows

    if gnss_outage is None:
        return []
    if isinstance(gnss_outage, str):
        try:
            return parse_windows(gnss_outage)
        except FginsError as exc:  # the CLI's wording names its flag; here the argument
            raise ConfigError(str(exc).replace("--gnss-outage", "gnss_outage")) from None
    if not isinstance(gnss_outage, Iterable):
        raise ConfigError(
            "gnss_outage: must be a list of (start, end) pairs of seconds, e.g. [(60, 90)], or "
            f"a string '60:90,150:180', not {type(gnss_outage).__name__} {gnss_outage!r}"
        )
    windows = []
    for item in gnss_outage:
        pair = list(item) if isinstance(item, Iterable) and not isinstance(item, str) else []
        if len(pair) != 2 or not all(_is_real(v) for v in pair):
            raise ConfigError(
                f"gnss_outage: {item!r} is not a (start, end) pair of seconds, e.g. (60, 90)"
            )
        start, end = float(pair[0]), float(pair[1])
        if not (math.isfinite(start) and math.isfinite(end)) or end <= start:
            raise ConfigError(f"gnss_outage: window {item!r} must have finite start < end")
        windows.append((start, end))
    return windows


def smooth(
    dataset: Dataset,
    method: str = "batch",
    *,
    config: str | os.PathLike[str] | RunConfig | None = None,
    gnss_outage: str | Iterable[Sequence[float]] | None = None,
    online: bool = False,
    progress: bool = False,
) -> Trajectory:
    """Estimate the trajectory of ``dataset`` with the factor graph or a Kalman baseline.

    Parameters
    ----------
    dataset : Dataset
        From :func:`load` (or any reader / the simulator).
    method : str, default "batch"
        ``batch`` (Levenberg-Marquardt over the whole drive), ``isam2`` (incremental, final
        estimate), or a baseline: ``ekf``, ``ekf-rts``, ``ukf``, ``planar-kf``, ``ekf18``,
        ``ekf18-rts`` (for an accelerometer array ``ekf`` and ``ekf-rts`` run the last two).
    config : path or RunConfig, optional
        Overrides the configuration chosen by :func:`load` (see :func:`configure`): a TOML
        file replaces load's file, with load's explicit ``imu_preset``, ``vehicle`` and
        ``robust`` still applied over it (as the CLI's flags are over ``--config``); a
        RunConfig is used as it is (checked again).
    gnss_outage : list of (start, end), optional
        Seconds after t0, the first GNSS epoch of the input. GNSS epochs with
        ``start <= t - t0 < end`` are withheld (the IMU is untouched). A string
        ``"60:90,150:180"`` is accepted too.
    online : bool, default False
        With ``method="isam2"``: return the online (filtered) estimate, what a real-time
        system would have had at each instant.
    progress : bool, default False
        Progress bars on stderr.

    Returns
    -------
    Trajectory
        One state per IMU sample: time (s), ENU position (m) at ``dataset.origin``, ENU
        velocity (m/s), body-to-ENU rotation, IMU biases (rad/s, m/s^2), covariances (SI).
        ``summary()`` gives the run summary, ``write(path)`` and ``to_dataframe()`` the outputs.

    Raises
    ------
    FginsError
        Unknown method, bad window, unusable data, a solve that did not converge.

    Example
    -------
    >>> import fgins
    >>> kitti = fgins.load("demo:kitti")
    >>> track = fgins.smooth(kitti, "ekf", gnss_outage=[(60, 90)])
    >>> track.summary()["gnss_withheld"]
    30
    >>> track.to_dataframe()[["east", "north", "up"]].shape
    (46968, 3)
    """
    from fgins.config import PRESET_GUESSED, RunConfig
    from fgins.outages import empty_windows, outage_mask, overlapping_windows
    from fgins.pipeline import METHODS, run_method

    _check_arguments(
        "smooth", dataset=(dataset, "dataset"), method=(method, "text"),
        config=(config, "config?"), online=(online, "bool"), progress=(progress, "bool"),
    )  # fmt: skip
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if online and method != "isam2":
        raise ConfigError(f"online=True (--online) needs method isam2, not {method!r}")
    windows = _windows(gnss_outage)
    # configure() notes what it guessed in the dataset's warnings: on a copy of the list (the
    # caller's dataset is not changed), and said here (a Dataset made in code never heard
    # "using the consumer-mems preset": outside tester).
    dataset = copy.copy(dataset)
    dataset.warnings = list(dataset.warnings)
    told = len(dataset.warnings)
    if config is None:
        run_config = dataset.metadata.get("run_config") or configure(dataset)
    elif isinstance(config, RunConfig):
        run_config = config  # used as is
    else:
        choices = dataset.metadata.get("run_choices") or {}
        run_config = configure(dataset, config, **choices)  # type: ignore[arg-type]
    for message in dataset.warnings[told:]:
        warnings.warn(message, FginsWarning, stacklevel=2)
    # A RunConfig is mutable: one changed in code since it was made is checked again here.
    run_config = run_config.checked()
    dataset = _checked_input(dataset, run_config.smoother.vehicle, run_config.imu_sample_timing)
    run_method_name = "isam2-online" if online else method
    mask = outage_mask(dataset, windows)
    started = time.perf_counter()
    trajectory = run_method(dataset, run_config, run_method_name, gnss_mask=mask, progress=progress)
    elapsed = time.perf_counter() - started
    trajectory.info["run"] = {
        "dataset": dataset.name,
        "inputs": list(dataset.metadata.get("inputs", [])),
        "method": run_method_name,
        "gnss_outage": windows,
        "imu_samples": len(dataset.imu),
        "gnss_epochs": len(dataset.gnss),
        "gnss_withheld": int((~mask).sum()),
        "wall_s": elapsed,
        # load()'s guess of the IMU preset is not this run's where its configuration has an
        # [imu] table (smooth(config=FILE) after a load without one: outside tester).
        "warnings": [w for w in dataset.warnings if not (run_config.imu and w.startswith(PRESET_GUESSED))],
    }
    # The raw fixes, for outputs that carry them beside the trajectory (MCAP).
    trajectory.info["source_gnss"] = dataset.gnss
    # A window that withholds nothing makes the run no outage test: said with the rest.
    unused = empty_windows(dataset, windows) + overlapping_windows(windows)
    if unused:
        trajectory.info["fit_warnings"] = unused + list(trajectory.info.get("fit_warnings", []))
    # What the solver found doubtful (an inconsistent fit, a mounting the vehicle constraints
    # contradict, unknown covariances) is said, never only stored.
    for message in trajectory.info.get("fit_warnings", []):
        warnings.warn(message, FginsWarning, stacklevel=2)
    return trajectory


def _checked_input(dataset: Dataset, vehicle: str, sample_timing: str) -> Dataset:
    """``dataset`` through the input checks every reader's goes through (fgins.io.validate),
    unless it already was: a Dataset made in code from arrays had skipped them, and an
    accelerometer in g was smoothed 45 m off without a word. Their findings are warned."""
    if dataset.metadata.get("input_checks") is not None:
        return dataset
    from fgins.io.validate import validate_dataset

    checked = validate_dataset(dataset, vehicle=vehicle, sample_timing=sample_timing)
    for message in checked.warnings[len(dataset.warnings) :]:
        warnings.warn(message, FginsWarning, stacklevel=3)
    return checked


# ---------------------------------------------------------------------------------------------
# Outputs


def _resolved(path: str | os.PathLike[str]) -> Path:
    return Path(path).expanduser().resolve()


def _input_paths(inputs: Iterable[str | os.PathLike[str]]) -> list[Path]:
    paths = []
    for item in inputs:
        text = os.fspath(item)
        if text.startswith("demo:"):
            continue
        paths.append(_resolved(text))
    return paths


#: Longest file or folder name, in bytes (NAME_MAX of Linux, macOS and Windows file systems).
NAME_MAX_BYTES = 255
#: What :func:`fgins.io.atomic.atomic_path` adds to an output's name for its temporary file
#: beside it (``.NAME.XXXXXXXX.part``): the name itself must leave room for that.
_TEMPORARY_NAME_EXTRA = 15


def _shortened(path: str | os.PathLike[str]) -> str:
    text = os.fspath(path)
    return text if len(text) <= 100 else f"{text[:50]}...{text[-30:]}"


def _check_name_lengths(path: str | os.PathLike[str], target: Path) -> None:
    """Refuse a name the file system cannot hold (ENAMETOOLONG), with the limit said."""
    parts = target.parts
    for index, part in enumerate(parts):
        last = index == len(parts) - 1
        limit = NAME_MAX_BYTES - (_TEMPORARY_NAME_EXTRA if last else 0)
        size = len(os.fsencode(part))
        if size > limit:
            kind = "file name" if last else f"folder name {_shortened(part)!r}"
            raise OutputError(
                f"{_shortened(path)}: {kind} too long ({size} bytes; at most {limit} bytes"
                + (f", {NAME_MAX_BYTES} less the temporary name written first" if last else "")
                + ")"
            )


def check_sim_output(output_dir: str | os.PathLike[str], check_out_dir) -> None:
    """``fgins sim``'s folder, before anything is simulated: ``check_out_dir`` (the sim
    writer's rules: new, empty or its own), and a new one must be creatable, not under a
    file: the output check's one line (as ``fgins smooth -o``), not the system's "File
    exists" / "Not a directory"."""
    folder = Path(output_dir).expanduser()
    _check_name_lengths(output_dir, folder)  # before the system's "File name too long"
    try:
        check_out_dir(folder)
    except OSError as exc:
        raise OutputError(
            f"{_shortened(str(folder))}: cannot write the simulation there "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
    if not folder.is_dir():  # the place of its config.toml: a writable folder, not a file
        check_output(folder / "config.toml", suffixes=(".toml",))


def check_output(
    path: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str]] = (),
    *,
    suffixes: Sequence[str] = OUTPUT_SUFFIXES,
    what: str = "output",
) -> Path:
    """Check that ``path`` can be written, before any work is done.

    The format must be known (from the extension); the nearest existing ancestor must be a
    writable folder (missing folders are created on writing), not a file; ``path`` must not be
    a folder, nor any of ``inputs`` (symlinks and hard links resolved), nor one of the file
    names of an input folder (:data:`INPUT_FOLDER_FILES`), which would turn it into input;
    no name in it may be longer than the file system allows.

    ``inputs`` may be one path or several; ``suffixes`` one extension or several. Returns the
    path with a leading ``~`` expanded: the place checked, to write to (the checks expanded it
    and the writers did not: ``~/x.csv`` was checked at $HOME and written to ``./~/``). Raises
    :class:`OutputError` with a one-line message.
    """
    _check_arguments("check_output", path=(path, "path"), what=(what, "text"))
    if "\x00" in os.fspath(path):
        raise OutputError(f"{_shortened(repr(os.fspath(path)))}: a path cannot hold a NUL character")
    inputs = _as_paths(inputs)
    suffixes = (suffixes,) if isinstance(suffixes, str) else tuple(suffixes)
    target = Path(path).expanduser()
    suffix = target.suffix.lower()
    if suffix not in suffixes:
        raise OutputError(
            f"{_shortened(path)}: {what} format must be one of {', '.join(suffixes)} "
            "(from the extension)"
        )
    _check_name_lengths(path, target)
    try:
        _check_output_place(path, target, suffix, inputs)
    except OSError as exc:  # a path the system refuses to look at (too long, no permission...)
        raise OutputError(
            f"{_shortened(path)}: cannot write there ({exc.strerror or type(exc).__name__})"
        ) from None
    return target


def _as_paths(inputs: object) -> list[str | os.PathLike[str]]:
    """``check_output``'s inputs as a list: one path given alone (a str was iterated by
    character, so the input itself passed the check), or none."""
    if inputs is None:
        return []
    if isinstance(inputs, (str, os.PathLike)):
        return [inputs]
    return list(inputs)  # type: ignore[call-overload]


def _check_output_place(
    path: str | os.PathLike[str],
    target: Path,
    suffix: str,
    inputs: Iterable[str | os.PathLike[str]],
) -> None:
    """The file-system half of :func:`check_output` (may raise OSError)."""
    if target.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name ending in {suffix}")
    ancestor = target.parent if str(target.parent) else Path(".")
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"{path}: cannot write under {ancestor}: it is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: folder {ancestor} is not writable")
    resolved = _resolved(target)
    for source in _input_paths(inputs):
        same = resolved == source or (
            target.exists() and source.exists() and os.path.samefile(target, source)
        )
        if same:
            raise OutputError(f"{path}: is an input of this run; refusing to overwrite it")
        bag = source if source.is_dir() else source.parent  # a bag folder, or its .db3/.mcap
        if (bag / "metadata.yaml").is_file() and bag in (_resolved(target.parent), resolved.parent):
            raise OutputError(
                f"{path}: inside the input ROS 2 bag folder {bag}; writing there would "
                "change the recording: write the output elsewhere"
            )
        if not source.is_dir():
            continue
        # The name in the folder, or, through a symlink, the name it points to there.
        for place in (_resolved(target.parent) / target.name, resolved):
            if place.parent == source and place.name.lower() in INPUT_FOLDER_FILES:
                linked = place == resolved and target.is_symlink()
                via = f" (a link to {resolved})" if linked else ""
                raise OutputError(
                    f"{path}{via}: {place.name} is a file name the input folder {source} is "
                    "read from; write the output elsewhere or under another name"
                )


def write(
    trajectory: Trajectory,
    path: str | os.PathLike[str],
    *,
    with_input: bool = False,
) -> Path:
    """Write ``trajectory`` to ``path``; the format follows the extension.

    ``.csv``: the trajectory CSV (``time,lat,lon,alt,east,north,up,vel_east,vel_north,vel_up,
    roll_deg,pitch_deg,heading_deg,std_east,std_north,std_up`` then the biases and the
    attitude's sigmas, as :func:`to_dataframe`), one row per
    state. ``.geojson`` / ``.kml``: the track for map viewers. ``.mcap``: Foxglove
    LocationFix / PoseInFrame / FrameTransform (plus the raw fixes; ``with_input=True`` copies
    the input MCAP's channels in). ``.tum``: ``timestamp tx ty tz qx qy qz qw`` in ENU at the
    same origin, body-to-ENU quaternion, for evo.

    The file is written to a temporary name and moved into place only when complete; the
    path is checked first (:func:`check_output`), also against the run's inputs.

    Example
    -------
    >>> track.write(tmp_path / "track.tum")  # doctest: +SKIP
    """
    _check_arguments(
        "write", trajectory=(trajectory, "trajectory"), path=(path, "path"),
        with_input=(with_input, "bool"),
    )  # fmt: skip
    run = trajectory.info.get("run", {})
    inputs = run.get("inputs", []) if isinstance(run, dict) else []
    path = check_output(path, inputs)
    if with_input:
        _check_with_input(inputs, path, option="with_input=True")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        from fgins.io.trajectory_csv import write_trajectory_csv

        write_trajectory_csv(trajectory, path)
    elif suffix in (".geojson", ".kml"):
        from fgins.io.trajectory_geo import write_trajectory_geo

        write_trajectory_geo(trajectory, path)
    elif suffix == ".tum":
        from fgins.io.trajectory_tum import write_trajectory_tum

        write_trajectory_tum(trajectory, path)
    else:  # .mcap (check_output allowed nothing else)
        from fgins.io.mcap_writer import write_mcap

        write_mcap(
            trajectory, path, gnss=trajectory.info.get("source_gnss"),
            input_path=str(inputs[0]) if with_input else None,
        )  # fmt: skip
    return Path(path)


def _check_with_input(
    inputs: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str],
    *,
    option: str = "--with-input",
) -> None:
    """Copying the input's channels needs an MCAP output and one MCAP input: else an
    :class:`OutputError` / :class:`InputError` saying what was given."""
    if Path(output).suffix.lower() != ".mcap":
        raise OutputError(f"{option} needs an MCAP output (got {_shortened(output)})")
    items = [os.fspath(item) for item in inputs]
    if len(items) == 1 and Path(items[0]).suffix.lower() == ".mcap" and Path(items[0]).is_file():
        return
    if not items:
        got = "a trajectory without inputs; with_input needs one from fgins.smooth"
    elif len(items) == 1 and Path(items[0]).is_dir():
        got = f"the folder {items[0]}"
    else:
        got = " ".join(items)
    raise InputError(f"{option} needs an MCAP input (got {got})")


def to_dataframe(trajectory: Trajectory) -> pd.DataFrame:
    """The trajectory as a :class:`pandas.DataFrame` with the trajectory CSV's columns.

    Columns, in order: ``time`` (s), ``lat``, ``lon`` (deg), ``alt`` (ellipsoidal m),
    ``east``, ``north``, ``up`` (m), ``vel_east``, ``vel_north``, ``vel_up`` (m/s),
    ``roll_deg``, ``pitch_deg``, ``heading_deg`` (deg, heading from north clockwise),
    ``std_east``, ``std_north``, ``std_up`` (1-sigma m), then ``gyro_bias_x..z`` (rad/s),
    ``accel_bias_x..z`` (m/s^2) and ``std_roll_deg``, ``std_pitch_deg``, ``std_heading_deg``
    (1-sigma deg). A method that does not estimate some of them (planar-kf: biases, attitude
    sigmas) gives NaN there. Full float64 values (the CSV rounds them when printing).
    """
    import pandas as pd

    from fgins.io.trajectory_csv import trajectory_columns

    _check_arguments("to_dataframe", trajectory=(trajectory, "trajectory"))
    header, table = trajectory_columns(trajectory)
    return pd.DataFrame(table, columns=header)


def _plain(value: Any) -> bool:
    """True for values a JSON summary can hold."""
    if isinstance(value, (str, int, float, bool)) or value is None:
        return True
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return False


def summary(trajectory: Trajectory) -> dict[str, Any]:
    """The run summary of a trajectory as a plain (JSON-serialisable) dict.

    Keys: ``method``, ``states``, ``t_start``, ``t_end``, ``duration_s``, ``timings`` (wall
    seconds per stage) and, for a trajectory from :func:`smooth`, ``dataset``, ``inputs``,
    ``gnss_outage``, ``imu_samples``, ``gnss_epochs``, ``gnss_withheld``, ``wall_s``,
    ``warnings``; then what the method reported: ``gnss_gating`` (text),
    ``gnss_epochs_used``, ``gnss_rejected`` (text) and ``gnss_rejected_times`` (s),
    ``gnss_excluded`` (text), ``gnss_excluded_times`` (s after the first GNSS epoch) and
    ``gnss_excluded_count`` (fixes left out as faults, batch and iSAM2),
    ``iterations``, ``initial_error``/``final_error``, ``keyframes``,
    ``odometer_scale_error``... (only those the method has).
    """
    import numpy as np

    _check_arguments("summary", trajectory=(trajectory, "trajectory"))
    out: dict[str, Any] = {
        "method": trajectory.method,
        "states": len(trajectory),
        "t_start": float(trajectory.t[0]) if len(trajectory) else float("nan"),
        "t_end": float(trajectory.t[-1]) if len(trajectory) else float("nan"),
    }
    out["duration_s"] = out["t_end"] - out["t_start"]
    run = trajectory.info.get("run")
    if isinstance(run, dict):
        out.update(run)
    for key, value in trajectory.info.items():
        if key in ("run", "source_gnss", "online"):
            continue
        if isinstance(value, np.generic):
            value = value.item()
        if _plain(value):
            out[key] = value
    out["timings"] = {
        k: float(v) for k, v in trajectory.timings.items() if isinstance(v, (int, float))
    }
    for k, v in trajectory.timings.items():
        if isinstance(v, (list, tuple, np.ndarray)) and len(v):
            # Per-step latencies (iSAM2's per-keyframe update) as their distribution.
            ms = 1e3 * np.asarray(v, dtype=float)
            out["timings"][f"{k.removesuffix('_s')}_ms"] = {
                "p50": float(np.percentile(ms, 50)),
                "p99": float(np.percentile(ms, 99)),
                "max": float(ms.max()),
            }
    return out


# ---------------------------------------------------------------------------------------------
# Benchmark and plots


def _check_same_drive(trajectory: Trajectory, dataset: Dataset, what: str) -> None:
    """A :class:`ConfigError` when ``trajectory`` was smoothed from another dataset than
    ``dataset`` (by its name and IMU sample count); one without a run record passes."""
    run = trajectory.info.get("run", {})
    if isinstance(run, dict) and run and (
        run.get("dataset") != dataset.name or run.get("imu_samples") != len(dataset.imu)
    ):
        raise ConfigError(
            f"{what} was smoothed from {run.get('dataset')!r} ({run.get('imu_samples')} IMU "
            f"samples), not from this dataset {dataset.name!r} ({len(dataset.imu)}): give the "
            "dataset it came from"
        )


def _own_outages(dataset: Dataset, reference: Trajectory | None) -> list[tuple[float, float]]:
    """The GNSS outages built into the data (a sim folder's [scenario] outages), in seconds
    after t0, when the benchmark can score them: against a truth, each holding no GNSS epoch
    (they were left out of the data). ``fgins sim aircraft-ekf`` writes its 60 s outage so:
    the default windows around it withheld nothing there and the benchmark stopped."""
    import numpy as np

    absolute = dataset.metadata.get("scenario_outages_t") or []
    if reference is None or not absolute:
        return []
    t = dataset.gnss.t
    own = []
    for start, end in absolute:
        if t[0] < start < t[-1] and not np.any((t >= start) & (t < end)):
            own.append((float(start - dataset.t0), float(min(end, t[-1]) - dataset.t0)))
    return own


def _hollow_windows(
    dataset: Dataset, config: RunConfig, windows: list[tuple[float, float]]
) -> list[tuple[tuple[float, float], str]]:
    """The windows that hold GNSS epochs but none the run would use (each gated: no
    position, outside the IMU span, fix quality, PDOP), each with why."""
    from fgins.factors.gnss import gate_epochs
    from fgins.outages import in_windows

    gnss, imu = dataset.gnss, dataset.imu
    out = []
    for window in windows:
        inside = in_windows(gnss.t, dataset.t0, [window])
        if not inside.any():
            continue  # no epoch at all: empty_windows's case
        gate = gate_epochs(
            gnss.subset(inside), config.gnss, imu_span=(float(imu.t[0]), float(imu.t[-1]))
        )
        if gate.usable.any():
            continue
        reasons = [
            f"{n} {what}"
            for n, what in (
                (gate.rejected_pdop, f"by PDOP > {gate.pdop_max:g}" if gate.pdop_max else "by PDOP"),
                (gate.rejected_quality, "by fix quality"),
                (gate.rejected_position, "without a position"),
                (gate.outside_span, "outside the IMU time span"),
            )
            if n
        ]
        out.append(
            ((float(window[0]), float(window[1])),
             f"its {int(inside.sum())} GNSS epochs are all gated already: {', '.join(reasons)}")
        )  # fmt: skip
    return out


def _truth_for(dataset: Dataset, truth: Any) -> Trajectory | None:
    from fgins.io.trajectory_csv import read_trajectory_csv

    stated = bool(dataset.metadata.get("origin_stated"))  # a truth's bare ENU is about it

    if truth is None:
        return None
    if isinstance(truth, Trajectory):
        # Another drive's trajectory scored as this one's truth gives numbers, silently.
        _check_same_drive(truth, dataset, "bench(): truth")
        reference = truth
    elif isinstance(truth, str) and truth == "auto":
        # A simulator folder holds its exact truth beside the sensor files.
        inputs = dataset.metadata.get("inputs", [])
        if len(inputs) == 1 and (Path(inputs[0]) / "truth.csv").is_file():
            return read_trajectory_csv(Path(inputs[0]) / "truth.csv", dataset.origin, enu_about_origin=stated)
        return None
    elif isinstance(truth, (str, os.PathLike)):
        reference = read_trajectory_csv(truth, dataset.origin, enu_about_origin=stated)
    else:
        raise ConfigError(
            f"bench(): truth must be a Trajectory, a trajectory CSV's path, \"auto\" or None, "
            f"not {type(truth).__name__}"
        )
    span = (float(dataset.imu.t[0]), float(dataset.imu.t[-1]))
    covered = min(span[1], float(reference.t[-1])) - max(span[0], float(reference.t[0]))
    if len(reference.t) < 2 or covered < 0.5 * (span[1] - span[0]):
        raise InputError(
            f"bench(): the truth covers {reference.t[0]:.1f}-{reference.t[-1]:.1f} s, less than "
            f"half of this drive's {span[0]:.1f}-{span[1]:.1f} s: not its reference"
        )
    _check_truth_near_fixes(reference, dataset)
    return reference


# A truth whose positions lie further than this from the drive's own fixes (median, m, and
# times their median stated sigma) is another drive's: another drive's truth.csv over the
# same span was scored silently as 1,089 m of "outage error" (outside tester).
TRUTH_FIXES_APART_M = 30.0
TRUTH_FIXES_APART_SIGMAS = 10.0


def _check_truth_near_fixes(reference: Trajectory, dataset: Dataset) -> None:
    import numpy as np

    fixes = dataset.gnss_enu()
    at = reference.at(dataset.gnss.t)
    both = np.all(np.isfinite(at[:, :2]), axis=1) & np.all(np.isfinite(fixes[:, :2]), axis=1)
    if both.sum() < 3:
        return
    apart = float(np.median(np.hypot(*(at[both, :2] - fixes[both, :2]).T)))
    sigma = dataset.gnss.std
    stated = float(np.nanmedian(sigma[:, :2])) if sigma is not None and np.isfinite(sigma[:, :2]).any() else 0.0
    if apart > max(TRUTH_FIXES_APART_M, TRUTH_FIXES_APART_SIGMAS * stated):
        raise InputError(
            f"bench(): the truth lies {apart:.0f} m (median) from this drive's GNSS fixes: not "
            "its reference (another drive's truth, or another origin)"
        )


def check_methods(methods: str | Iterable[str], baseline: str | None = None) -> list[str]:
    """``methods`` (names, or one comma-separated string) as a list, checked: at least one,
    all known; and ``baseline``, when given, one of the rows they make (``isam2`` also makes
    ``isam2-online``). Else a :class:`ConfigError` naming what is wrong."""
    from fgins.pipeline import METHODS

    if isinstance(methods, str):
        methods = [m.strip() for m in methods.split(",") if m.strip()]
    elif not isinstance(methods, Iterable):
        raise ConfigError(
            f"--methods: must be a list of method names, not {type(methods).__name__} {methods!r}"
        )
    methods = list(methods)
    if not methods:
        raise ConfigError(f"--methods: no method given; choose from {', '.join(METHODS)}")
    unknown = sorted({str(m) for m in methods if not isinstance(m, str) or m not in METHODS})
    if unknown:
        raise ConfigError(
            f"--methods: unknown {', '.join(unknown)}; choose from {', '.join(METHODS)}"
        )
    methods = list(dict.fromkeys(methods))  # a method named twice is one row, not two
    # isam2's run gives its online estimate too, its row unless isam2-online is asked for
    # on its own (fgins.bench.outages.run_case): one row either way.
    if baseline is not None:
        rows = [*methods, *(["isam2-online"] if "isam2" in methods else [])]
        if baseline not in rows:
            known = "unknown method" if baseline not in METHODS else "not among --methods"
            raise ConfigError(
                f"--baseline {baseline!r}: {known}; the ratios are taken against a method of "
                f"the same run: choose one of {', '.join(dict.fromkeys(rows))}"
                + (" or add it to --methods" if baseline in METHODS else "")
            )
    return methods


def bench(
    dataset: Dataset,
    methods: Sequence[str] = DEFAULT_BENCH_METHODS,
    outages: str | Iterable[Sequence[float]] | None = None,
    *,
    config: str | os.PathLike[str] | RunConfig | None = None,
    truth: Trajectory | str | os.PathLike[str] | None = "auto",
    baseline: str | None = None,
    outage_duration: float | None = None,
    outage_period: float | None = None,
    outage_start: float | None = None,
    output_dir: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> pd.DataFrame:
    """Outage benchmark: every method on the same data and the same GNSS outages.

    Parameters
    ----------
    dataset : Dataset
        From :func:`load`.
    methods : sequence of str, default ("batch", "isam2", "ekf", "ekf-rts")
        Methods to run; ``isam2`` also contributes its online estimate (``isam2-online``).
    outages : list of (start, end), optional
        Outage windows in seconds after t0. Default: the data's own outages where they
        can be scored (a sim folder's ``[scenario] outages``, against its truth) and no
        protocol number is given, else ``outage_duration`` (30) s every ``outage_period``
        (90) s from ``outage_start`` (60) s while they fit in the GNSS span, less those
        where the data have no GNSS epoch (said).
    config : path or RunConfig, optional
        Overrides the configuration chosen by :func:`load`.
    truth : Trajectory, path, "auto" or None, default "auto"
        Reference. ``"auto"``: a simulator folder's ``truth.csv`` when the dataset was loaded
        from one; otherwise (and with None) the withheld GNSS fixes themselves.
    baseline : str, optional
        Method the ``rms_ratio`` column is taken against (measured in the same run, so one
        of ``methods``, or ``isam2-online`` with ``isam2``). Default: ``ekf`` when among
        ``methods``, else the first of them.
    output_dir : path, optional
        Also write ``outages.json``, ``outages.md`` and one plot per case there.

    Returns
    -------
    pandas.DataFrame
        One row per method: ``case``, ``method``, ``h_rms_outage_m``, ``h_max_outage_m``,
        ``h_end_outage_m`` (mean error at the end of the windows), ``h_rms_aided_m``,
        ``rpe_100m_m`` (RMS relative position error over 100 m of reference path, see
        :func:`fgins.bench.metrics.relative_position_error`), ``within_3sigma_outage``
        (fraction), ``wall_s``, ``imu_samples_per_s``, ``rms_ratio``. ``attrs`` holds
        ``reference``, ``outages`` and ``baseline``.

    Example
    -------
    >>> table = fgins.bench(fgins.load("demo:kitti"), methods=["ekf", "ekf-rts"])  # doctest: +SKIP
    """
    from fgins.bench.outages import (
        BenchCase,
        check_bench_dir,
        results_frame,
        run_case,
        window_table,
        write_results,
    )
    from fgins.config import RunConfig
    from fgins.outages import periodic_windows

    _check_arguments(
        "bench", dataset=(dataset, "dataset"), config=(config, "config?"),
        baseline=(baseline, "text?"), outage_duration=(outage_duration, "number?"),
        outage_period=(outage_period, "number?"), outage_start=(outage_start, "number?"),
        output_dir=(output_dir, "path?"), progress=(progress, "bool"),
    )  # fmt: skip
    methods = check_methods(methods, baseline)
    if baseline is None:
        baseline = "ekf" if "ekf" in methods else methods[0]
    if output_dir is not None and Path(output_dir).exists() and not Path(output_dir).is_dir():
        raise OutputError(f"{output_dir}: exists and is not a folder")
    if config is None:
        run_config = dataset.metadata.get("run_config") or configure(dataset)
    elif isinstance(config, RunConfig):
        run_config = config
    else:  # as smooth(): load's explicit choices over a file
        run_config = configure(dataset, config, **(dataset.metadata.get("run_choices") or {}))
    run_config = run_config.checked()  # a RunConfig changed in code is checked again
    dataset = _checked_input(dataset, run_config.smoother.vehicle, run_config.imu_sample_timing)
    array_only = [m for m in methods if m.startswith("ekf18")]
    if array_only and dataset.accel_array is None:
        # Known before any solve: not a run of the others and a row of nothing.
        raise ConfigError(
            f"--methods {array_only[0]}: {dataset.name or 'the input'} has an ordinary IMU; "
            f"{array_only[0]} needs accelerometer-array readings (accel_array.csv): leave it "
            f"out of --methods ({array_only[0].replace('ekf18', 'ekf')} is the filter for an "
            "ordinary IMU)"
        )
    windows = _windows(outages)
    given = [name for name, value in (("outage_duration", outage_duration),
             ("outage_period", outage_period), ("outage_start", outage_start)) if value is not None]  # fmt: skip
    if windows and given:
        # Two answers to one question: the run used the windows and dropped the protocol's
        # number without a word (outside tester: --outage-duration 20 beside 60:90).
        raise ConfigError(
            f"bench: outage windows given together with {given[0]} (the periodic protocol's "
            f"--{given[0].replace('_', '-')}): give one or the other"
        )
    from fgins.outages import empty_windows, overlapping_windows

    said: list[str] = []  # warnings, also returned in attrs["warnings"] (the CLI prints them)

    reference = _truth_for(dataset, truth)
    # The protocol's windows where asked for (any of its three numbers given), else the
    # data's own outages where they can be scored, else the protocol's defaults.
    asked = (outage_duration, outage_period, outage_start)
    protocol = tuple(
        default if value is None else float(value)
        for value, default in zip(asked, (30.0, 90.0, 60.0), strict=True)
    )
    own = [] if windows or any(v is not None for v in asked) else _own_outages(dataset, reference)
    if own:
        windows = own
    elif not windows:
        span = float(dataset.gnss.t[-1] - dataset.t0)
        windows = periodic_windows(*protocol, span)
        # The protocol's windows are not the user's: one that falls where the data have no
        # GNSS already (a sim folder's outage without its truth, a receiver's gap) is left
        # out and said; an explicit window there stays an error.
        found = [empty_windows(dataset, [window]) for window in windows]
        empty = [line for lines in found for line in lines]
        if empty and len(empty) < len(windows):
            said.append(
                f"bench: {len(empty)} of the {len(windows)} default outage windows fall where "
                f"the data have no GNSS epoch and are left out ({empty[0]})"
            )
            windows = [window for window, lines in zip(windows, found, strict=True) if not lines]

    overlaps = overlapping_windows(windows)
    if overlaps:
        # Each window is scored as its own outage: two that run into each other would score
        # parts of one longer outage (twice where they overlap).
        raise ConfigError(overlaps[0] + "; benchmark windows must be apart")
    empty = [] if own else empty_windows(dataset, windows)
    if empty or not windows:
        # A benchmark of outages with no outage in it measures nothing (outside tester:
        # exit 0 and a table of NaN).
        raise ConfigError(
            (empty[0] + f" ({len(empty)} of {len(windows)} windows)") if empty
            else "no outage window fits in the GNSS span: give outages inside the drive"
        )
    # A window whose fixes are all gated already (PDOP, fix quality) withholds nothing the
    # run would have used: the run is the same as without it, no outage test (outside
    # tester: car-urban's default 60:90 inside its PDOP stretch, scored as an outage).
    hollow = [] if own else _hollow_windows(dataset, run_config, windows)
    for window, why in hollow:
        said.append(
            f"bench: window {window[0]:g}:{window[1]:g} s withholds no usable GNSS fix ({why}): "
            "the run is the same without it; left out of the scores"
        )
    if hollow:
        left = {window for window, _ in hollow}
        windows = [w for w in windows if (float(w[0]), float(w[1])) not in left]
        if not windows:
            (start, end), why = hollow[0]
            raise ConfigError(
                f"window {start:g}:{end:g} s withholds no usable GNSS fix ({why}; {len(hollow)} "
                f"of {len(hollow)} windows): no outage to score; give windows where the data "
                "have fixes the run uses"
            )
    # A window past the data's end is scored over the part the data have (outside tester:
    # 280:400 on 300 s scored as 280:300 without a word).
    import numpy as np

    last = float(dataset.gnss.t[-1] - dataset.t0)
    step = float(np.median(np.diff(dataset.gnss.t))) if len(dataset.gnss.t) > 1 else 0.0
    for start, end in windows:
        if end > last + step:
            said.append(
                f"bench: window {start:g}:{end:g} s runs past the last GNSS epoch ({last:.1f} s "
                f"after t0): scored over {start:g}:{last:.1f}, its outage as long as that"
            )
    name = dataset.name.replace(":", "-") or "input"
    if output_dir is not None:
        check_bench_dir(output_dir, [name])  # before any solve
    case = BenchCase(name, dataset, run_config, windows, truth=reference)
    case.left_out = [(window, why) for window, why in hollow]
    run_case(case, methods, progress=progress)
    if not case.results:
        raise FginsError(
            f"bench: no method produced a result ({'; '.join(case.failures)}); nothing written"
        )
    for method, why in case.failed.items():
        said.append(f"bench: {method} produced no result ({why}); its row says so")
    # What each method said of its own result (a smoother's attitude not to be trusted, a
    # fit that does not hold): its row's numbers mean nothing without it (outside tester:
    # an EKF+RTS row at "100 % in 3 sigma" whose smooth run warned "not to be trusted").
    for result in case.results:
        said.extend(  # once the method's name (a filter's own notes begin with it)
            f"bench: {line if line.startswith(f'{result.method}: ') else f'{result.method}: {line}'}"
            for line in result.warnings
        )
    rows = {result.method for result in case.results}
    if baseline not in rows:
        said.append(
            f"bench: the baseline {baseline} produced no result: the RMS / {baseline} column "
            "is n/a"
        )
    for line in said:
        warnings.warn(line, FginsWarning, stacklevel=2)
    frame = results_frame([case], baseline=baseline)
    frame.attrs.update(
        {
            "reference": "truth" if reference is not None else "withheld GNSS",
            "outages": windows,
            # Where the windows come from: given, the data's own (a sim folder's
            # [scenario] outages) or the default protocol.
            "outages_from": "given" if _windows(outages) else ("data" if own else "protocol"),
            "protocol": protocol,
            "baseline": baseline,
            "outages_left_out": [window for window, _ in hollow],
            "warnings": said,
            # Each window's own numbers per method (fgins.bench.outages.MethodResult.windows).
            "windows": {result.method: result.windows for result in case.results},
            "window_table": window_table([case]),
        }
    )
    if output_dir is not None:
        write_results([case], Path(output_dir), baseline=baseline)
    return frame


def plot(
    trajectories: Trajectory | Sequence[Trajectory],
    dataset: Dataset,
    *,
    gnss_outage: str | Iterable[Sequence[float]] | None = None,
    path: str | os.PathLike[str] | None = None,
    title: str = "",
) -> Figure:
    """Track and horizontal error against the GNSS fixes, as a matplotlib Figure.

    One or several trajectories of the same ``dataset``; ``gnss_outage`` shades the windows
    and marks the withheld fixes (default: the windows of the first trajectory's run).
    ``path`` also writes the figure (PNG, PDF or SVG by extension). In a notebook the
    returned Figure displays itself.
    """
    from fgins.bench.plots import plot_track_and_errors

    if isinstance(trajectories, (str, bytes, dict)):  # iterating it would judge its parts
        # a wrong-type argument, as trajectories[i] below (README "Errors"): InputError
        raise InputError(
            f"plot(): trajectories must be a Trajectory (from fgins.smooth) or a list of them, "
            f"not {type(trajectories).__name__}"
        )
    items = (
        [trajectories]
        if isinstance(trajectories, Trajectory) or not isinstance(trajectories, Iterable)
        else list(trajectories)
    )
    if not items:
        raise InputError("plot(): trajectories is empty; give a Trajectory (from fgins.smooth)")
    _check_arguments(
        "plot", **{f"trajectories[{i}]": (item, "trajectory") for i, item in enumerate(items)}
    )
    _check_arguments(
        "plot", dataset=(dataset, "dataset"), path=(path, "path?"), title=(title, "text")
    )
    for i, item in enumerate(items):
        # A trajectory drawn against another drive's fixes is a plot of nonsense, silently.
        _check_same_drive(item, dataset, f"plot(): trajectories[{i}]")
    if path is not None:
        run = items[0].info.get("run", {})
        inputs = run.get("inputs", []) if isinstance(run, dict) else []
        path = check_output(path, inputs, suffixes=PLOT_SUFFIXES, what="plot")
    if gnss_outage is None:
        run = items[0].info.get("run", {}) if items else {}
        windows = list(run.get("gnss_outage", [])) if isinstance(run, dict) else []
    else:
        windows = _windows(gnss_outage)
    return plot_track_and_errors(items, dataset, windows, path=path, title=title)
