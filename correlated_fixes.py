"""Slow GNSS errors: fixes whose errors are correlated from one fix to the next (numpy only).

A receiver's single-point errors (atmosphere, orbits, multipath) change over tens of seconds,
not from fix to fix. Every estimator here weights the fixes as independent, so its
covariance averages their errors over many fixes; a solution that follows slow errors keeps
them in full, and at higher rates the reported sigmas shrink further while the error does
not. (Outside tester, honest 3 m / 5 m receiver sigmas with errors correlated over 10-30 s:
2.1-3.9 m off horizontally at a reported 0.45 m, z 3.5-6.6, at 1 Hz; 4.6 m vertically at
0.28 m at 5 Hz, z 17; nothing said.)

The sign is in the residuals: about a solution that follows slow errors, the fixes'
residuals keep their neighbours' sign (lag-1 autocorrelation 0.8-0.99 in those drives),
while independent errors leave them uncorrelated (-0.3 to 0.15 over white-noise drives of
1-20 Hz, RTK or phone). The estimate is then an average over fewer independent fixes than
it took: the variance of a mean of AR(1) errors is (1 + rho) / (1 - rho) times that of
independent ones. That factor on the solution's own variance where it rests on the fixes, or
the part of the fixes' variance their residuals do not show (the solution took it), whichever
is larger, up to the fixes' own variance (errors that never change cannot be averaged: the
solution is as good as one fix), is what the solution's variance there should be; the
difference is added to every state's position covariance, horizontal and vertical apart, and
said.
"""

from __future__ import annotations

import numpy as np

# Lag-1 autocorrelation of the residuals above which the fixes' errors count as slow (white
# errors gave -0.3 to 0.15; KITTI's OXTS fixes 0.56 horizontally, 0.82 vertically).
CORRELATED_RHO = 0.4
RHO_MAX = 0.98  # the factor's bound (99): beyond it the fixes' own variance bounds it anyway
MIN_PAIRS = 30
CLIP_SIGMAS = 4.0  # residuals beyond this many robust sigmas (outliers) are clipped


def residual_correlation(t: np.ndarray, whitened: np.ndarray) -> tuple[float, float]:
    """Lag-1 autocorrelation of whitened residuals ``whitened`` (n, 3; east, north, up) at
    fix times ``t``, horizontal (east and north pooled) and vertical, over consecutive fixes
    no further apart than 1.5 typical intervals (an outage or a gap is not a lag of one);
    NaN where fewer than MIN_PAIRS pairs. Outliers are clipped at CLIP_SIGMAS robust sigmas
    so a multipath jump does not make the correlation."""
    t = np.asarray(t, dtype=float)
    whitened = np.asarray(whitened, dtype=float)
    if len(t) < MIN_PAIRS + 1:
        return float("nan"), float("nan")
    step = np.diff(t)
    pair = (step > 0) & (step <= 1.5 * float(np.median(step)))
    out = []
    for columns in ([0, 1], [2]):
        x = whitened[:, columns]
        finite = np.all(np.isfinite(x), axis=1)
        use = pair & finite[:-1] & finite[1:]
        if use.sum() < MIN_PAIRS:
            out.append(float("nan"))
            continue
        x = np.where(np.isfinite(x), x, 0.0) - np.median(x[finite], axis=0)
        scale = 1.4826 * float(np.median(np.abs(x[finite]))) or 1.0
        x = np.clip(x, -CLIP_SIGMAS * scale, CLIP_SIGMAS * scale)
        a, b = x[:-1][use], x[1:][use]
        denominator = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
        out.append(float(np.sum(a * b)) / denominator if denominator > 0 else float("nan"))
    return out[0], out[1]


# The variance ratio: the variance of the residuals' means over blocks of BLOCK_S (at least
# MIN_BLOCK_FIXES consecutive fixes) against that of independent ones (1 for white errors,
# (1 + rho) / (1 - rho) for AR(1) ones over long blocks). Lag-1 alone missed slow errors
# under a white part: receiver errors of 0.5 m white plus 1 m correlated over 60 s left
# residuals at lag-1 0.28-0.31 (under CORRELATED_RHO) and a solution 1.2 m off at a reported
# 0.24 m, z 5-6, "0.00 m horizontally" said (outside tester); their ratio is 3-5, white
# errors' 0.6-1.4.
BLOCK_S = 10.0
MIN_BLOCK_FIXES = 5
MIN_BLOCKS = 10
CORRELATED_RATIO = 2.0


def variance_ratio(t: np.ndarray, whitened: np.ndarray) -> tuple[float, float]:
    """The variance ratio (see BLOCK_S) of whitened residuals ``whitened`` (n, 3; east,
    north, up) at fix times ``t``, horizontal (east and north pooled) and vertical, over
    blocks of consecutive fixes no further apart than 1.5 typical intervals; NaN where fewer
    than MIN_BLOCKS blocks. Outliers clipped as in :func:`residual_correlation`."""
    t = np.asarray(t, dtype=float)
    whitened = np.asarray(whitened, dtype=float)
    if len(t) < MIN_BLOCKS * MIN_BLOCK_FIXES:
        return float("nan"), float("nan")
    step = np.diff(t)
    typical = float(np.median(step))
    if not typical > 0:
        return float("nan"), float("nan")
    size = max(MIN_BLOCK_FIXES, round(BLOCK_S / typical))
    # contiguous runs of fixes (an outage or a gap ends one), cut into whole blocks
    run = np.concatenate([[0], np.cumsum(~((step > 0) & (step <= 1.5 * typical)))])
    out = []
    for columns in ([0, 1], [2]):
        x = whitened[:, columns]
        finite = np.all(np.isfinite(x), axis=1)
        if finite.sum() < MIN_BLOCKS * size:
            out.append(float("nan"))
            continue
        x = x - np.median(x[finite], axis=0)
        scale = 1.4826 * float(np.median(np.abs(x[finite]))) or 1.0
        x = np.clip(np.where(finite[:, None], x, 0.0), -CLIP_SIGMAS * scale, CLIP_SIGMAS * scale)
        means = []
        members = np.flatnonzero(finite)  # in time order, so each run's are consecutive
        for group in np.split(members, np.flatnonzero(np.diff(run[members])) + 1):
            whole = len(group) // size * size
            if whole:
                means.append(x[group[:whole]].reshape(-1, size, x.shape[1]).mean(axis=1))
        blocks = np.concatenate(means) if means else np.zeros((0, x.shape[1]))
        if len(blocks) < MIN_BLOCKS:
            out.append(float("nan"))
            continue
        centre = x[finite].mean(axis=0)
        variance = float(np.mean((x[finite] - centre) ** 2))
        block_variance = float(np.mean((blocks - centre) ** 2))
        out.append(size * block_variance / variance if variance > 0 else float("nan"))
    return out[0], out[1]


def slow_error_variance(
    rho: float, scatter: float, solution_variance: float, fix_variance: float,
    ratio: float = float("nan"),
) -> float:
    """The variance (m^2) to add where the residuals of fixes of variance ``fix_variance``
    about a solution of variance ``solution_variance`` correlate at ``rho`` and scatter by
    ``scatter`` of their sigmas (robust whitened RMS); 0 under CORRELATED_RHO. The larger of
    two readings, at most the fixes' own variance: the AR(1) factor (1 + rho) / (1 - rho) on
    the solution's variance (the residuals' correlation is lower than the errors', as the
    solution takes their slow part: 0.86-0.92 for errors of 0.97 at 1 Hz), and the part of
    the fixes' variance the residuals do not show, which the solution followed
    (1 - scatter^2: sigmas too large for white errors scatter little too, hence only with
    the correlation). The variance ``ratio`` (:func:`variance_ratio`) above CORRELATED_RATIO
    counts as correlation too, and as the factor where it is the larger."""
    correlated = np.isfinite(rho) and rho > CORRELATED_RHO
    blocks = np.isfinite(ratio) and ratio > CORRELATED_RATIO
    if not (correlated or blocks):
        return 0.0
    factor = max(
        (1.0 + min(rho, RHO_MAX)) / (1.0 - min(rho, RHO_MAX)) if correlated else 1.0,
        ratio if blocks else 1.0,
    )
    followed = (1.0 - min(scatter, 1.0) ** 2) * fix_variance if np.isfinite(scatter) else 0.0
    target = min(fix_variance, max(factor * solution_variance, followed))
    return max(target - solution_variance, 0.0)
