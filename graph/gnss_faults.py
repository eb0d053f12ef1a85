"""GNSS fault exclusion: the fixes a robust solution cannot explain are taken out, the drive
solved again, and each one tested against that solution before it stays out.

The default Huber kernel bounds the pull of one multipath fix, but not of a run of them: in
an urban canyon a receiver tracking reflections gives ten or twenty fixes in a row 15-30 m
off, each consistent with its neighbours. On the urban car (consumer IMU, 2.7 m fixes) ten
fixes 20 m off pulled batch, iSAM2 and EKF+RTS alike 4.9 m off (2.9 m over the whole drive
against 0.64 clean) while every reported sigma stayed 0.6 m; a redescending kernel from the
start (Cauchy at 3 sigma) still left 2.3 m and cost the clean drives 5-10 %.

So, after the robust solve (:func:`exclude_gnss_faults`):

1. candidates: the used fixes whose whitened residual norm exceeds :data:`FAULT_SIGMA` (5:
   one Gaussian fix in 67,000);
2. their positions are taken out of the graph (:meth:`Problem.exclude_gnss`; their
   velocities stay, under their own kernel) and the drive solved again from the robust
   solution;
3. each one out is tested against the new solution with its uncertainty: the normalised
   innovation ``|d| = sqrt(d' (R + J P J') d)`` (``R`` the fix's covariance, ``P`` the
   solved pose's marginal, ``J`` the antenna's position in the pose) comes back in within
   :data:`FAULT_SIGMA`; a used fix now beyond it goes out; until the set settles.

A fix stays out only where the solution without it, that solution's uncertainty included,
still cannot reach it: a fix pulled off by its faulty neighbours comes back; one beside a long
exclusion is judged against a dead-reckoned, uncertain solution and comes back too. Where
more than :data:`MAX_FAULT_FRACTION` of the fixes are candidates, the fixes are not faulty,
their sigmas are too small (the GNSS report says so): nothing is excluded; where the rounds
grow the set beyond that fraction, the solution is wrong, not the fixes: nothing either. Without a robust
kernel (``--robust none``, every fix at full weight) or with ``[gnss] fault_exclusion =
false``, nothing either. Cost: nothing on a drive without large residuals, one solve per
round (at most :data:`MAX_ROUNDS`) otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from fgins.graph.problem import Problem
from fgins.graph.solution import marginal_function
from fgins.graph.solve import SolveReport, degrees_of_freedom, finish_report, solve_in_rounds

# Beyond 5 sigma: one Gaussian fix in 67,000 (chi, 3 dof), where 4.03 (the large-residual
# report's 99.9 %) left out one in a thousand, enough to move a 10 Hz drive's outage by 9 %.
FAULT_SIGMA = 5.0
MAX_FAULT_FRACTION = 0.25
MAX_ROUNDS = 4
# Fixes that must stay in the graph whatever the test says (two anchor position and heading).
MIN_KEPT_FIXES = 2


@dataclass
class FaultExclusion:
    """What the exclusion did: the fixes left out (keyframes, times), the rounds solved, and
    why it did nothing where it did nothing."""

    keyframes: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    rounds: int = 0
    note: str | None = None
    warning: str | None = None  # the solution does not fit its fixes: said as a warning
    t0: float = 0.0  # the first GNSS epoch's time, which the summary counts from

    def info(self, used: int) -> dict[str, object]:
        """The run summary's keys (``used``: the fixes still in the graph)."""
        if not self.keyframes and self.note is None:
            return {}
        out: dict[str, object] = {
            "gnss_excluded_times": list(self.times),
            "gnss_excluded_count": len(self.keyframes),
        }
        if self.keyframes:
            listed = ", ".join(f"{t - self.t0:.1f}" for t in self.times[:20]) + (
                " ..." if len(self.times) > 20 else ""
            )
            out["gnss_excluded"] = (
                f"GNSS fault exclusion: {len(self.keyframes)} of {used + len(self.keyframes)} "
                f"fixes left out: the solution without them, its uncertainty included, stays "
                f"more than {FAULT_SIGMA:g} sigma from each ({self.rounds} solve(s) more; "
                f"multipath or a receiver fault; [gnss] fault_exclusion = false keeps them at "
                f"the kernel's weight): t - t0 = {listed}"
            )
        if self.note:
            out["gnss_excluded"] = self.note
        if self.warning:
            out["fit_warnings"] = [self.warning]
        return out


def exclude_gnss_faults(
    problem: Problem,
    report: SolveReport,
    result: gtsam.Values,
    graph: gtsam.NonlinearFactorGraph,
    speeds: np.ndarray | None = None,
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph, FaultExclusion]:
    """The solution with the GNSS faults left out (see the module docstring), its graph, and
    what was left out. ``report`` takes the rounds' iterations and the final fit; ``speeds``
    are the stops' (:func:`fgins.graph.solve.stop_speeds`); by default the stops the solution
    has (``problem.zupt_keyframes``) stay."""
    outcome = FaultExclusion()
    if speeds is None and problem.zupt_keyframes:  # the stops decided stay stops
        stops = np.isin(np.arange(problem.n_keyframes), sorted(problem.zupt_keyframes))
        speeds = np.where(stops, 0.0, np.inf)
    gnss = problem.config.gnss
    if not gnss.fault_exclusion or (gnss.huber_k is None and gnss.cauchy_k is None):
        return result, graph, outcome
    keyframes = problem.position_keyframes
    _, whitened = problem.gnss_whitened_residuals(result)
    candidates = set(keyframes[np.linalg.norm(whitened, axis=1) > FAULT_SIGMA].tolist())
    if not candidates:
        return result, graph, outcome
    if len(candidates) > MAX_FAULT_FRACTION * len(keyframes):
        outcome.note = (
            f"GNSS fault exclusion: none; {len(candidates)} of {len(keyframes)} fixes lie beyond "
            f"{FAULT_SIGMA:g} sigma, too many to be faults: their sigmas are too small, or the "
            "solution is wrong"
        )
        outcome.warning = (
            f"GNSS: the solution misses {len(candidates)} of its {len(keyframes)} fixes by more "
            f"than {FAULT_SIGMA:g} sigma: their sigmas are too small for this receiver, or the "
            "solution is wrong (fixes too sparse for this IMU to bridge, its biases or noise "
            "set too small, the clocks offset: --time-offset); its sigmas are not to be trusted"
        )
        return result, graph, outcome
    excluded, best, _ = _settle(problem, report, outcome, candidates, (result, graph), speeds, keyframes)
    enclosed = _enclosed(excluded, keyframes)
    if excluded and enclosed and outcome.note is None:
        # A run of consistent faulty fixes (an RTK fix on the wrong integers for 15-30 s,
        # 0.5 m off at 1.5 cm sigmas) pulls the robust solution onto itself: the fixes beyond
        # 5 sigma are then the good ones on its ramps, left out as faults, and the fault
        # itself stays in, the track on it at z 50 (outside tester). The other reading,
        # the stretch between the runs out with them, settled the same way; the one that
        # fits its data better, at a cost for each run it leaves out, is kept.
        other = FaultExclusion()
        alternative, alternative_best, settled = _settle(
            problem, report, other, excluded | enclosed, best, speeds, keyframes
        )
        values, alternative_graph = alternative_best
        if (
            alternative
            and settled
            and other.note is None
            and 2.0 * alternative_graph.error(values) / max(degrees_of_freedom(alternative_graph, values), 1)
            <= ALTERNATIVE_CHI2_MAX
            and _cost(alternative_graph, values, alternative, keyframes)
            < _cost(best[1], best[0], excluded, keyframes)
        ):
            excluded, best = alternative, alternative_best
        outcome.rounds += other.rounds
    problem.exclude_gnss(excluded)
    if not excluded:
        return result, graph, outcome
    values, graph = best
    finish_report(report, graph, values)
    outcome.keyframes = sorted(excluded)
    outcome.times = [float(problem.segments.times[k]) for k in outcome.keyframes]
    outcome.t0 = float(problem.dataset.t0)
    return values, graph, outcome


def _settle(
    problem: Problem,
    report: SolveReport,
    outcome: FaultExclusion,
    proposal: set[int],
    start: tuple[gtsam.Values, gtsam.NonlinearFactorGraph],
    speeds: np.ndarray | None,
    keyframes: np.ndarray,
) -> tuple[set[int], tuple[gtsam.Values, gtsam.NonlinearFactorGraph], bool]:
    """The fixes left out once the tests settle, from ``proposal`` and the solution
    ``start``, the last solution that converged (``start`` when none), and whether the
    tests settled (no fix back in, none more out)."""
    excluded: set[int] = set()
    seen: list[frozenset[int]] = []
    best = start
    settled = False
    while outcome.rounds < MAX_ROUNDS:
        proposal = _keep_enough(proposal, keyframes)
        if frozenset(proposal) in seen or not proposal:
            break
        seen.append(frozenset(proposal))
        problem.exclude_gnss(proposal)
        trial = SolveReport(solver=report.solver)
        values, trial_graph = solve_in_rounds(problem, best[0], speeds, trial)
        outcome.rounds += 1
        report.iterations += trial.iterations
        report.rounds += trial.rounds
        report.repreintegrated += trial.repreintegrated
        if not trial.converged:
            break  # keep the last solution that converged
        excluded, best = set(proposal), (values, trial_graph)
        innovation = _normalised_innovations(problem, trial_graph, values, sorted(excluded))
        back = {k for k, norm in innovation.items() if norm <= FAULT_SIGMA}
        used = problem.position_keyframes
        _, now = problem.gnss_whitened_residuals(values)
        out = set(used[np.linalg.norm(now, axis=1) > FAULT_SIGMA].tolist())
        if not back and not out:
            settled = True
            break
        proposal = (excluded - back) | out
        if len(proposal) > MAX_FAULT_FRACTION * len(keyframes):
            # Each round leaves more out: the solution, not the fixes, is wrong (a car that
            # reversed for its first 200 m started with its heading turned round: 67 of 141
            # fixes went out, the fit stayed at chi2/dof 4.4). Nothing is left out.
            outcome.note = (
                f"GNSS fault exclusion: none; leaving fixes out put ever more beyond "
                f"{FAULT_SIGMA:g} sigma ({len(proposal)} of {len(keyframes)}): the solution, "
                "not the fixes, is at fault"
            )
            excluded = set()
            break
    return excluded, best, settled


# The other reading is taken only where its fit is consistent (a car started with its heading
# turned round fitted at chi2/dof 4.4 whichever fixes went out, and the other reading left
# 29 of 125 out under a wrong solution).
ALTERNATIVE_CHI2_MAX = 1.5
# What leaving out one run of consecutive fixes costs in a comparison of two readings (in
# GTSAM's error, half the chi-square): an offset of its own, three numbers at the Akaike
# rate of 2 each.
RUN_COST = 3.0


def _runs(excluded: set[int], keyframes: np.ndarray) -> list[list[int]]:
    """The runs of consecutive fixes (in ``keyframes`` order) among ``excluded``: indices."""
    inside = np.isin(keyframes, sorted(excluded))
    runs: list[list[int]] = []
    for i in np.flatnonzero(inside):
        if runs and runs[-1][-1] == i - 1:
            runs[-1].append(int(i))
        else:
            runs.append([int(i)])
    return runs


def _enclosed(excluded: set[int], keyframes: np.ndarray) -> set[int]:
    """The fixes between two runs of ``excluded`` (keyframes), where the whole would still
    be a fault's share (MAX_FAULT_FRACTION)."""
    runs = _runs(excluded, keyframes)
    between = {int(keyframes[i]) for a, b in pairwise(runs) for i in range(a[-1] + 1, b[0])}
    if len(between | excluded) > MAX_FAULT_FRACTION * len(keyframes):
        return set()
    return between


def _cost(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, excluded: set[int], keyframes: np.ndarray) -> float:
    """A reading's cost: its graph's error (the kept fixes and every other factor) plus
    RUN_COST for each run of fixes it leaves out."""
    return float(graph.error(values)) + RUN_COST * len(_runs(excluded, keyframes))


def _keep_enough(proposal: set[int], keyframes: np.ndarray) -> set[int]:
    """``proposal`` less its last members where it would leave fewer than MIN_KEPT_FIXES."""
    room = max(len(keyframes) - MIN_KEPT_FIXES, 0)
    return set(sorted(proposal)[:room])


def _normalised_innovations(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keyframes: list[int]
) -> dict[int, float]:
    """Each excluded fix's distance from the solution in sigmas of the fix and of the
    solution together (the antenna's position: pose marginal through the lever arm)."""
    marginal: Callable[[int], np.ndarray] = marginal_function(graph, values)
    lever = np.asarray(problem.config.gnss.lever_arm_m, dtype=float)
    skew = np.array(
        [[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]]
    )
    out: dict[int, float] = {}
    for k in keyframes:
        g = int(problem.gnss_at[k])
        pose = values.atPose3(X(k))
        rotation = pose.rotation().matrix()
        difference = pose.translation() + rotation @ lever - problem.gnss_enu[g]
        # GTSAM's pose tangent is (rotation, translation) in the body frame: the antenna
        # moves by R (dt - [l]x dtheta).
        jacobian = rotation @ np.hstack([-skew, np.eye(3)])
        covariance = np.diag(problem.gnss_sigma[g] ** 2) + jacobian @ marginal(X(k)) @ jacobian.T
        try:
            out[k] = float(np.sqrt(difference @ np.linalg.solve(covariance, difference)))
        except np.linalg.LinAlgError:
            out[k] = np.inf
        if not np.isfinite(out[k]):  # no marginal (NaN): judged by the fix's sigma alone
            out[k] = float(np.linalg.norm(difference / problem.gnss_sigma[g]))
    return out


def with_every_fix(problem: Problem, faults: FaultExclusion, read: Callable[[], dict]) -> dict:
    """``read()`` with the positions left out put back in the problem. The readings of the
    model (the antenna's arm, the clocks: fgins.graph.reports.lever_arm_report) take every
    fix at the solution before the exclusion, as the Kalman baselines do: a model error
    shows most where it would be taken for a fault (fixes 0.5 s late on a banking aircraft:
    the turns' fixes left out, the latency read as 0.446 s instead of 0.482, and 1.28 m
    inside the outage instead of 0.43)."""
    if not faults.keyframes:
        return read()
    problem.exclude_gnss(set())
    try:
        return read()
    finally:
        problem.exclude_gnss(faults.keyframes)
