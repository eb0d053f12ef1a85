"""GNSS receiver model: fixes with DOP-scaled noise, outliers, biased stretches, outages.

Noise per epoch: sigma_east = sigma_north = UERE x HDOP, sigma_up = UERE x VDOP (the same
rule the estimators use to weight fixes, DESIGN.md), unless a constant ``sigma_m`` is given.
All times in the model (DOP stretches, biased windows, outages) are seconds relative to the
first GNSS epoch, like the outage windows of the CLI.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgins.datatypes import GnssData, InputError, Origin
from fgins.geodesy import enu_to_lla, vectors_nav_to_local

Window = tuple[float, float]


@dataclass(frozen=True)
class DopStretch:
    """A stretch of degraded geometry (urban canyon, trees): HDOP near ``hdop`` inside."""

    start_s: float
    end_s: float
    hdop: float


@dataclass(frozen=True)
class BiasedStretch:
    """Fixes inside [start_s, end_s) are offset by ``offset_m`` (ENU metres): multipath."""

    start_s: float
    end_s: float
    offset_m: tuple[float, float, float]


@dataclass(frozen=True)
class GnssModel:
    """Receiver settings. ``velocity_sigma_m_per_s`` None: no velocity output."""

    rate_hz: float = 1.0
    uere_m: float = 3.0
    sigma_m: tuple[float, float, float] | None = None
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity_sigma_m_per_s: float | None = None
    fix_quality: int = 1
    open_sky_hdop: float = 1.1
    vdop_ratio: float = 1.6
    dop_stretches: tuple[DopStretch, ...] = ()
    biased_stretches: tuple[BiasedStretch, ...] = ()
    outlier_fraction: float = 0.0
    outlier_size_m: float = 0.0
    outages: tuple[Window, ...] = ()

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.uere_m <= 0:
            raise InputError("GNSS model: rate_hz and uere_m must be > 0")
        if not 0.0 <= self.outlier_fraction <= 1.0:
            raise InputError("GNSS model: outlier_fraction must be within [0, 1]")
        for a, b in self.outages:
            if b <= a:
                raise InputError(f"GNSS model: outage window {a}:{b} is empty; use A < B")


@dataclass
class GnssTruthInput:
    """What the receiver sees: vehicle truth at the IMU times plus the body rate."""

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray
    body_rate: np.ndarray  # rad/s, body relative to the (Earth-fixed) ENU frame


@dataclass
class GnssSimInfo:
    """Counts and indices (into the epochs *before* outage removal) for tests and reports."""

    epoch_t: np.ndarray
    outlier_epochs: np.ndarray
    biased_epochs: np.ndarray
    removed_epochs: int
    error_enu: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def epoch_indices(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the IMU samples that carry a GNSS epoch (rate must divide the IMU rate)."""
    imu_rate = 1.0 / float(np.median(np.diff(t)))
    ratio = imu_rate / rate_hz
    step = round(ratio)
    if step < 1 or abs(ratio - step) > 1e-6 * ratio:
        raise InputError(
            f"GNSS rate {rate_hz} Hz does not divide the IMU rate {imu_rate:.6g} Hz; "
            "choose a rate whose period is a whole number of IMU samples"
        )
    return np.arange(0, len(t), step)


def _smooth_noise(rng: np.random.Generator, n: int, window: int) -> np.ndarray:
    """Zero-mean, unit-ish std, slowly varying noise (moving average of white noise)."""
    window = max(1, min(window, n))
    raw = rng.standard_normal(n + window)
    smooth = np.convolve(raw, np.ones(window) / np.sqrt(window), mode="valid")[:n]
    return smooth


def dop_series(
    rng: np.random.Generator, rel_t: np.ndarray, model: GnssModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HDOP, VDOP, PDOP per epoch: open sky around ``open_sky_hdop``, raised in stretches."""
    n = len(rel_t)
    window = max(1, round(20.0 * model.rate_hz))
    hdop = model.open_sky_hdop * (1.0 + 0.12 * _smooth_noise(rng, n, window))
    hdop = np.clip(hdop, 0.8, 1.6 * model.open_sky_hdop)
    for stretch in model.dop_stretches:
        inside = (rel_t >= stretch.start_s) & (rel_t < stretch.end_s)
        hdop[inside] = stretch.hdop * (1.0 + 0.08 * _smooth_noise(rng, int(inside.sum()), 3))
    # Rounded like a receiver reports them; the sigmas are computed from the reported values.
    hdop = np.round(hdop, 2)
    vdop = np.round(model.vdop_ratio * hdop, 2)
    pdop = np.round(np.hypot(hdop, vdop), 2)
    return hdop, vdop, pdop


def simulate_gnss(
    rng: np.random.Generator, truth: GnssTruthInput, origin: Origin, model: GnssModel
) -> tuple[GnssData, GnssSimInfo]:
    """Fixes at ``model.rate_hz`` on IMU sample times; positions returned as geodetic LLA."""
    index = epoch_indices(truth.t, model.rate_hz)
    t = truth.t[index]
    rel_t = t - t[0]
    n = len(index)
    rotation = truth.rotation[index]
    lever = np.asarray(model.lever_arm_m, dtype=float)
    antenna = truth.position[index] + rotation @ lever
    antenna_velocity = truth.velocity[index] + np.einsum(
        "nij,nj->ni", rotation, np.cross(truth.body_rate[index], lever)
    )

    hdop, vdop, pdop = dop_series(rng, rel_t, model)
    if model.sigma_m is not None:
        std = np.tile(np.asarray(model.sigma_m, dtype=float), (n, 1))
    else:
        std = model.uere_m * np.column_stack([hdop, hdop, vdop])
    error = rng.standard_normal((n, 3)) * std

    biased = np.zeros(n, dtype=bool)
    for stretch in model.biased_stretches:
        inside = (rel_t >= stretch.start_s) & (rel_t < stretch.end_s)
        error[inside] += np.asarray(stretch.offset_m, dtype=float)
        biased |= inside
    outliers = rng.random(n) < model.outlier_fraction
    if outliers.any():
        direction = rng.standard_normal((int(outliers.sum()), 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        error[outliers] += model.outlier_size_m * direction

    velocity = velocity_std = None
    if model.velocity_sigma_m_per_s is not None:
        velocity_std = np.full((n, 3), float(model.velocity_sigma_m_per_s))
        velocity = antenna_velocity + rng.standard_normal((n, 3)) * velocity_std

    num_sats = np.clip(np.round(4.0 + 10.0 / hdop + rng.normal(0.0, 0.7, n)), 4, 24)
    keep = np.ones(n, dtype=bool)
    for a, b in model.outages:
        keep &= ~((rel_t >= a) & (rel_t < b))
    lla = enu_to_lla(antenna + error, origin)
    if velocity is not None:  # a receiver's velocity is in the local level where it is
        velocity = vectors_nav_to_local(lla, velocity, origin)
    gnss = GnssData(
        t=t,
        lla=lla,
        velocity=velocity,
        std=std,
        velocity_std=velocity_std,
        hdop=hdop,
        vdop=vdop,
        pdop=pdop,
        fix_quality=np.full(n, model.fix_quality),
        num_sats=num_sats,
    ).subset(keep)
    info = GnssSimInfo(
        epoch_t=t,
        outlier_epochs=np.flatnonzero(outliers),
        biased_epochs=np.flatnonzero(biased),
        removed_epochs=int((~keep).sum()),
        error_enu=error,
    )
    return gnss, info
