"""How far the GNSS fixes scatter about a solution against their own sigmas (numpy only):
one check for the factor graph's summary and the Kalman baselines' fit note."""

from __future__ import annotations

import numpy as np

# Fixes scattering this many times their own sigma (robust whitened RMS) about the solution;
# a height scale this many times the horizontal one points at the heights alone.
SIGMA_TOO_SMALL = 2.0
SIGMA_AXIS_RATIO = 1.5
MIN_FIXES = 30


def robust_scale(whitened: np.ndarray) -> float:
    """1.4826 x the median absolute whitened residual: the RMS of unit normal errors, which a
    few outliers do not move."""
    return float(1.4826 * np.median(np.abs(whitened)))


def gnss_scatter(whitened: np.ndarray, method: str = "") -> dict[str, object]:
    """How far the fixes scatter about the solution against their own sigmas, horizontally
    and vertically (robust: 1.4826 x the median absolute whitened residual, so a few outliers
    do not count; ~0.7-1 when the sigmas are right, as the fit follows the fixes a little).

    The overall chi-square, diluted by the IMU's many factors, hid fixes whose heights were
    in feet (3.3x their vertical sigma: chi2/dof 2.6, no word) or whose sigmas were a few
    times too small; every reported uncertainty then comes out that much too small."""
    whitened = whitened[np.all(np.isfinite(whitened), axis=1)]
    if len(whitened) < MIN_FIXES:
        return {}
    who = f"{method}: " if method else ""
    horizontal, vertical = robust_scale(whitened[:, :2]), robust_scale(whitened[:, 2])
    out: dict[str, object] = {
        "gnss_whitened_scale_horizontal": horizontal, "gnss_whitened_scale_vertical": vertical,
    }  # fmt: skip
    if vertical > SIGMA_TOO_SMALL and vertical > SIGMA_AXIS_RATIO * horizontal and method == "planar-kf":
        # Its height is a random walk between fixes: a climbing vehicle's heights are not in
        # its model (fgins's own simulated aircraft had "an altitude in feet, two datums
        # mixed" said of its right heights; outside tester).
        out["fit_warnings"] = [
            f"{who}GNSS: the fixes' heights scatter {vertical:.1f}x their vertical sigma about its "
            f"solution (horizontally {horizontal:.1f}x; robust whitened RMS, ~1 expected): the "
            "planar filter holds its height between fixes, and the vehicle climbs or descends "
            "faster than that model allows (or the heights are in feet, or of two datums); its "
            "vertical uncertainty is that much too small: --method batch or ekf model the height"
        ]
    elif vertical > SIGMA_TOO_SMALL and vertical > SIGMA_AXIS_RATIO * horizontal:
        out["fit_warnings"] = [
            f"{who}GNSS: the fixes' heights scatter {vertical:.1f}x their vertical sigma about the "
            f"solution (horizontally {horizontal:.1f}x; robust whitened RMS, ~1 expected): an "
            "altitude in feet (3.3x), heights of two datums mixed (ellipsoid and mean sea "
            "level), or a vertical sigma (VDOP, std_up) too small; the vertical uncertainty "
            "reported is that much too small"
        ]
    elif max(horizontal, vertical) > SIGMA_TOO_SMALL:
        out["fit_warnings"] = [
            f"{who}GNSS: the fixes scatter {horizontal:.1f}x their horizontal and {vertical:.1f}x "
            "their vertical sigma about the solution (robust whitened RMS, ~1 expected): the "
            "sigmas (std columns, GST, covariance, [gnss] sigma_m or UERE x DOP) are too small "
            "for this receiver, or the method's model (the IMU noise set too small; a planar "
            "filter on a vehicle that banks or climbs) holds the track too stiff; the reported "
            "uncertainties are about that much too small"
        ]
    return out


def velocity_scatter(whitened: np.ndarray) -> dict[str, object]:
    """How far the fixes' velocities scatter about the solution against their own sigmas
    (robust, as :func:`gnss_scatter`; ``whitened`` (n, 3), NaN where a velocity has no
    vertical). Velocity sigmas come from the data, ``[gnss] velocity_sigma_m_per_s`` or
    0.1 m/s x HDOP: a receiver in a city scatters its Doppler velocities by 0.3-1 m/s, and
    taken at 0.2 they held the track 2.5-5 times too stiff (an urban car: 2.2-4.2 m inside
    outages against 1.0-1.1 m with the right sigma, its sigmas 2.5-5 times too small;
    chi2/dof 2.2 said nothing)."""
    horizontal_rows = whitened[np.all(np.isfinite(whitened[:, :2]), axis=1), :2]
    if len(horizontal_rows) < MIN_FIXES:
        return {}
    horizontal = robust_scale(horizontal_rows)
    up = whitened[:, 2][np.isfinite(whitened[:, 2])]
    vertical = robust_scale(up) if len(up) >= MIN_FIXES else float("nan")
    out: dict[str, object] = {
        "gnss_velocity_whitened_scale_horizontal": horizontal,
        "gnss_velocity_whitened_scale_vertical": vertical,
    }
    if np.nanmax([horizontal, vertical]) > SIGMA_TOO_SMALL:
        shown = f"{horizontal:.1f}x horizontally" + (
            f" and {vertical:.1f}x vertically" if np.isfinite(vertical) else ""
        )
        out["fit_warnings"] = [
            f"GNSS: the fixes' velocities scatter {shown} their sigma about the solution "
            "(robust whitened RMS, ~1 expected): the velocity sigmas (velocity std columns, "
            "[gnss] velocity_sigma_m_per_s, or 0.1 m/s x HDOP without either) are too small "
            "for this receiver; the track is held too stiff and its reported uncertainties "
            "are too small"
        ]
    return out

