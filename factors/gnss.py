"""GNSS measurement model: per-epoch sigmas (data, GST, UERE x DOP), gating, GTSAM factors.

The numpy half (:func:`position_sigmas`, :func:`velocity_sigmas`, :func:`gate_epochs`) is the
one GNSS noise model of the project: the factor graph and every Kalman baseline call it, so a
comparison isolates the estimator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.config import GnssConfig
from fgins.datatypes import FROZEN_DROPPED_KEY, Dataset, GnssData, InputError
from fgins.geodesy import skew, skew_batch

# NMEA GGA fix-quality codes -> UERE table key (9: SBAS-corrected, NovAtel's WAAS code).
QUALITY_UERE_KEY = {1: "autonomous", 2: "dgps", 9: "dgps", 4: "rtk_fixed", 5: "rtk_float"}
# GGA codes that are no GNSS measurement: 6 dead reckoning (the receiver's own extrapolation),
# 7 manual input, 8 simulator mode. Gated whatever min_fix_quality says, counted "by fix
# quality" (an outside tester's quality-8 logs went in as 60 real fixes).
NOT_MEASURED_QUALITIES = {6: "dead reckoning", 7: "manual input", 8: "simulator"}


def _positive(values: np.ndarray) -> np.ndarray:
    """``values`` with every entry that is not a finite number > 0 set to NaN (missing)."""
    values = np.asarray(values, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(values) & (values > 0), values, np.nan)


def position_sigmas(gnss: GnssData, config: GnssConfig) -> np.ndarray:
    """1-sigma east/north/up position error per epoch (M, 3).

    Priority: a constant configured ``sigma_m``; the data's own sigmas (covariance, GST);
    UERE x HDOP horizontally and UERE x VDOP vertically (PDOP when VDOP is absent; HDOP
    alone: vertical = 1.5 x horizontal, the usual geometry ratio); ``default_sigma_m``.
    """
    n = len(gnss)
    if config.sigma_m is not None:
        return np.tile(np.asarray(config.sigma_m, dtype=float), (n, 1))
    sigma = np.tile(np.asarray(config.default_sigma_m, dtype=float), (n, 1))
    uere = np.array(
        [
            config.uere_m.get(
                QUALITY_UERE_KEY.get(int(q), "autonomous"), config.uere_m["autonomous"]
            )
            for q in gnss.fix_quality
        ]
    )
    # A DOP or sigma <= 0 is corrupt, not "very precise": treated as missing, so it can never
    # be floored to min_sigma_m and turn a bad fix into the most trusted one.
    hdop, vdop, pdop = (_positive(x) for x in (gnss.hdop, gnss.vdop, gnss.pdop))
    has_h = np.isfinite(hdop)
    # The low-cost UAV study's convention, per axis: sigma_E = sigma_N = UERE x HDOP. (Strictly
    # HDOP bounds sqrt(sE^2 + sN^2), so this is conservative by sqrt(2); receivers' HDOP
    # underestimates multipath, which that margin absorbs.)
    sigma[has_h, 0] = sigma[has_h, 1] = uere[has_h] * hdop[has_h]
    vertical_dop = np.where(np.isfinite(vdop), vdop, pdop)
    vertical_dop = np.where(np.isfinite(vertical_dop), vertical_dop, 1.5 * hdop)
    has_v = np.isfinite(vertical_dop)
    sigma[has_v, 2] = uere[has_v] * vertical_dop[has_v]
    data_sigma = _positive(gnss.std)
    has_data = np.isfinite(data_sigma)
    sigma[has_data] = data_sigma[has_data]
    return np.maximum(sigma, config.min_sigma_m)


def sigmas_from_dop_model(gnss: GnssData, config: GnssConfig) -> np.ndarray:
    """(M,) True where :func:`position_sigmas` had no sigma of the data's own or configured
    and used UERE x DOP (or ``default_sigma_m``): a model whose scale the fit can check."""
    if config.sigma_m is not None:
        return np.zeros(len(gnss), dtype=bool)
    return ~np.all(np.isfinite(_positive(gnss.std)), axis=1)


def velocity_sigmas(gnss: GnssData, config: GnssConfig) -> np.ndarray:
    """1-sigma east/north/up velocity error per epoch (M, 3); NaN where there is no velocity."""
    n = len(gnss)
    sigma = np.full((n, 3), np.nan)
    has_velocity = np.all(np.isfinite(gnss.velocity[:, :2]), axis=1)
    if config.velocity_sigma_m_per_s is not None:
        sigma[has_velocity] = config.velocity_sigma_m_per_s
    else:
        data = _positive(gnss.velocity_std)
        # Doppler velocity is typically ~0.1 m/s x DOP; without data sigmas use that.
        hdop = _positive(gnss.hdop)
        hdop = np.where(np.isfinite(hdop), hdop, 1.0)
        fallback = np.column_stack([0.1 * hdop, 0.1 * hdop, 0.2 * hdop])
        sigma[has_velocity] = np.where(np.isfinite(data), data, fallback)[has_velocity]
    no_up = ~np.isfinite(gnss.velocity[:, 2])
    sigma[no_up, 2] = np.nan
    # Horizontal-only velocity comes from speed + course (RMC/VTG): course is noise at walking
    # speed, so those epochs give no velocity factor below the threshold.
    speed = np.linalg.norm(np.nan_to_num(gnss.velocity[:, :2]), axis=1)
    sigma[no_up & (speed < config.course_min_speed_m_per_s)] = np.nan
    return sigma


@dataclass
class GateResult:
    """Which epochs are used, and why the others are not.

    Every epoch is counted exactly once, in this priority order (the first reason that
    applies): withheld by the caller's outage mask, no finite position, outside the IMU time
    span (when given), fix quality below the minimum (or 6 dead reckoning, 7 manual input,
    8 simulator: :data:`NOT_MEASURED_QUALITIES`), PDOP above
    ``pdop_max``. So ``total == n_used + withheld + rejected_position + outside_span +
    rejected_quality + rejected_pdop``; an epoch in an outage is never "gated by PDOP".

    ``usable`` keeps its old meaning: epochs that pass the gates, ignoring the outage mask
    (callers AND it with their own mask); ``used`` is ``usable & ~withheld``.
    """

    usable: np.ndarray
    rejected_pdop: int
    rejected_quality: int
    withheld: int = 0
    rejected_position: int = 0
    outside_span: int = 0
    pdop_max: float | None = None
    used: np.ndarray | None = None
    # False when the caller gave no outage mask: then "used" cannot be claimed, only "pass
    # the gates" (the caller may still withhold some of them).
    outage_applied: bool = True

    def __post_init__(self) -> None:
        if self.used is None:
            self.used = self.usable

    @property
    def total(self) -> int:
        return len(self.usable)

    @property
    def n_used(self) -> int:
        return int(self.used.sum())

    def summary(self) -> str:
        """One line whose counts add up to the number of epochs, e.g. ``GNSS: 469 epochs:
        409 used, 60 withheld by outage, 0 gated by PDOP > 5, 0 by fix quality``."""
        pdop = f"PDOP > {self.pdop_max:g}" if self.pdop_max is not None else "PDOP"
        if self.outage_applied:
            parts = [f"{self.n_used} used", f"{self.withheld} withheld by outage"]
        else:
            parts = [f"{self.n_used} pass the gates (outages not counted here)"]
        if self.rejected_position:
            parts.append(f"{self.rejected_position} without a position")
        if self.outside_span:
            parts.append(f"{self.outside_span} outside the IMU time span")
        parts += [
            f"{self.rejected_pdop} gated by {pdop}",
            f"{self.rejected_quality} by fix quality",
        ]
        return f"GNSS: {self.total} epochs: " + ", ".join(parts)


def dropped_on_read_note(metadata: dict[str, object]) -> str:
    """The epochs a reader dropped before the count line could see them (NMEA quality 0,
    NavSatFix status -1, UBX without a fix), as a suffix of that line: the line's own
    counts add up to the dataset's epochs, and the user still sees every epoch of the file."""
    dropped = int(metadata.get("gnss_epochs_without_fix", 0) or 0)  # type: ignore[call-overload]
    # The frozen output's repeats the input checks left out (fgins.io.motion_checks): a
    # 200-row gnss.csv was counted "152 epochs" (outside tester).
    frozen = int(metadata.get(FROZEN_DROPPED_KEY, 0) or 0)  # type: ignore[call-overload]
    parts = [f"+{dropped} epochs without a fix, dropped on reading"] if dropped else []
    parts += [f"+{frozen} repeats of a frozen position, left out on loading"] if frozen else []
    return f" ({'; '.join(parts)})" if parts else ""



def gate_epochs(
    gnss: GnssData,
    config: GnssConfig,
    withheld: np.ndarray | None = None,
    imu_span: tuple[float, float] | None = None,
) -> GateResult:
    """PDOP and fix-quality gates (the MEMS study rejects PDOP > 5); gated epochs are outages.

    Parameters
    ----------
    gnss, config
        The fixes and the GNSS settings (``min_fix_quality``, ``pdop_max``).
    withheld
        Optional bool mask (M,), True where the caller withholds the epoch (an outage). Such an
        epoch is counted as withheld only, whatever its PDOP or quality. Without it the
        summary says "pass the gates", not "used", as it cannot know the outages.
    imu_span
        Optional (start, end) time of the IMU; epochs outside it cannot be used and are
        counted as such (and are not ``usable``).

    Returns
    -------
    GateResult
        ``usable`` (gates only, as before), ``used`` (also not withheld) and the counts per
        reason, each epoch counted once (see :class:`GateResult` for the order).
    """
    n = len(gnss)
    outage_applied = withheld is not None
    if withheld is None:
        withheld = np.zeros(n, dtype=bool)
    withheld = np.asarray(withheld, dtype=bool)
    if withheld.shape != (n,):
        raise InputError(
            f"withheld has shape {withheld.shape} for {n} GNSS epochs; build it with "
            "~fgins.outages.outage_mask(dataset, windows)"
        )
    position_ok = np.all(np.isfinite(gnss.lla), axis=1)
    span_ok = np.ones(n, dtype=bool)
    if imu_span is not None:
        span_ok = (gnss.t >= imu_span[0]) & (gnss.t <= imu_span[1])
    quality_ok = (gnss.fix_quality >= config.min_fix_quality) & ~np.isin(
        gnss.fix_quality, list(NOT_MEASURED_QUALITIES)
    )
    pdop_ok = np.ones(n, dtype=bool)
    if config.pdop_max is not None:
        pdop_ok = ~(np.isfinite(gnss.pdop) & (gnss.pdop > config.pdop_max))
    usable = position_ok & span_ok & quality_ok & pdop_ok
    # Attribute each epoch to the first reason in the priority order.
    remaining = ~withheld
    counts = []
    for ok in (position_ok, span_ok, quality_ok, pdop_ok):
        counts.append(int((remaining & ~ok).sum()))
        remaining = remaining & ok
    return GateResult(
        usable=usable,
        rejected_pdop=counts[3],
        rejected_quality=counts[2],
        withheld=int(withheld.sum()),
        rejected_position=counts[0],
        outside_span=counts[1],
        pdop_max=config.pdop_max,
        used=usable & ~withheld,
        outage_applied=outage_applied,
    )


# 3-D whitened residual norm above which a fix is a "large residual": chi-square, 3 dof,
# 99.9 % (the level graph/reports.py reports at), so 0.1 % of good fixes exceed it.
LARGE_RESIDUAL_SIGMA = 4.03
LARGE_RESIDUAL_EXPECTED = 0.001


def kernel_weights(whitened_norms: np.ndarray, config: GnssConfig) -> np.ndarray:
    """Weight the robust kernel gives each GNSS factor at its whitened residual norm (GTSAM's
    mEstimator weights: Cauchy k^2 / (k^2 + r^2), Huber min(1, k / r)); 1 without a kernel."""
    r = np.abs(np.asarray(whitened_norms, dtype=float))
    if config.cauchy_k is not None:
        return config.cauchy_k**2 / (config.cauchy_k**2 + r**2)
    if config.huber_k is not None:
        return np.minimum(1.0, config.huber_k / np.maximum(r, 1e-300))
    return np.ones_like(r)


def residual_summary(
    whitened_norms: np.ndarray, config: GnssConfig, downweighted_below: float = 0.5
) -> str:
    """One honest line about GNSS residuals at the solution.

    A residual above :data:`LARGE_RESIDUAL_SIGMA` is a *large residual*; only a robust
    kernel really down-weights a fix, so "rejected"/"down-weighted" is said only with one
    on, counting fixes whose kernel weight is below ``downweighted_below``.
    """
    norms = np.asarray(whitened_norms, dtype=float)
    n, large = len(norms), int((norms > LARGE_RESIDUAL_SIGMA).sum())
    line = f"GNSS residuals: {large} of {n} fixes above {LARGE_RESIDUAL_SIGMA:g} sigma"
    if config.cauchy_k is not None or config.huber_k is not None:
        kind, k = (
            ("cauchy", config.cauchy_k)
            if config.cauchy_k is not None
            else ("huber", config.huber_k)
        )
        weak = int((kernel_weights(norms, config) < downweighted_below).sum())
        line += (
            f"; robust kernel {kind} (k={k:g}) down-weighted {weak} of them below "
            f"{100 * downweighted_below:.0f} % weight"
        )
    else:
        line += " (no robust kernel: they keep full weight; --robust cauchy down-weights them)"
    if n and large > max(3, 10 * LARGE_RESIDUAL_EXPECTED * n):
        line += (
            f"; {100 * large / n:.0f} % is far above the {100 * LARGE_RESIDUAL_EXPECTED:g} % "
            "expected: the GNSS sigmas are too small for these fixes"
        )
    return line


def position_noise_model(sigma: np.ndarray, config: GnssConfig):  # -> gtsam noise model
    """Diagonal GTSAM noise model, wrapped in a Cauchy or Huber kernel when configured.

    Huber is convex (safe from any start) but only bounds an outlier's pull; Cauchy
    redescends, so a 50-sigma jump ends up with almost no weight.
    """
    import gtsam

    base = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, dtype=float))
    if config.cauchy_k is not None:
        kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(config.cauchy_k)
    elif config.huber_k is not None:
        kernel = gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k)
    else:
        return base
    return gtsam.noiseModel.Robust.Create(kernel, base)


def position_factor(
    pose_key: int, position_enu: np.ndarray, sigma: np.ndarray, config: GnssConfig
):  # -> gtsam.NonlinearFactor
    """GNSS antenna position factor on a pose, with the lever arm when it is not zero."""
    import gtsam

    noise = position_noise_model(sigma, config)
    lever_arm = np.asarray(config.lever_arm_m, dtype=float)
    if np.any(lever_arm != 0):
        return gtsam.GPSFactorArm(pose_key, position_enu, lever_arm, noise)
    return gtsam.GPSFactor(pose_key, position_enu, noise)


def antenna_check_rows(
    pose_key: int,
    rotation: np.ndarray,
    imu_position: np.ndarray,
    velocity: np.ndarray,
    position_enu: np.ndarray,
    sigma: np.ndarray,
    config: GnssConfig,
    along_drive: float = 0.0,
):  # -> tuple[gtsam.JacobianFactor, np.ndarray]
    """A GNSS position factor linearised at a solution, and its columns (3, 5) in the lever
    arm's change (body axes, about the configured arm) and in a time offset (s, about none:
    the fix stamped ``d`` late was taken where the antenna was ``d`` earlier; ``d = d0 + d1
    * along_drive``, ``along_drive`` the fix's time from the drive's middle over half its
    length, -1 to 1), for :mod:`fgins.graph.parameter_step`. Rows whitened by the fix's
    sigmas and the configured kernel's weight at the solution's residual (GTSAM's IRLS
    weight)."""
    import gtsam

    arm = np.asarray(config.lever_arm_m, dtype=float)
    residual = imu_position + rotation @ arm - np.asarray(position_enu, dtype=float)
    whiten = 1.0 / np.asarray(sigma, dtype=float)
    weight = float(kernel_weights(np.linalg.norm(residual * whiten), config))
    rows = np.sqrt(weight) * whiten[:, None]
    pose_jacobian = np.hstack([-rotation @ skew(arm), rotation])  # Pose3: rotation, then translation
    factor = gtsam.JacobianFactor(
        pose_key, rows * pose_jacobian, -(rows[:, 0] * residual), gtsam.noiseModel.Unit.Create(3)
    )
    time = -np.outer(np.asarray(velocity, dtype=float), [1.0, along_drive])
    return factor, rows * np.hstack([rotation, time])


def antenna_velocity_check_rows(
    pose_key: int,
    velocity_key: int,
    bias_key: int,
    rotation: np.ndarray,
    velocity: np.ndarray,
    rate: np.ndarray,
    lever_arm: np.ndarray,
    measured: np.ndarray,
    sigma: np.ndarray,
    config: GnssConfig,
    acceleration: np.ndarray,
    along_drive: float,
    half_span: float,
):  # -> tuple[gtsam.JacobianFactor, np.ndarray]
    """A GNSS velocity linearised at a solution as :func:`antenna_velocity_factors` does
    (``rate`` the bias-corrected body rate), and its columns (3, 5) in the lever arm's
    change (``R [w]x``) and in the time offset of :func:`antenna_check_rows` (a velocity
    stamped ``d`` late is the one of ``d`` earlier: ``-a [1, along_drive]``; and against
    an IMU clock running ``r = -d1 / half_span`` fast, the velocity reads ``1 + r`` times
    the solution's: ``-v / half_span`` more in ``d1``). Rows whitened by the sigmas and
    weighted by :func:`check_weights`."""
    import gtsam

    lever_skew = skew(np.asarray(lever_arm, dtype=float))
    offset = np.asarray(rate, dtype=float) @ lever_skew  # w x l
    residual = np.asarray(velocity, float) + rotation @ offset - np.asarray(measured, float)
    whiten = 1.0 / np.asarray(sigma, dtype=float)
    weight = float(check_weights(np.linalg.norm(residual * whiten), config))
    rows = np.sqrt(weight) * whiten[:, None]
    d_pose = np.hstack([-rotation @ skew(offset), np.zeros((3, 3))])
    d_bias = np.hstack([np.zeros((3, 3)), rotation @ lever_skew])
    factor = gtsam.JacobianFactor(
        pose_key, rows * d_pose, velocity_key, rows * np.eye(3), bias_key, rows * d_bias,
        -(rows[:, 0] * residual), gtsam.noiseModel.Unit.Create(3),
    )  # fmt: skip
    time = -np.outer(np.asarray(acceleration, dtype=float), [1.0, along_drive])
    time[:, 1] -= np.asarray(velocity, dtype=float) / half_span
    return factor, rows * np.hstack([rotation @ skew(np.asarray(rate, dtype=float)), time])


def check_weights(whitened_norms: np.ndarray | float, config: GnssConfig) -> np.ndarray:
    """How the antenna and clock check weighs a GNSS velocity at its whitened residual: as
    a redescending (Cauchy) kernel at the configured kernel's width, whatever kernel the
    solve used. Velocities are sharp (0.1-0.2 m/s) and a city's multipath throws them by
    tens of sigmas, which a Huber kernel only bounds (80 sigmas still add 4 x 80 to the
    chi-square): 4 % of a car's velocities 8 m/s off read as an antenna 4 m to the side at
    7 sigma. (The positions keep the solve's kernel: an arm's or a latency's own residuals
    reach 3-5 sigmas, and a redescending weight there blurred a 0.2 s latency into "cannot
    tell".) Without a configured kernel, every velocity at full weight."""
    k = config.cauchy_k if config.cauchy_k is not None else config.huber_k
    r = np.abs(np.asarray(whitened_norms, dtype=float))
    return np.ones_like(r) if k is None else k**2 / (k**2 + r**2)


def velocity_factor(velocity_key: int, velocity_enu: np.ndarray, sigma: np.ndarray, config: GnssConfig):
    """Prior on the navigation-frame velocity key (GNSS Doppler velocity), under the
    fixes' kernel: a receiver's velocity jumps by metres per second in a city's multipath
    as its position does (2-3 % of an urban car's velocities 5 m/s off: 0.71 -> 1.32 m
    inside outages at full weight, nothing said)."""
    import gtsam

    return gtsam.PriorFactorVector(
        velocity_key, np.asarray(velocity_enu, dtype=float), position_noise_model(sigma, config)
    )


def antenna_velocity(
    rotation: np.ndarray, velocity: np.ndarray, body_rate: np.ndarray, lever_arm: np.ndarray
) -> np.ndarray:
    """Navigation-frame velocity of an antenna ``lever_arm`` (body axes) away from the IMU:
    ``v + R (w x l)``, with ``w`` the body angular rate (bias-corrected)."""
    return np.asarray(velocity, float) + np.asarray(rotation, float) @ np.cross(body_rate, lever_arm)


# The median norm of a 3-vector of unit normal errors, and how many velocities make a set
# whose median says how far the whole set misfits (an iSAM2 update brings one).
MEDIAN_NORM_3D = 1.54
ADAPTIVE_KERNEL_MIN = 10


def antenna_velocity_factors(
    pose_keys: np.ndarray,
    velocity_keys: np.ndarray,
    bias_keys: np.ndarray,
    rotation: np.ndarray,
    velocity: np.ndarray,
    gyro: np.ndarray,
    gyro_bias: np.ndarray,
    lever_arm: np.ndarray,
    measured: np.ndarray,
    sigma: np.ndarray,
    point,  # gtsam.Values holding every pose, velocity and bias under the keys
    config: GnssConfig | None = None,
) -> list:
    """GNSS Doppler velocities of an antenna off the IMU, linearised at ``point``, for n
    epochs ((n, 3, 3) rotations, (n, 3) the rest; ``gyro`` the samples at the fixes).

    The antenna moves at ``v + R ((g - b_g) x l)``: in a turn or a roll a lever arm of a metre
    adds tenths of a m/s, the size of a receiver's velocity sigma, which a plain prior on V
    would book as IMU error. GTSAM has no such factor and a Python callback would see the
    whole Values per evaluation (issue 9), so each is a ``JacobianFactor`` rebuilt at each
    new estimate, like the NHC (exact at convergence); the Jacobians come in one vectorised
    pass. With GTSAM's right perturbations R Exp(t) and b + db: d/dt = -R [c]x
    (c = w x l), d/dv = I, d/db_g = R [l]x. With ``config`` and a set of at least
    ADAPTIVE_KERNEL_MIN (the batch's rebuilds), each is weighted by its kernel at the
    residual there (the IRLS weight GTSAM's robust factors take, frozen until the next
    rebuild), the kernel widened by the set's own median misfit: an outlier is one among
    the rest. One velocity alone (an iSAM2 update) cannot tell an outlier from a state that
    is still off, and stays at full weight.
    """
    import gtsam

    lever_skew = skew(np.asarray(lever_arm, dtype=float))
    # w x l as w [l]x (rows): plain matmuls, np.cross and einsum cost ~60 us at n = 1, the
    # one epoch of an iSAM2 update (issue 9).
    offset = (np.asarray(gyro, float) - np.asarray(gyro_bias, float)) @ lever_skew
    residual = velocity + (rotation @ offset[:, :, None])[:, :, 0] - measured
    n = len(residual)
    if config is not None and n >= ADAPTIVE_KERNEL_MIN:
        norms = np.linalg.norm(residual / sigma, axis=1)
        # Outliers among the rest: where the whole set misfits (a start heading 120 deg
        # off: every residual tens of sigmas), the kernel's width grows with it, or the
        # frozen weights would leave the heading no pull (the batch stayed at 9.9 m).
        spread = float(np.median(norms)) / MEDIAN_NORM_3D
        weight = kernel_weights(norms / max(spread, 1.0), config)
        sigma = sigma / np.sqrt(weight)[:, None]
    d_pose = np.zeros((n, 3, 6))
    d_pose[:, :, :3] = -(rotation @ skew_batch(offset))
    d_bias = np.zeros((n, 3, 6))
    d_bias[:, :, 3:] = rotation @ lever_skew
    eye = np.eye(3)
    out = []
    for i in range(n):
        linear = gtsam.JacobianFactor(
            int(pose_keys[i]), d_pose[i], int(velocity_keys[i]), eye, int(bias_keys[i]),
            d_bias[i], -residual[i], gtsam.noiseModel.Diagonal.Sigmas(sigma[i]),
        )  # fmt: skip
        out.append(gtsam.LinearContainerFactor(linear, point))
    return out



def select_epochs(
    dataset: Dataset, config: GnssConfig, gnss_mask: np.ndarray | None
) -> tuple[np.ndarray, dict[str, int]]:
    """Usable epochs and counts that add up: every epoch is counted once, outage first
    (a withheld epoch is never "rejected for PDOP"), then the IMU span, then the gates (the
    order of :func:`gate_epochs`: an epoch the IMU does not cover is "outside the IMU span"
    whatever its PDOP). The graph and the Kalman baselines count alike."""
    gnss, imu = dataset.gnss, dataset.imu
    kept = np.ones(len(gnss), dtype=bool) if gnss_mask is None else np.asarray(gnss_mask, bool)
    gate = gate_epochs(gnss.subset(kept), config, imu_span=(float(imu.t[0]), float(imu.t[-1])))
    usable = np.zeros(len(gnss), dtype=bool)
    usable[kept] = gate.usable
    counts = {
        "total": len(gnss),
        "withheld": int((~kept).sum()),
        "gated_pdop": gate.rejected_pdop,
        "gated_quality": gate.rejected_quality,
        "outside_imu_span": gate.outside_span,
    }
    return usable, counts


# Fixes a run needs at the least: the alignment's start and a second to move it.
MIN_USABLE_FIXES = 2


def require_usable_fixes(
    dataset: Dataset, config: GnssConfig, gnss_mask: np.ndarray | None, usable: np.ndarray,
    counts: dict[str, int] | None = None,
) -> None:  # fmt: skip
    """Raise :func:`no_usable_gnss_error` where ``usable`` holds fewer than MIN_USABLE_FIXES
    (``counts`` from :func:`select_epochs`, computed here when not given)."""
    found = int(np.count_nonzero(usable))
    if found >= MIN_USABLE_FIXES:
        return
    if counts is None:
        counts = select_epochs(dataset, config, gnss_mask)[1]
    raise no_usable_gnss_error(dataset, config, counts, found)


def no_usable_gnss_error(
    dataset: Dataset, config: GnssConfig, counts: dict[str, int], usable: int = 0
) -> InputError:
    """Why no GNSS epoch is usable, naming the actual causes: the time bases only when every
    epoch left after the outages lies outside the IMU span (all fixes gated used to be
    blamed on the clocks too)."""
    imu = dataset.imu
    name = dataset.name or "input"
    total, withheld = counts["total"], counts["withheld"]
    outside = counts["outside_imu_span"]
    if withheld == total:
        return InputError(
            f"{name}: no usable GNSS epoch: the GNSS outage windows withhold every one ({total})"
        )
    if outside == total - withheld:
        return InputError(
            f"{name}: no GNSS epoch within the IMU time span ({imu.t[0]:.3f}-{imu.t[-1]:.3f} s; "
            f"GNSS {dataset.gnss.t[0]:.3f}-{dataset.gnss.t[-1]:.3f} s); check the time bases "
            "(--time-offset)"
        )
    parts = []
    if withheld:
        parts.append(f"{withheld} withheld by the outage windows")
    if counts["gated_pdop"]:
        parts.append(
            f"{counts['gated_pdop']} gated by PDOP > {config.pdop_max:g} ([gnss] pdop_max)"
        )
    if counts["gated_quality"]:
        quality = dataset.gnss.fix_quality
        named = ", ".join(
            f"{n} with {q} ({what})"
            for q, what in NOT_MEASURED_QUALITIES.items()
            if (n := int(np.sum(quality == q)))
        )
        parts.append(
            f"{counts['gated_quality']} by fix quality < {config.min_fix_quality} (0 = no fix; "
            "[gnss] min_fix_quality) or 6-8 (dead reckoning, manual input, simulator: not "
            f"measurements{': ' + named if named else ''})"
        )
    if outside:
        parts.append(f"{outside} outside the IMU time span")
    if usable:  # too few, not none (a real log: 9 fixes, all of them at PDOP ~23)
        return InputError(
            f"{name}: only {usable} usable GNSS epoch(s) of {total} (a run needs "
            f"{MIN_USABLE_FIXES}): " + ", ".join(parts)
        )
    return InputError(f"{name}: no usable GNSS epoch of {total}: " + ", ".join(parts))
