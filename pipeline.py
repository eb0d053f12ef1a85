"""One call from a dataset to a trajectory, whatever the method (factor graph or baseline)."""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory
from fgins.initial_guess import KeyframeGuess

GRAPH_METHODS = ("batch", "isam2", "isam2-online")
# Kalman baselines: method name -> "module:function" taking (dataset, config, gnss_mask=...,
# progress=...) and returning a Trajectory. Modules are imported only when asked for.
BASELINE_METHODS = {
    "ekf": "fgins.baseline.ekf:run_ekf",
    "ekf-rts": "fgins.baseline.ekf:run_ekf_rts",
    "ukf": "fgins.baseline.ukf:run_ukf",
    "planar-kf": "fgins.baseline.planar_kf:run_planar_kf",
    "ekf18": "fgins.baseline.ekf18:run_ekf18",
}
# A gyro-free IMU (raw accelerometer-array readings in the dataset) has its own filter.
ACCEL_ARRAY_METHODS = {"ekf": "ekf18"}
METHODS = GRAPH_METHODS + tuple(BASELINE_METHODS)


def run_method(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
) -> Trajectory:
    mounting_note = _check_mounting(dataset, config)
    trajectory = _run(dataset, config, method, gnss_mask, progress)
    if mounting_note:
        trajectory.info.setdefault("fit_warnings", []).append(mounting_note)
    return trajectory


def _check_mounting(dataset: Dataset, config: RunConfig) -> str | None:
    """A car's configured IMU mounting against the one its turns show (fgins.mounting):
    the constraints every method applies in the vehicle frame depend on it."""
    if not config.smoother.nhc or dataset.accel_array is not None:
        return None  # no vehicle-frame constraint (or derived rates: too noisy to tell)
    from fgins.mounting import check_mounting

    return check_mounting(dataset, config.smoother.imu_to_vehicle_rpy_deg)


def _run(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    gnss_mask: np.ndarray | None,
    progress: bool,
) -> Trajectory:
    if method in GRAPH_METHODS:
        from fgins.graph.smoother import smooth

        return smooth(
            dataset, config, method, gnss_mask=gnss_mask, progress=progress,
            initial_guess=filter_initial_guess(dataset, config, gnss_mask),
        )  # fmt: skip
    if dataset.accel_array is not None:
        method = ACCEL_ARRAY_METHODS.get(method, method)
    if method in BASELINE_METHODS:
        module_name, function_name = BASELINE_METHODS[method].split(":")
        try:
            function = getattr(importlib.import_module(module_name), function_name)
        except (ImportError, AttributeError):
            raise FginsError(f"method {method!r} is not available in this build") from None
        trajectory = function(dataset, config, gnss_mask=gnss_mask, progress=progress)
        if dataset.odometer is not None and len(dataset.odometer.t):
            # The Kalman baselines have no wheel-speed update: said, never silently ignored.
            trajectory.info["fit_warnings"] = [
                *trajectory.info.get("fit_warnings", []),
                f"{method} does not use the wheel speed ({len(dataset.odometer.t)} samples); "
                "--method batch or isam2 do",
            ]
        return trajectory
    raise FginsError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")


def filter_initial_guess(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None
) -> Callable[[np.ndarray], list[KeyframeGuess]] | None:
    """The initial guesses the factor graph may start from, for the input at hand.

    For an IMU, None: the graph runs its own keyframe EKF over the very factors it
    optimises (:mod:`fgins.graph.keyframe_filter`: the same measurement models, a fifth of
    the cost of the IMU-rate 15-state EKF). For an accelerometer array (gyro-free): the
    18-state EKF on the raw readings, with Huber-weighted GNSS updates, sampled at the
    keyframe times; and, for a car, the guess from the GNSS track and gravity
    (:mod:`fgins.track_guess`), which cannot diverge where the EKF does (GNSS at 0.2 Hz
    leaves the EKF's attitude nothing to hold it between fixes). The graph starts from the
    one that fits its factors best and restarts from the other if that fit fails.

    Huber-weighted updates bound what a gross outlier can do to the guess; a hard innovation
    gate would be worse: once it rejects a few fixes the filter can lock out
    (:func:`fgins.initial_guess.guess_config`).
    """
    if dataset.accel_array is None:
        return None

    def guesses(times: np.ndarray) -> list[KeyframeGuess]:
        # The filter reports its states at the keyframes only (the same numbers as sampling
        # its IMU-rate output there, without making that output: issue 9).
        from fgins.baseline.guess import filter_guess
        from fgins.track_guess import track_guess

        candidates: list[KeyframeGuess] = []
        failures: list[FginsError] = []
        makers = [lambda: filter_guess(dataset, config, times, gnss_mask=gnss_mask)]
        if config.smoother.nhc:  # the vehicle's nose follows its track
            makers.append(lambda: track_guess(dataset, config, times, gnss_mask=gnss_mask))
        for make in makers:
            try:
                candidates.append(make())
            except FginsError as exc:
                failures.append(exc)
        if not candidates:
            raise failures[0]
        return candidates

    return guesses
