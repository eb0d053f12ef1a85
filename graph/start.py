"""The batch's start: the keyframe EKF over the graph's own factors, or the candidates the
pipeline supplies (ranked by how well they fit with their attitudes and biases held), or
GNSS-reset dead reckoning; the preintegration is made about the start's biases.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.datatypes import FginsError
from fgins.factors.values import put_bias, put_pose, put_vector
from fgins.graph.keyframe_filter import keyframe_filter
from fgins.graph.problem import Problem
from fgins.graph.solve import full_graph, levenberg_marquardt, nonlinear_graph


class KeyframeGuess(Protocol):
    """States at the keyframe times (K rows): what an initial-guess provider returns."""

    rotation: np.ndarray  # (K, 3, 3) body -> ENU
    position: np.ndarray  # (K, 3)
    velocity: np.ndarray  # (K, 3)
    accel_bias: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)


# keyframe times (K,) -> candidate states there, best first; chosen and supplied by the
# pipeline (a filter that matches the input, a guess from the GNSS track), so graph/ does not
# depend on baseline/. The batch starts from the candidate that fits best (_held_fit_error).
InitialGuess = Callable[[np.ndarray], Sequence[KeyframeGuess]]


def _values_from_states(problem: Problem, guess: KeyframeGuess) -> gtsam.Values:
    values = gtsam.Values()
    for k in range(problem.n_keyframes):
        put_pose(values, X(k), gtsam.Pose3(gtsam.Rot3(guess.rotation[k]), guess.position[k]))
        put_vector(values, V(k), guess.velocity[k])
        put_bias(values, B(k), gtsam.imuBias.ConstantBias(guess.accel_bias[k], guess.gyro_bias[k]))
        problem.insert_extra_values(k, values)
    return values


def _usable_guess(guess: KeyframeGuess | None, n: int) -> bool:
    if guess is None:
        return False
    arrays = (guess.rotation, guess.position, guess.velocity, guess.accel_bias, guess.gyro_bias)
    return all(len(a) == n and np.all(np.isfinite(a)) for a in arrays)


@dataclass
class Start:
    """A start for LM: initial values and what made them (the problem's preintegration is
    about their biases when they are the current start)."""

    values: gtsam.Values
    source: str
    guess: KeyframeGuess | None = None  # to re-preintegrate about when taken up again

    def take(self, problem: Problem, progress: bool = False) -> gtsam.Values:
        """Preintegrate about this start's biases (if it has its own) and return its values."""
        if self.guess is not None:
            problem.preintegrate_all(self.guess.accel_bias, self.guess.gyro_bias, progress)
        return self.values


def initial_values(
    problem: Problem, initial_guess: InitialGuess | None, progress: bool
) -> tuple[Start, list[Start]]:
    """The start for LM, and the other candidates (for a restart), best first.

    Without ``initial_guess`` (an IMU): the keyframe EKF over the graph's own factors
    (:mod:`fgins.graph.keyframe_filter`), which preintegrates every interval about its
    filtered bias as it goes. With one (for an accelerometer array: the pipeline's ekf18 and
    the GNSS-track guess): every usable candidate, each interval preintegrated about its
    biases; LM starts from the one that fits best (:func:`_held_fit_error`). If none gives a
    usable start:
    GNSS-reset dead reckoning about zero bias. On return the preintegration is about the
    start's biases.
    """
    n = problem.n_keyframes
    problem.restart()
    try:
        if initial_guess is None:
            return Start(keyframe_filter(problem, progress), "keyframe EKF"), []
        guesses = list(initial_guess(problem.segments.times))
    except FginsError as exc:
        problem.info.setdefault("fit_warnings", []).append(
            f"the initial-guess filter failed ({exc}); started from dead reckoning instead"
        )
        guesses = []
    starts = [
        Start(_values_from_states(problem, guess), getattr(guess, "method", "filter"), guess)
        for guess in guesses
        if _usable_guess(guess, n)
    ]
    if len(starts) > 1:
        errors = [_held_fit_error(problem, start.take(problem, progress)) for start in starts]
        order = np.argsort(np.nan_to_num(np.array(errors), nan=np.inf), kind="stable")
        if order[0] != len(starts) - 1:  # the last one evaluated is preintegrated already
            starts[order[0]].take(problem, progress)
        starts = [starts[i] for i in order]
        problem.info["initial_guess_errors"] = {
            starts[j].source: float(errors[i]) for j, i in enumerate(order)
        }
    elif starts:
        starts[0].take(problem, progress)
    if starts:
        return starts[0], starts[1:]
    zeros = np.zeros((n, 3))
    problem.preintegrate_all(zeros, zeros, progress)
    return Start(dead_reckoning_guess(problem), "dead reckoning"), []


# Candidate starts are compared with their attitudes and biases held this tightly.
HELD_ATTITUDE_RAD = 1e-5
HELD_BIAS = 1e-7
HELD_FIT_ITERATIONS = 5


def _held_fit_error(problem: Problem, values: gtsam.Values) -> float:
    """The graph error once a candidate's positions and velocities are fitted to its own
    attitudes and biases (held by tight priors): how well what is hard to find (attitude,
    rate bias) explains the data. The error at the raw guess says little about that: it is
    dominated by how the guess's positions and velocities fit each other (a track guess
    interpolates fixes, a filter's states are propagated), which a few iterations put right
    for any start; a heading 40 deg off barely changes it (tests/test_track_guess.py)."""
    graph = full_graph(problem, nonlinear_graph(problem, None), values)
    held = gtsam.NonlinearFactorGraph()
    held.push_back(graph)
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[np.full(3, HELD_ATTITUDE_RAD), np.full(3, 1e6)]  # Pose3 tangent: rotation first
    )
    bias_noise = gtsam.noiseModel.Isotropic.Sigma(6, HELD_BIAS)
    for k in range(problem.n_keyframes):
        held.add(gtsam.PriorFactorPose3(X(k), values.atPose3(X(k)), pose_noise))
        held.add(gtsam.PriorFactorConstantBias(B(k), values.atConstantBias(B(k)), bias_noise))
    try:
        fitted = levenberg_marquardt(held, values, HELD_FIT_ITERATIONS, 1e-5, "batch LM")[0]
    except (FginsError, RuntimeError):
        return math.inf  # a start whose error is not even finite
    error = graph.error(fitted)
    return error if math.isfinite(error) else math.inf


def dead_reckoning_guess(problem: Problem) -> gtsam.Values:
    """IMU prediction reset to GNSS position (and differenced-GNSS velocity) at every fix."""
    align = problem.alignment
    values = gtsam.Values()
    state = gtsam.NavState(gtsam.Rot3(align.rotation), align.position, align.velocity)
    bias = gtsam.imuBias.ConstantBias()
    fd_velocity = _finite_difference_velocity(problem)
    for k in range(problem.n_keyframes):
        if k > 0:
            state = problem.predict(k - 1, state, bias)
            g = int(problem.gnss_at[k])
            if g >= 0:
                velocity = state.velocity()
                if np.all(np.isfinite(fd_velocity[g])):
                    velocity = fd_velocity[g]
                state = gtsam.NavState(state.attitude(), problem.gnss_enu[g], velocity)
        put_pose(values, X(k), state.pose())
        put_vector(values, V(k), state.velocity())
        put_bias(values, B(k), bias)
        problem.insert_extra_values(k, values)
    return values


def _finite_difference_velocity(problem: Problem) -> np.ndarray:
    """GNSS velocity where given, else central differences over neighbours <= 5 s apart."""
    keyed = problem.gnss_at[problem.gnss_at >= 0]
    t = np.full(len(problem.gnss_enu), np.nan)
    t[keyed] = problem.segments.times[problem.gnss_at >= 0]
    enu = problem.gnss_enu
    out = problem.gnss_velocity.copy()
    for g in range(len(enu)):
        if np.all(np.isfinite(out[g])):
            continue
        lo, hi = max(g - 1, 0), min(g + 1, len(enu) - 1)
        if hi > lo and t[hi] - t[lo] <= 5.0:
            out[g] = (enu[hi] - enu[lo]) / (t[hi] - t[lo])
        else:
            out[g] = np.nan
    return out
