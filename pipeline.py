"""One call from a dataset to a trajectory, whatever the method (factor graph or baseline)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory

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
        return function(dataset, config, gnss_mask=gnss_mask, progress=progress)
    raise FginsError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")


@dataclass
class KeyframeStates:
    """Navigation states and IMU biases at given times (K rows): a filter's initial guess."""

    rotation: np.ndarray  # (K, 3, 3) body -> ENU
    position: np.ndarray  # (K, 3)
    velocity: np.ndarray  # (K, 3)
    accel_bias: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)


def filter_initial_guess(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None
) -> Callable[[np.ndarray], KeyframeStates]:
    """The initial guess the factor graph starts from: the Kalman filter that matches the
    input (the 18-state gyro-free EKF for an accelerometer array, else the 15-state EKF),
    with Huber-weighted GNSS updates, sampled at the keyframe times.

    Huber-weighted updates bound what a gross outlier can do to the guess; a hard innovation
    gate would be worse: once it rejects a few fixes the filter can lock out
    (:func:`fgins.initial_guess.guess_config`).
    """

    def guess(times: np.ndarray) -> KeyframeStates:
        # The filter reports its states at the keyframes only (same numbers as
        # sample_states of its IMU-rate output, without that output: issue 9).
        from fgins.baseline.guess import filter_guess

        return filter_guess(dataset, config, times, gnss_mask=gnss_mask)  # type: ignore[return-value]

    return guess


def sample_states(trajectory: Trajectory, times: np.ndarray) -> KeyframeStates:
    """A trajectory's states at ``times``: position and velocity interpolated, attitude at
    the nearest sample, biases averaged over each keyframe interval [t_k, t_k+1) (a gyro-free
    front end's rate error is noisy sample to sample; its mean is what preintegration needs)."""
    t = trajectory.t
    nearest = np.clip(np.searchsorted(t, times), 0, len(t) - 1)
    position = np.column_stack([np.interp(times, t, trajectory.position[:, i]) for i in range(3)])
    velocity = np.column_stack([np.interp(times, t, trajectory.velocity[:, i]) for i in range(3)])

    def interval_mean(values: np.ndarray | None) -> np.ndarray:
        if values is None:
            return np.zeros((len(times), 3))
        values = np.nan_to_num(np.asarray(values, dtype=float))
        cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(values, axis=0)])
        lo = np.searchsorted(t, times)
        hi = np.append(lo[1:], len(t))
        hi = np.maximum(hi, lo + 1)
        lo, hi = np.clip(lo, 0, len(t) - 1), np.clip(hi, 1, len(t))
        return (cumulative[hi] - cumulative[lo]) / (hi - lo)[:, None]

    return KeyframeStates(
        rotation=trajectory.rotation[nearest],
        position=position,
        velocity=velocity,
        accel_bias=interval_mean(trajectory.accel_bias),
        gyro_bias=interval_mean(trajectory.gyro_bias),
    )
