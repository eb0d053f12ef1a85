"""The initial guess a smoother starts from: filter states at its keyframe times (numpy only).

The pipeline chooses the guess (DESIGN.md: "the pipeline, not graph/, chooses and hands over
an initial guess"): for an IMU, the graph's own keyframe EKF (:mod:`fgins.graph.keyframe_filter`,
which needs the graph's factors and so lives in graph/); for an accelerometer array, the
18-state gyro-free EKF's states (:func:`fgins.baseline.ekf18.ekf18_states_at` through
:func:`fgins.baseline.guess.filter_guess`) and, on a car, the states from the GNSS track and
gravity (:func:`fgins.track_guess.track_guess`), handed over as candidates through this
GTSAM-free contract, which imports neither side. (:func:`fgins.baseline.ekf.ekf_states_at` gives the 15-state
EKF's states the same way.)

Why keyframe states only: the smoother needs one state per keyframe (one per GNSS epoch and
outage fill time), not the filter's IMU-rate output with a 15x15 covariance per sample, which
cost 5.7 KB per IMU sample (4.1 GB on a 1 h, 200 Hz drive).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fgins.config import RunConfig


@dataclass(frozen=True)
class KeyframeGuess:
    """Navigation states at the keyframe times ``t`` (K,).

    ``rotation`` (K, 3, 3) body -> ENU, ``position`` and ``velocity`` (K, 3) in the dataset's
    ENU frame, ``accel_bias`` and ``gyro_bias`` (K, 3) in the body frame (NaN-free: a filter
    without such a state reports zeros). ``method`` names the filter that made it.
    """

    t: np.ndarray
    rotation: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    method: str = "ekf"

    def __len__(self) -> int:
        return len(self.t)

    @property
    def finite(self) -> bool:
        """True when every position and velocity is finite (else fall back to another guess)."""
        return bool(np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.velocity)))


def guess_config(config: RunConfig) -> RunConfig:
    """The configuration of the filter that makes the initial guess: Huber-weighted GNSS.

    Huber-weighted updates bound what a gross outlier can do to the guess; a hard innovation
    gate would be worse: once it rejects a few fixes the filter can lock out. (The values
    graph.start.initial_values has always used: huber_k = 2, no Cauchy kernel.)
    """
    return replace(config, gnss=replace(config.gnss, huber_k=2.0, cauchy_k=None))
