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


def slow_error_variance(
    rho: float, scatter: float, solution_variance: float, fix_variance: float
) -> float:
    """The variance (m^2) to add where the residuals of fixes of variance ``fix_variance``
    about a solution of variance ``solution_variance`` correlate at ``rho`` and scatter by
    ``scatter`` of their sigmas (robust whitened RMS); 0 under CORRELATED_RHO. The larger of
    two readings, at most the fixes' own variance: the AR(1) factor (1 + rho) / (1 - rho) on
    the solution's variance (the residuals' correlation is lower than the errors', as the
    solution takes their slow part: 0.86-0.92 for errors of 0.97 at 1 Hz), and the part of
    the fixes' variance the residuals do not show, which the solution followed
    (1 - scatter^2: sigmas too large for white errors scatter little too, hence only with
    the correlation)."""
    if not (np.isfinite(rho) and rho > CORRELATED_RHO):
        return 0.0
    rho = min(rho, RHO_MAX)
    followed = (1.0 - min(scatter, 1.0) ** 2) * fix_variance if np.isfinite(scatter) else 0.0
    target = min(fix_variance, max((1.0 + rho) / (1.0 - rho) * solution_variance, followed))
    return max(target - solution_variance, 0.0)
