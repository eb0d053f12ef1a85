"""Batch smoothing: Levenberg-Marquardt over the whole drive from the best start, restarts
from the other candidates when a fit cannot be trusted, stops decided on a first solution,
covariances from the marginals.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import gtsam
import numpy as np

from fgins.datatypes import FginsError, Trajectory
from fgins.graph.gnss_faults import exclude_gnss_faults, with_every_fix
from fgins.graph.gyro_scale import add_scale_spread, correct_gyro_scale
from fgins.graph.isam2 import run_isam2
from fgins.graph.problem import Problem
from fgins.graph.reports import (
    extra_states,
    gnss_report,
    lever_arm_report,
    merge_info,
    solver_report,
    vehicle_fit_report,
)
from fgins.graph.solution import (
    covariance_report,
    marginal_covariances,
    marginal_function,
    states_from_values,
    to_trajectory,
)
from fgins.graph.solve import (
    NotConvergedError,
    SolveReport,
    callback_factors,
    fail_if_diverged,
    finish_report,
    full_graph,
    is_suspect,
    nonlinear_graph,
    solve_from,
    solve_with_stops,
)
from fgins.graph.start import InitialGuess, Start, dead_reckoning_guess, initial_values


def _fall_back(
    problem: Problem,
    source: str,
    others: list[Start],
    report: SolveReport,
    result: gtsam.Values,
    graph: gtsam.NonlinearFactorGraph,
    second_opinion: bool = False,
) -> tuple[SolveReport, gtsam.Values, gtsam.NonlinearFactorGraph]:
    """The first start led LM to an unconverged or inconsistent fit (e.g. the filter
    diverged in an outage, or with sparse GNSS): try the other candidate guesses, then
    GNSS-reset dead reckoning, then iSAM2 (whose incremental relinearisation follows a poor
    start far better), and keep the first consistent fit, else the one with the least error.
    Says which it took. ``second_opinion``: the first fit converged but fits only fairly
    (chi2/dof above CHI2_SECOND_OPINION): iSAM2's start alone, kept where it fits better."""
    first = report

    def dead_reckoning() -> gtsam.Values:
        zeros = np.zeros((problem.n_keyframes, 3))
        problem.preintegrate_all(zeros, zeros, False)
        return dead_reckoning_guess(problem)

    def isam2() -> gtsam.Values:
        return run_isam2(problem, False, online_covariance=False, relinearize_skip=1)[1]

    best = (report, result, graph, source)
    tried_iterations = tried_rounds = 0  # every restart's: the work done is said in full
    restarts: list[tuple[str, Callable[[], gtsam.Values]]] = [
        (other.source, lambda other=other: other.take(problem)) for other in others
    ]
    restarts += [("dead reckoning", dead_reckoning), ("iSAM2", isam2)]
    if second_opinion:
        restarts = restarts[-1:]
    for name, start in restarts:
        if name == source:
            continue
        problem.restart()  # gravity and stops as the fixes give them, not the last solve
        try:
            candidate = (*solve_from(problem, start()), name)
        except FginsError:
            continue  # this start cannot even be computed: try the next
        tried_iterations += candidate[0].iterations
        tried_rounds += candidate[0].rounds
        # A second opinion that did not converge is no opinion: the first fit stays.
        if candidate[0].final_error < best[0].final_error and not (
            second_opinion and is_suspect(candidate[0])
        ):
            best = candidate
        if not is_suspect(candidate[0]):
            break
    report, result, graph, taken = best
    problem.preintegrate_about(result)  # the kept solution's, not the last start's
    if taken != source:
        report.initial_error = first.initial_error
        report.iterations = first.iterations + tried_iterations
        report.rounds = first.rounds + tried_rounds
        report.fallback = (
            f"the {source} initial guess gave a fit of chi2/dof {first.chi2_per_dof:.2f}; the "
            "iSAM2 start fits better: taken"
            if second_opinion
            else f"the {source} initial guess gave an unconverged or inconsistent fit (chi2/dof "
            f"{first.chi2_per_dof:.2f}); restarted from {taken}"
        )
        graph = full_graph(problem, nonlinear_graph(problem, None), result)
        finish_report(report, graph, result)
    return report, result, graph


# Above this chi2/dof a converged first fit gets a second opinion from the iSAM2 start (see
# smooth_batch): a fit of consistent noise models sits at 0.1-1.3.
CHI2_SECOND_OPINION = 1.5


def smooth_batch(
    problem: Problem, progress: bool = True, initial_guess: InitialGuess | None = None
) -> Trajectory:
    """Levenberg-Marquardt over the whole drive, covariances from the marginals.

    With ZUPT on, two passes: the first solves without zero-velocity factors; stops are then
    the quiet-IMU keyframes where that solution's speed is low, and the second pass adds
    their ZUPTs. Deciding stops from the initial guess instead would let a guess that is
    wrong in an outage plant a false stop, which no optimiser recovers from.
    """
    started = time.perf_counter()
    start, others = initial_values(problem, initial_guess, progress)
    source = start.source
    report, result, graph = solve_from(problem, start.values)
    if is_suspect(report):
        report, result, graph = _fall_back(problem, source, others, report, result, graph)
    elif report.chi2_per_dof > CHI2_SECOND_OPINION:
        # A fair fit may still be a wrong basin: a walker's phone-grade IMU, its heading
        # swept through 360 deg at chi2/dof 2.2, 12.8 m inside an outage at 4.7 times the
        # sigmas, where iSAM2's start, relinearised as it goes, found chi2/dof 1.2 and
        # 1.5 m (outside tester). The better fit is kept.
        report, result, graph = _fall_back(
            problem, source, others, report, result, graph, second_opinion=True
        )
    report.start = source  # a restart says so in report.fallback
    report, result, graph = solve_with_stops(problem, report, result, graph)
    scale_info: dict[str, object] = {}
    spread = None
    if report.converged:  # a fit that is poor may be poor for the scale (chi2/dof 10 on an
        # aircraft with a gyro 1 % large and 0.1 m/s velocities; 0.56 corrected)
        result, graph, scale_info, spread = correct_gyro_scale(problem, report, result, graph)
    # Faults last: a model error the steps above correct (a gyro scale) is no fault of the
    # fixes (a 3 % scale put one fix beyond 4 sigma before its correction); the stops found
    # stay (fgins.graph.gnss_faults).
    before = (graph, result)
    result, graph, faults = exclude_gnss_faults(problem, report, result, graph)
    fail_if_diverged(report)
    if not report.converged:
        raise NotConvergedError(
            f"batch: Levenberg-Marquardt did not converge ({report.iterations} iterations in "
            f"{report.rounds} rounds, error {report.initial_error:.4g} -> "
            f"{report.final_error:.4g}); no output written. Try --method isam2, or check the "
            "IMU noise settings"
        )
    solved = time.perf_counter()
    marginal = marginal_function(graph, result)
    covariances = marginal_covariances(problem, marginal, marginal, result, progress)
    add_scale_spread(covariances, spread)
    states = states_from_values(problem, result, covariances)
    trajectory = to_trajectory(problem, states, "batch", smoothed=True)
    trajectory.timings.update(
        {"optimize": solved - started, "covariance": time.perf_counter() - solved}
    )
    merge_info(
        trajectory,
        gnss_report(problem, result),
        with_every_fix(problem, faults, lambda: lever_arm_report(problem, *before)),
        extra_states(problem, result, marginal),
        solver_report(report),
        vehicle_fit_report(problem, result),
        covariance_report(covariances),
        scale_info,
        faults.info(len(problem.gnss_used)),
        {
            "initial_guess": source,
            "zupt_keyframes": len(problem.zupt_keyframes),
            "restarted_from_isam2": report.fallback is not None,
            "python_callback_factors": callback_factors(graph),
        },
    )
    return trajectory
