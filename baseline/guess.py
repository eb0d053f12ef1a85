"""The Kalman filter that makes the factor graph's initial guess, chosen per input."""

from __future__ import annotations

import numpy as np

from fgins.baseline.ekf import EkfOptions, ekf_states_at
from fgins.baseline.ekf18 import ekf18_states_at
from fgins.config import RunConfig
from fgins.datatypes import Dataset
from fgins.initial_guess import KeyframeGuess, guess_config

# The guess filter composes each block's Phi and Q over at most this many sub-steps (not
# every IMU sample): the covariance to first order, ~10x less work per block (issue 9).
GUESS_TRANSITION_STEPS = 8


def filter_guess(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    *,
    gnss_mask: np.ndarray | None = None,
    array_filter: bool = True,
    biases: str = "interval",
) -> KeyframeGuess:
    """The forward filter's states at ``times`` with the guess configuration
    (:func:`guess_config`). Raises what the filter raises (FginsError / InputError).

    The filter that matches the input, as ``fgins.pipeline.filter_initial_guess`` chooses
    it: the 18-state gyro-free EKF on the raw array readings for an accelerometer-array
    dataset (``array_filter=False``: the 15-state EKF on the front end's output instead),
    else the 15-state EKF; the same numbers as sampling their IMU-rate output with
    sampling the filter's IMU-rate output (``biases="interval"``: biases averaged over each
    keyframe interval; ``"nearest"``: the first sample's, graph.smoother's older guess).
    """
    config = guess_config(config)
    if array_filter and dataset.accel_array is not None:
        return ekf18_states_at(dataset, config, times, gnss_mask=gnss_mask, biases=biases)
    return ekf_states_at(
        dataset, config, times, gnss_mask=gnss_mask, biases=biases,
        options=EkfOptions(transition_steps=GUESS_TRANSITION_STEPS),
    )  # fmt: skip
