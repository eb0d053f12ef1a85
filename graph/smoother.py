"""Batch (Levenberg-Marquardt) and incremental (iSAM2) smoothing of a dataset.

Entry point: :func:`smooth`. Both methods share the same problem (keyframes, factors,
priors; :mod:`fgins.graph.problem`) and solve (:mod:`fgins.graph.solve`); they live in
:mod:`fgins.graph.batch` (from the start of :mod:`fgins.graph.start`) and
:mod:`fgins.graph.isam2`, which also yields the online estimate: each keyframe's state as it
was right after its own update, i.e. what a real-time system would have had. Their output
and summary come from :mod:`fgins.graph.solution` and :mod:`fgins.graph.reports`.

Every factor the optimiser evaluates runs in C++: the land-vehicle constraints, which GTSAM
has no factor for, enter as factors linearised at an estimate and rebuilt in an outer loop
(:mod:`fgins.factors.vehicle`), so one linearisation costs O(K), not O(K^2).

Honesty: every solve checks that its error is finite, that it made progress and converged,
and how consistent the fit is (chi-square per degree of freedom); the result says which
solver produced it, how, and any fallback taken. A solve that cannot be trusted is an error,
never an initial guess under the method's name.
"""

from __future__ import annotations

import time

import numpy as np

from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory
from fgins.graph.batch import smooth_batch
from fgins.graph.isam2 import DeferredTrajectory, smooth_isam2
from fgins.graph.problem import build_problem
from fgins.graph.start import InitialGuess, initial_values

__all__ = [
    "DeferredTrajectory",
    "InitialGuess",
    "initial_values",
    "smooth",
    "smooth_batch",
    "smooth_isam2",
]


def smooth(
    dataset: Dataset,
    config: RunConfig,
    method: str = "batch",
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    initial_guess: InitialGuess | None = None,
) -> Trajectory:
    """Smooth ``dataset`` with ``method`` ('batch', 'isam2' or 'isam2-online').

    ``initial_guess``: keyframe times -> states there, e.g. a Kalman filter's; the pipeline
    chooses the filter that matches the input. The batch starts from it; iSAM2 solves from
    it only where its own final estimate does not fit.
    """
    started = time.perf_counter()
    problem = build_problem(dataset, config, gnss_mask, progress=progress)
    built = time.perf_counter()
    if method == "batch":
        trajectory = smooth_batch(problem, progress, initial_guess)
    elif method in ("isam2", "isam2-online"):
        trajectory, other = smooth_isam2(
            problem, progress, online_first=method == "isam2-online", initial_guess=initial_guess
        )
        if other is not None:  # None: the online pass failed (said in the summary)
            trajectory.info["online"] = other
            if method == "isam2-online":
                _antenna_readings_of(other, trajectory)
            else:  # the online estimate it carries says what it would alone
                _antenna_readings_of(trajectory, other)
    else:
        raise FginsError(f"unknown factor-graph method {method!r}")
    trajectory.timings["build"] = built - started
    trajectory.timings["total"] = time.perf_counter() - started
    return trajectory


# What the GNSS time and lever-arm checks read, in the final solution's info.
_ANTENNA_KEYS = ("gnss_time", "gnss_lever_arm", "gnss_velocity_lag", "antenna_findings")


def _antenna_readings_of(final: Trajectory, online: Trajectory) -> None:
    """The final solution's GNSS time and lever-arm readings (and its fit, which decides a
    correction) given to the online estimate of the same run, in place: the online pass
    has no such check of its own, so fixes 0.2 s late or an arm of the wrong sign went
    through ``--online`` unsaid and uncorrected, 2.4 m off at the fixes at z 3.3 (outside
    tester), where the same run's final estimate and the forward EKF corrected them."""
    for key, value in final.info.items():
        if key not in online.info and (key.startswith(_ANTENNA_KEYS) or key in ("chi2_per_dof", "dof")):
            online.info[key] = value
    said = [w for w in final.info.get("fit_warnings", []) if w.startswith(("GNSS lever arm", "GNSS time"))]
    if said:
        online.info["fit_warnings"] = [*online.info.get("fit_warnings", []), *said]

