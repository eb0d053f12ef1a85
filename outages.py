"""GNSS outage windows: parsing ``A:B[,C:D...]`` and withholding epochs (IMU untouched)."""

from __future__ import annotations

import itertools

import numpy as np

from fgins.datatypes import ConfigError, Dataset, FginsError


def parse_windows(text: str | None) -> list[tuple[float, float]]:
    """``"60:90,150:180"`` -> [(60.0, 90.0), (150.0, 180.0)] (seconds relative to t0)."""
    if text is None:
        return []
    if not text.strip(" ,"):
        raise FginsError("--gnss-outage: no window given (e.g. 60:90 or 60:90,150:180)")
    windows = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            start_text, end_text = part.split(":")
            start, end = float(start_text), float(end_text)
        except ValueError:
            raise FginsError(
                f"--gnss-outage: {part!r} is not START:END in seconds (e.g. 60:90)"
            ) from None
        if not (np.isfinite(start) and np.isfinite(end)):
            raise FginsError(
                f"--gnss-outage: window {part!r}: START and END must be finite numbers of "
                "seconds (e.g. 60:90)"
            )
        if end <= start:
            raise FginsError(f"--gnss-outage: window {part!r} must have START < END")
        windows.append((start, end))
    return windows


def outage_mask(dataset: Dataset, windows: list[tuple[float, float]]) -> np.ndarray:
    """True for GNSS epochs kept; epochs with A <= t - t0 < B are withheld."""
    relative = dataset.gnss.t - dataset.t0
    keep = np.ones(len(dataset.gnss), dtype=bool)
    for start, end in windows:
        keep &= ~((relative >= start) & (relative < end))
    return keep


def empty_windows(dataset: Dataset, windows: list[tuple[float, float]]) -> list[str]:
    """One line per window that withholds no GNSS epoch (a typo or a window past the drive:
    the run would be no outage test at all)."""
    relative = dataset.gnss.t - dataset.t0
    lines = []
    for start, end in windows:
        if not np.any(in_windows(dataset.gnss.t, dataset.t0, [(start, end)])):
            before, after = relative[relative < start], relative[relative >= end]
            if len(before) and len(after):
                # Inside the span, between two epochs (fixes 5 s apart and a 1 s window): the
                # span alone pointed elsewhere (outside tester).
                where = (
                    f"it falls between the epochs at {before.max():.1f} and {after.min():.1f} s "
                    "after t0"
                )
            else:
                where = f"the epochs span {relative.min():.1f} .. {relative.max():.1f} s after t0"
            line = (
                f"GNSS outage window {start:.10g}:{end:.10g} s withholds no GNSS epoch ({where}): "
                "no outage there"
            )
            absolute = in_windows(dataset.gnss.t, 0.0, [(start, end)])
            if np.any(absolute) and dataset.t0:
                # A window in the log's own time base (POSIX or GPS seconds): say which one
                # it would be after t0.
                line += (
                    f"; windows count from the first GNSS epoch (t0 = {dataset.t0:.10g}): as the "
                    f"log's own times, it is {start - dataset.t0:.1f}:{end - dataset.t0:.1f}"
                )
            lines.append(line)
    return lines


def overlapping_windows(windows: list[tuple[float, float]]) -> list[str]:
    """One line per pair of windows that overlap or touch: withheld together they are one
    longer outage, which the user may not have meant (a typo in a list of windows)."""
    ordered = sorted(windows)
    lines = []
    for (start_a, end_a), (start_b, end_b) in itertools.pairwise(ordered):
        if start_b <= end_a:
            lines.append(
                f"GNSS outage windows {start_a:.10g}:{end_a:.10g} and {start_b:.10g}:{end_b:.10g} s "
                f"{'touch' if start_b == end_a else 'overlap'}: together they withhold one outage "
                f"of {max(end_a, end_b) - start_a:.10g} s"
            )
    return lines


WINDOW_EDGE_S = 1e-6  # a stamp this close to a window's edge is on it


def in_windows(t: np.ndarray, t0: float, windows: list[tuple[float, float]]) -> np.ndarray:
    """True where ``t`` (absolute) lies inside any window, ``start <= t - t0 < end`` to
    the microsecond: at POSIX times ``t - t0`` is off by ~1e-13 s (a 5 Hz fix stamped at
    1.4 s read 1.39999999999998 and was withheld by a window ending at 1.4; outside tester)."""
    relative = np.asarray(t) - t0
    inside = np.zeros(relative.shape, dtype=bool)
    for start, end in windows:
        inside |= (relative >= start - WINDOW_EDGE_S) & (relative < end - WINDOW_EDGE_S)
    return inside


def periodic_windows(
    duration_s: float, period_s: float, start_s: float, span_s: float
) -> list[tuple[float, float]]:
    """Outages of ``duration_s`` every ``period_s`` from ``start_s`` while they fit in ``span_s``."""
    if duration_s <= 0 or period_s <= duration_s:
        # Equal, the windows touch: one outage (refused as explicit touching windows are,
        # after "0 < duration <= period" had let it through; outside tester).
        raise ConfigError(
            f"outage protocol: need 0 < duration < period (outage duration {duration_s:g} s, "
            f"period {period_s:g} s; windows that touch are one outage: give that one window)"
        )
    windows = []
    start = start_s
    while start + duration_s <= span_s:
        windows.append((start, start + duration_s))
        start += period_s
    if not windows:
        raise FginsError(
            f"outage protocol: no {duration_s:g} s window fits in {span_s:.0f} s of GNSS from {start_s:g} s"
        )
    return windows
