"""The Kalman filter that makes the factor graph's initial guess where the graph's own
keyframe EKF (:mod:`fgins.graph.keyframe_filter`) does not match the input: a gyro-free
accelerometer array, whose rates the 18-state EKF estimates from the raw readings."""

from __future__ import annotations

import numpy as np

from fgins.baseline.ekf18 import ekf18_states_at
from fgins.config import RunConfig
from fgins.datatypes import Dataset, InputError
from fgins.initial_guess import KeyframeGuess, guess_config


def filter_guess(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    *,
    gnss_mask: np.ndarray | None = None,
    biases: str = "interval",
) -> KeyframeGuess:
    """The 18-state gyro-free EKF's states at ``times`` with the guess configuration
    (:func:`guess_config`: Huber-weighted GNSS), the same numbers as sampling its IMU-rate
    output (``biases="interval"``: biases averaged over each keyframe interval;
    ``"nearest"``: the first sample's). Raises what the filter raises (FginsError)."""
    if dataset.accel_array is None:
        raise InputError("the gyro-free initial guess needs accelerometer-array readings")
    return ekf18_states_at(dataset, guess_config(config), times, gnss_mask=gnss_mask, biases=biases)
