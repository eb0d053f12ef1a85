"""Plots people look at: the track with outages highlighted, and error versus time."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fgins.bench.metrics import Errors
from fgins.datatypes import Trajectory
from fgins.io.atomic import atomic_path
from fgins.outages import in_windows


def plot_track_and_errors(
    trajectory: Trajectory,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    t0: float,
    windows: list[tuple[float, float]],
    errors: Errors | None,
    path: str | Path,
    title: str = "",
) -> None:
    """Left: ENU track, GNSS fixes, withheld fixes in red. Right: horizontal error vs time
    with outage windows shaded and the reported 3-sigma band."""
    withheld = in_windows(gnss_t, t0, windows)
    fig, (ax_track, ax_err) = plt.subplots(1, 2, figsize=(14, 6))
    ax_track.plot(
        trajectory.position[:, 0], trajectory.position[:, 1], "b-", lw=1, label=trajectory.method
    )
    ax_track.plot(gnss_enu[~withheld, 0], gnss_enu[~withheld, 1], "k.", ms=2, label="GNSS used")
    if withheld.any():
        ax_track.plot(
            gnss_enu[withheld, 0], gnss_enu[withheld, 1], "r.", ms=4, label="GNSS withheld"
        )
        inside = in_windows(trajectory.t, t0, windows)
        ax_track.plot(
            np.where(inside, trajectory.position[:, 0], np.nan),
            np.where(inside, trajectory.position[:, 1], np.nan),
            "m-", lw=2, label="bridged by IMU",
        )  # fmt: skip
    ax_track.set_xlabel("east (m)")
    ax_track.set_ylabel("north (m)")
    ax_track.axis("equal")
    ax_track.grid(True, alpha=0.3)
    ax_track.legend(loc="best", fontsize=8)
    if errors is not None:
        rel = errors.t - t0
        ax_err.plot(rel, errors.horizontal, "b.-", ms=2, lw=0.8, label="horizontal error")
        ax_err.plot(rel, 3 * errors.horizontal_std, "g--", lw=0.8, label="reported 3 sigma")
        for start, end in windows:
            ax_err.axvspan(start, end, color="red", alpha=0.12)
        ax_err.set_xlabel("time since first GNSS epoch (s)")
        ax_err.set_ylabel("horizontal error vs GNSS (m)")
        ax_err.set_yscale("symlog", linthresh=0.5)
        ax_err.grid(True, alpha=0.3)
        ax_err.legend(loc="upper left", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)


def plot_outage_errors(case, path: str | Path) -> None:
    """Per method: horizontal error vs time with outages shaded and each method's 3-sigma."""
    fig, ax = plt.subplots(figsize=(12, 5))
    t0 = case.dataset.t0
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for color, result in zip(colors * 3, case.results, strict=False):
        rel = result.errors.t - t0
        ax.plot(rel, result.errors.horizontal, "-", color=color, lw=0.9, label=result.method)
        ax.plot(rel, 3 * result.errors.horizontal_std, ":", color=color, lw=0.7)
    for start, end in case.windows:
        ax.axvspan(start, end, color="red", alpha=0.1)
    ax.set_yscale("symlog", linthresh=0.5)
    ax.set_xlabel("time since first GNSS epoch (s)")
    ax.set_ylabel("horizontal error (m); dotted: reported 3 sigma")
    reference = "truth" if case.truth is not None else "withheld GNSS"
    ax.set_title(f"{case.name}: error against {reference}, outages shaded")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def plot_outage_sweep(sweep, path: str | Path) -> None:
    """Error versus outage length, one line per method: RMS inside, and at the end."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    for ax, table, label in (
        (axes[0], sweep.rms_error, "horizontal RMS inside the outage (m)"),
        (axes[1], sweep.end_error, "horizontal error at outage end (m)"),
    ):
        for method, errors in table.items():
            ax.plot(sweep.lengths, errors, "o-", label=method)
        ax.set_yscale("log")
        ax.set_xlabel("outage length (s)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{sweep.name}: error growth with outage length")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
