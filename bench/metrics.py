"""Error metrics of a trajectory against a reference (truth or withheld GNSS)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import Trajectory
from fgins.outages import in_windows


@dataclass
class Errors:
    """Horizontal/vertical errors (m) at reference epochs, split by inside/outside outages."""

    t: np.ndarray
    horizontal: np.ndarray
    vertical: np.ndarray
    inside: np.ndarray
    horizontal_std: np.ndarray
    # Per axis (M, 2): east and north errors and their sigmas (the reference's included
    # against fixes), for the 2-D 3-sigma test.
    east_north: np.ndarray
    east_north_std: np.ndarray

    def inside_3_sigma(self, rows: np.ndarray) -> float:
        """The fraction of ``rows`` (a mask) whose horizontal error lies inside the 3-sigma
        ellipse (2-D chi-square 11.83: 99.73 %, as 3 sigma in one dimension). Not
        |e| <= 3 sqrt(sE^2 + sN^2): that is 4.24 sigmas of an isotropic error, 99.99 %, and
        sigmas 2x too small still scored 89 % (outside tester). NaN without sigmas."""
        if not rows.any():
            return float("nan")
        std = self.east_north_std[rows]
        if not np.all(np.isfinite(std)):
            return float("nan")
        squared = np.sum((self.east_north[rows] / std) ** 2, axis=1)
        return float(np.mean(squared <= CHI2_2D_3_SIGMA))

    def window(self, rows: np.ndarray) -> dict[str, float]:
        """Horizontal RMS, max, error at the end and the 3-sigma share over ``rows``, and
        their horizontal NEES (mean of (e/s)^2 per axis: about 1 where the sigmas are
        honest)."""
        if not rows.any():
            return {}
        return {
            "h_rms": self._rms(self.horizontal[rows]),
            "h_max": float(self.horizontal[rows].max()),
            "h_end": float(self.horizontal[np.flatnonzero(rows)[-1]]),
            "within_3sigma": self.inside_3_sigma(rows),
            "nees_h": float(np.mean((self.east_north[rows] / self.east_north_std[rows]) ** 2)),
        }

    @staticmethod
    def _rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")

    def summary(self) -> dict[str, float]:
        out = {
            "h_rms_outage": self._rms(self.horizontal[self.inside]),
            "h_max_outage": float(self.horizontal[self.inside].max())
            if self.inside.any()
            else float("nan"),
            "v_rms_outage": self._rms(self.vertical[self.inside]),
            "h_rms_aided": self._rms(self.horizontal[~self.inside]),
            "v_rms_aided": self._rms(self.vertical[~self.inside]),
            "h_rms_all": self._rms(self.horizontal),
        }
        # Fraction of outage epochs whose horizontal error is inside the reported 3 sigma.
        within = self.inside_3_sigma(self.inside)
        if np.isfinite(within):
            out["within_3sigma_outage"] = within
        return out


CHI2_2D_3_SIGMA = 11.829  # chi-square, 2 dof, at 99.73 % (3 sigma in one dimension)


def errors_against(
    trajectory: Trajectory,
    reference_t: np.ndarray,
    reference_enu: np.ndarray,
    t0: float,
    windows: list[tuple[float, float]],
    reference_std: np.ndarray | None = None,
) -> Errors:
    """Errors of ``trajectory`` (interpolated) at the reference epochs it spans.
    ``reference_std`` (M, >= 2): the reference's own east/north sigmas (withheld GNSS fixes),
    which the 3-sigma test adds to the trajectory's: against fixes of 5 m sigma an honest
    0.5 m trajectory sigma was "10 % within 3 sigma"."""
    span = (reference_t >= trajectory.t[0]) & (reference_t <= trajectory.t[-1])
    t = reference_t[span]
    estimate = trajectory.at(t)
    difference = estimate - reference_enu[span]
    std = np.column_stack(
        [np.interp(t, trajectory.t, trajectory.position_std[:, i]) for i in range(2)]
    )
    if reference_std is not None:
        std = np.hypot(std, np.asarray(reference_std, dtype=float)[span, :2])
    return Errors(
        t=t,
        horizontal=np.linalg.norm(difference[:, :2], axis=1),
        vertical=np.abs(difference[:, 2]),
        inside=in_windows(t, t0, windows),
        horizontal_std=np.linalg.norm(std, axis=1),
        east_north=difference[:, :2],
        east_north_std=std,
    )


def relative_position_error(
    trajectory: Trajectory,
    reference_t: np.ndarray,
    reference_enu: np.ndarray,
    segment_m: float = 100.0,
) -> float:
    """RMS relative position error (m) over consecutive segments of ``segment_m`` of path.

    Definition (orientation-free, so it works against GNSS fixes as well as truth): the
    reference epochs inside the trajectory's span are cut into consecutive, non-overlapping
    segments; a segment starts where the previous one ended (the first at the first epoch)
    and ends at the first epoch whose reference path length since its start is at least
    ``segment_m``. For a segment (i, j) the error is
    ``|(p_est(t_j) - p_est(t_i)) - (p_ref(t_j) - p_ref(t_i))|`` with the estimate linearly
    interpolated at the reference times; the result is the RMS over segments (NaN if the
    reference path is shorter than one segment). This is evo's RPE (translation part, delta
    in metres, consecutive pairs taken on the reference path) on positions alone, i.e. with
    both orientations set to identity; it differs from evo's default by the attitude error at
    each segment start, which rotates the estimate's displacement.
    """
    span = (reference_t >= trajectory.t[0]) & (reference_t <= trajectory.t[-1])
    t = np.asarray(reference_t)[span]
    ref = np.asarray(reference_enu)[span]
    if t.size < 2:
        return float("nan")
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref, axis=0), axis=1))])
    # Segment ends: one searchsorted per segment (drive length / segment_m of them).
    ends = [0]
    while True:
        nxt = int(np.searchsorted(path, path[ends[-1]] + segment_m, side="left"))
        if nxt >= t.size:
            break
        ends.append(max(nxt, ends[-1] + 1))
    if len(ends) < 2:
        return float("nan")
    ends_index = np.array(ends)
    error = np.diff(trajectory.at(t[ends_index]), axis=0) - np.diff(ref[ends_index], axis=0)
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def used_fixes(trajectory: Trajectory, dataset, config) -> np.ndarray:
    """Bool mask over ``dataset.gnss``: the fixes the run that made ``trajectory`` used.

    Every fix the smoother was given and kept: not withheld by the run's outage windows
    (``info["run"]["gnss_outage"]``), through the gates of ``config.gnss`` (position, IMU
    span, fix quality, PDOP: :func:`fgins.factors.gnss.select_epochs`, as the methods count),
    not thinned to the keyframe spacing (the graph's ``decimated``), and neither left out as a
    fault (``gnss_excluded_times``, batch and iSAM2) nor rejected by a filter's innovation
    gate (``rejected_times``). Those last are matched to the nearest fix (a run that moved
    the fixes' times reports them moved, by well under half the fix spacing)."""
    from fgins.factors.gnss import select_epochs
    from fgins.outages import outage_mask

    gnss_t = np.asarray(dataset.gnss.t, dtype=float)
    run = trajectory.info.get("run")
    windows = list(run.get("gnss_outage", [])) if isinstance(run, dict) else []
    used, _ = select_epochs(dataset, config.gnss, outage_mask(dataset, windows))
    used = used.copy()
    counts = trajectory.info.get("gnss_counts")
    if isinstance(counts, dict) and counts.get("decimated"):
        # The graph keeps a fix only at least min_keyframe_interval_s after the last kept one.
        interval = config.smoother.min_keyframe_interval_s
        last = -np.inf
        for i in np.flatnonzero(used):
            if gnss_t[i] - last >= interval - 1e-9:
                last = gnss_t[i]
            else:
                used[i] = False
    left_out = [
        float(t)
        for key in ("gnss_excluded_times", "rejected_times")
        for t in (trajectory.info.get(key) or [])
    ]
    if left_out and used.any():
        candidates = np.flatnonzero(used)
        for t in left_out:
            used[candidates[np.argmin(np.abs(gnss_t[candidates] - t))]] = False
    return used


def h_rms_at_used_fixes(trajectory: Trajectory, dataset, config) -> float:
    """Horizontal RMS (m) of ``trajectory`` at the fixes its run used (:func:`used_fixes`),
    against those fixes: the aided fit, with no gated or faulty fix in it."""
    used = used_fixes(trajectory, dataset, config)
    errors = errors_against(trajectory, dataset.gnss.t[used], dataset.gnss_enu()[used], dataset.t0, [])
    return errors.summary()["h_rms_aided"]
