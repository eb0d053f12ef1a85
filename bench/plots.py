"""Plots people look at: the track with outages highlighted, and error versus time.

Every function returns a :class:`matplotlib.figure.Figure` (a notebook displays it, a program
can change it) and writes it to ``path`` when one is given. Figures are created without
pyplot, so no global backend is selected or changed and no figure stays registered anywhere:
writing a file renders through Agg, and an interactive session keeps its own backend.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from fgins.bench.metrics import Errors, errors_against
from fgins.datatypes import Dataset, Trajectory
from fgins.io.atomic import atomic_path
from fgins.outages import in_windows


def save_figure(fig: Figure, path: str | Path, dpi: int = 110) -> None:
    """Write ``fig`` atomically; the format follows the extension (PNG when there is none)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip(".").lower() or "png")


def _colors() -> list[str]:
    return list(matplotlib.rcParams["axes.prop_cycle"].by_key()["color"])


def plot_track_and_errors(
    trajectories: Trajectory | Sequence[Trajectory],
    dataset: Dataset,
    windows: Sequence[tuple[float, float]] = (),
    *,
    errors: Sequence[Errors] | None = None,
    path: str | Path | None = None,
    title: str = "",
) -> Figure:
    """Left: ENU track(s), GNSS fixes, withheld fixes in red, the bridged stretches. Right:
    horizontal error against the GNSS fixes versus time, outage windows shaded, with each
    trajectory's reported 3-sigma band (dashed).

    ``errors`` (one per trajectory) defaults to :func:`fgins.bench.metrics.errors_against` the
    dataset's fixes. Returns the Figure; ``path`` also writes it.
    """
    items = [trajectories] if isinstance(trajectories, Trajectory) else list(trajectories)
    gnss_t = dataset.gnss.t
    gnss_enu = dataset.gnss_enu()
    t0 = dataset.t0
    windows = list(windows)
    if errors is None:
        errors = [errors_against(tr, gnss_t, gnss_enu, t0, windows) for tr in items]
    withheld = in_windows(gnss_t, t0, windows)
    single = len(items) == 1  # one trajectory: the bridged stretch in magenta, as always
    fig = Figure(figsize=(14, 6))
    ax_track, ax_err = fig.subplots(1, 2)
    ax_track.plot(gnss_enu[~withheld, 0], gnss_enu[~withheld, 1], "k.", ms=2, label="GNSS used")
    if withheld.any():
        ax_track.plot(
            gnss_enu[withheld, 0], gnss_enu[withheld, 1], "r.", ms=4, label="GNSS withheld"
        )
    for k, (color, trajectory, error) in enumerate(zip(_colors() * 3, items, errors, strict=False)):
        label = trajectory.method or f"trajectory {k + 1}"
        ax_track.plot(
            trajectory.position[:, 0], trajectory.position[:, 1], "-", color=color, lw=1,
            label=label,
        )  # fmt: skip
        if withheld.any():
            inside = in_windows(trajectory.t, t0, windows)
            ax_track.plot(
                np.where(inside, trajectory.position[:, 0], np.nan),
                np.where(inside, trajectory.position[:, 1], np.nan),
                "-", color="m" if single else color, lw=2, alpha=1.0 if single else 0.6,
                label="bridged by IMU" if single else None,
            )  # fmt: skip
        rel = error.t - t0
        ax_err.plot(rel, error.horizontal, ".-", color=color, ms=2, lw=0.8, label=label)
        ax_err.plot(rel, 3 * error.horizontal_std, "--", color=color, lw=0.8)
    ax_track.set_xlabel("east (m)")
    ax_track.set_ylabel("north (m)")
    ax_track.axis("equal")
    ax_track.grid(True, alpha=0.3)
    ax_track.legend(loc="best", fontsize=8)
    for start, end in windows:
        ax_err.axvspan(start, end, color="red", alpha=0.12)
    ax_err.set_xlabel("time since first GNSS epoch (s)")
    ax_err.set_ylabel("horizontal error vs GNSS (m); dashed: reported 3 sigma")
    ax_err.set_yscale("symlog", linthresh=0.5)
    ax_err.grid(True, alpha=0.3)
    ax_err.legend(loc="upper left", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def plot_outage_errors(case, path: str | Path | None = None) -> Figure:
    """Per method of a benchmark case: horizontal error vs time, outages shaded, each method's
    reported 3 sigma dotted."""
    fig = Figure(figsize=(12, 5))
    ax = fig.subplots()
    t0 = case.dataset.t0
    for color, result in zip(_colors() * 3, case.results, strict=False):
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
    if path is not None:
        save_figure(fig, path)
    return fig


def plot_outage_sweep(sweep, path: str | Path | None = None) -> Figure:
    """Error versus outage length, one line per method: RMS inside, and at the end."""
    fig = Figure(figsize=(13, 5))
    axes = fig.subplots(1, 2)
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
    if path is not None:
        save_figure(fig, path)
    return fig
