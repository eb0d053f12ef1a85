"""Outage-reconstruction benchmark: every method on identical data and identical outages.

Reference: simulator truth where the dataset has it, else the withheld GNSS fixes themselves
(on real data, the only independent reference inside an outage). Results: per-method metrics,
a markdown table with ratios against a baseline method measured in the same run, JSON, plots.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgins.bench.metrics import Errors, errors_against, relative_position_error
from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory
from fgins.factors.gnss import position_sigmas
from fgins.io.atomic import atomic_path, write_json
from fgins.outages import in_windows, outage_mask
from fgins.pipeline import run_method


@dataclass
class MethodResult:
    method: str
    metrics: dict[str, float]
    wall_s: float
    errors: Errors
    trajectory: Trajectory
    # Each window's own numbers ({"window": [start, end], "h_rms", "h_max", "h_end",
    # "within_3sigma", "nees_h"}): pooled ones hid a window at 0 % inside 3 sigma.
    windows: list[dict] = field(default_factory=list)

    @property
    def warnings(self) -> list[str]:
        """What the method said of this result (its fit's warnings)."""
        return [str(line) for line in self.trajectory.info.get("fit_warnings", [])]


@dataclass
class BenchCase:
    """One dataset under one outage protocol."""

    name: str
    dataset: Dataset
    config: RunConfig
    windows: list[tuple[float, float]]
    truth: Trajectory | None = None
    results: list[MethodResult] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)  # "method: why", one per failed method
    # Method -> why it produced no result (a row that says so in the table and the JSON).
    failed: dict[str, str] = field(default_factory=dict)
    # Windows left out of the scores, each with why (one that withholds no usable fix).
    left_out: list[tuple[tuple[float, float], str]] = field(default_factory=list)


def _truth_errors(
    trajectory: Trajectory, truth: Trajectory, t0: float, windows: list[tuple[float, float]]
) -> Errors:
    # Only where the truth covers the trajectory (a truth over part of the drive was held at
    # its ends, every state past them scored against its last position).
    covered = (trajectory.t >= truth.t[0]) & (trajectory.t <= truth.t[-1])
    t = trajectory.t[covered]
    difference = trajectory.position[covered] - truth.at(t)
    std = trajectory.position_std[covered, :2]
    return Errors(
        t=t,
        horizontal=np.linalg.norm(difference[:, :2], axis=1),
        vertical=np.abs(difference[:, 2]),
        inside=in_windows(t, t0, windows),
        horizontal_std=np.linalg.norm(std, axis=1),
        east_north=difference[:, :2],
        east_north_std=std,
    )


def end_of_outage_errors(
    errors: Errors, t0: float, windows: list[tuple[float, float]]
) -> list[float]:
    """Horizontal error at the last reference epoch inside each window (the drift at its end)."""
    out = []
    relative = errors.t - t0
    for start, end in windows:
        inside = np.flatnonzero((relative >= start) & (relative < end))
        if inside.size:
            out.append(float(errors.horizontal[inside[-1]]))
    return out


def run_case(case: BenchCase, methods: list[str], progress: bool = False) -> BenchCase:
    mask = outage_mask(case.dataset, case.windows)
    for method in methods:
        started = time.perf_counter()
        try:
            trajectory = run_method(
                case.dataset, case.config, method, gnss_mask=mask, progress=progress
            )
        except FginsError as exc:
            # Recorded (a row of the table and of outages.json); the caller says it as a
            # warning: printed here on stdout it was lost among the results (outside tester).
            case.failures.append(f"{method}: {exc}")
            case.failed[method] = str(exc)
            continue
        except Exception as exc:  # a defect in one method, not the benchmark's end
            # One method's internal error ended the whole benchmark, the others' results
            # lost with it (outside tester): its row says it, the rest stand.
            lines = str(exc).strip().splitlines()
            why = f"internal error: {type(exc).__name__}: {lines[0] if lines else ''}".rstrip(": ")
            why += " (a defect of fgins's: please report it with the input)"
            case.failures.append(f"{method}: {why}")
            case.failed[method] = why
            continue
        wall = time.perf_counter() - started
        variants = [(method, trajectory)]
        # isam2's run carries its online estimate: its row unless asked for on its own (then
        # run as `--online` is, corrections and all: carried, its row lost the warning and
        # the corrections the same method gives alone; outside tester).
        if method == "isam2" and "online" in trajectory.info and "isam2-online" not in methods:
            variants.append(("isam2-online", trajectory.info["online"]))
        for name, traj in variants:
            if case.truth is not None:
                errors = _truth_errors(traj, case.truth, case.dataset.t0, case.windows)
            else:
                errors = errors_against(
                    traj,
                    case.dataset.gnss.t,
                    case.dataset.gnss_enu(),
                    case.dataset.t0,
                    case.windows,
                    reference_std=position_sigmas(case.dataset.gnss, case.config.gnss),
                )
            metrics = errors.summary()
            if case.truth is not None:
                reference_t, reference_enu = case.truth.t, case.truth.position
            else:
                reference_t, reference_enu = case.dataset.gnss.t, case.dataset.gnss_enu()
            metrics["rpe_100m"] = relative_position_error(traj, reference_t, reference_enu)
            ends = end_of_outage_errors(errors, case.dataset.t0, case.windows)
            metrics["h_end_outage_mean"] = float(np.mean(ends)) if ends else float("nan")
            metrics["imu_samples_per_s"] = len(case.dataset.imu) / wall
            if case.truth is not None:
                metrics.update(_attitude_bias_errors(traj, case.truth))
            per_window = [
                {"window": [float(a), float(b)],
                 **errors.window(in_windows(errors.t, case.dataset.t0, [(a, b)]))}
                for a, b in case.windows
            ]  # fmt: skip
            case.results.append(MethodResult(name, metrics, wall, errors, traj, per_window))
    return case


def window_table(cases: list[BenchCase]) -> str:
    """Each window's horizontal RMS (m), its share inside the 3-sigma ellipse and its
    horizontal NEES (about 1 where the sigmas are honest), a column per method: a window
    where a method is worse, or its sigmas dishonest, is not averaged away."""
    lines: list[str] = []
    for case in cases:
        if not case.results or len(case.windows) < 2:
            continue  # one window: the main table's row is that window's
        methods = [r.method for r in case.results]
        lines += [
            f"| {case.name}: window (s) | " + " | ".join(f"{m}: h RMS (m), in 3σ, NEES" for m in methods) + " |",
            "|---|" + "---|" * len(methods),
        ]
        for i, (start, end) in enumerate(case.windows):
            cells = []
            for result in case.results:
                w = result.windows[i] if i < len(result.windows) else {}
                if "h_rms" not in w:
                    cells.append("n/a")
                    continue
                inside = f"{100 * w['within_3sigma']:.0f}%" if np.isfinite(w["within_3sigma"]) else "n/a"
                nees = f"{w['nees_h']:.1f}" if np.isfinite(w.get("nees_h", np.nan)) else "n/a"
                cells.append(f"{w['h_rms']:.2f}, {inside}, {nees}")
            lines.append(f"| {start:g}:{end:g} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines).rstrip()


def _attitude_bias_errors(trajectory: Trajectory, truth: Trajectory) -> dict[str, float]:
    rows = np.clip(np.searchsorted(truth.t, trajectory.t), 0, len(truth.t) - 1)
    est = trajectory.roll_pitch_heading_deg()
    ref = truth.roll_pitch_heading_deg()[rows]
    diff = (est - ref + 180.0) % 360.0 - 180.0
    out = {
        "roll_pitch_rms_deg": float(np.sqrt(np.mean(diff[:, :2] ** 2))),
        "heading_rms_deg": float(np.sqrt(np.mean(diff[:, 2] ** 2))),
    }
    if np.all(np.isfinite(trajectory.gyro_bias)) and np.all(np.isfinite(truth.gyro_bias)):
        out["gyro_bias_rms_deg_h"] = float(
            np.degrees(np.sqrt(np.mean((trajectory.gyro_bias - truth.gyro_bias[rows]) ** 2))) * 3600
        )
        out["accel_bias_rms_mg"] = float(
            np.sqrt(np.mean((trajectory.accel_bias - truth.accel_bias[rows]) ** 2)) / 9.80665e-3
        )
    return out


# Benchmark table: (column, unit-suffixed name, metric key or None for computed columns).
FRAME_COLUMNS = (
    "case", "method", "h_rms_outage_m", "h_max_outage_m", "h_end_outage_m", "h_rms_aided_m",
    "rpe_100m_m", "within_3sigma_outage", "wall_s", "imu_samples_per_s", "rms_ratio", "error",
)  # fmt: skip


def results_frame(cases: list[BenchCase], baseline: str = "ekf"):  # -> pandas.DataFrame
    """One row per case and method (:data:`FRAME_COLUMNS`); ``rms_ratio`` is the outage RMS
    over ``baseline``'s in the same case (NaN without it). A method that produced no result
    is a row of NaN metrics whose ``error`` says why (None on the others)."""
    import pandas as pd

    rows = []
    for case in cases:
        reference = next((r for r in case.results if r.method == baseline), None)
        for result in case.results:
            m = result.metrics
            ratio = (
                m["h_rms_outage"] / reference.metrics["h_rms_outage"]
                if reference is not None and reference.metrics["h_rms_outage"] > 0
                else float("nan")
            )
            rows.append(
                (
                    case.name, result.method, m["h_rms_outage"], m["h_max_outage"],
                    m["h_end_outage_mean"], m["h_rms_aided"], m.get("rpe_100m", float("nan")),
                    m.get("within_3sigma_outage", float("nan")), result.wall_s,
                    m["imu_samples_per_s"], ratio, None,
                )
            )  # fmt: skip
        nan = float("nan")
        for method, why in case.failed.items():
            rows.append((case.name, method, *[nan] * 9, why))
    return pd.DataFrame(rows, columns=list(FRAME_COLUMNS))


def frame_to_markdown(frame, baseline: str = "ekf") -> str:
    """The benchmark table (from :func:`results_frame`) as markdown, as ``fgins bench`` prints it."""
    lines = [
        "| case | method | h RMS outage (m) | h max outage (m) | h end (m) | h RMS aided (m) | "
        f"RPE/100 m (m) | in 3σ | wall (s) | IMU samples/s | RMS / {baseline} |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in frame.itertuples(index=False):
        error = getattr(row, "error", None)
        if isinstance(error, str):
            # A method that produced no result: the row says why, its numbers are n/a.
            why = "failed: " + " ".join(error.split()).replace("|", "\\|")
            lines.append(f"| {row.case} | {row.method} | {why} |" + " n/a |" * 8)
            continue
        ratio = f"{row.rms_ratio:.2f}" if np.isfinite(row.rms_ratio) else "n/a"
        lines.append(
            f"| {row.case} | {row.method} | {row.h_rms_outage_m:.2f} | {row.h_max_outage_m:.2f} | "
            f"{row.h_end_outage_m:.2f} | {row.h_rms_aided_m:.2f} | {row.rpe_100m_m:.2f} | "
            f"{100 * row.within_3sigma_outage:.0f}% | {row.wall_s:.2f} | "
            f"{row.imu_samples_per_s:,.0f} | {ratio} |"
        )
    return "\n".join(lines)


def markdown_table(cases: list[BenchCase], baseline: str = "ekf") -> str:
    """One row per case and method; ratios against ``baseline`` in the same case; then a
    line for each window left out of the scores, with why."""
    lines = [frame_to_markdown(results_frame(cases, baseline), baseline)]
    if per_window := window_table(cases):
        lines.append("\n" + per_window)
    for case in cases:
        for (start, end), why in case.left_out:
            lines.append(f"\n{case.name}: window {start:g}:{end:g} s left out of the scores: {why}")
    return "\n".join(lines)


#: The files ``fgins bench -o DIR`` writes besides one ``<case>.png`` per case.
BENCH_FILES = ("outages.json", "outages.md")


def _earlier_cases(folder: Path) -> list[str] | None:
    """The cases of the ``outages.json`` an earlier ``fgins bench`` wrote in ``folder``, or
    None when it holds none (or one that is not a benchmark's)."""
    import json

    try:
        payload = json.loads((folder / "outages.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(payload, dict) or not all(
        isinstance(v, dict) and "methods" in v for v in payload.values()
    ):
        return None
    return [str(name) for name in payload]


def check_bench_dir(out_dir: str | Path, cases: list[str] | tuple[str, ...] = ()) -> None:
    """``out_dir`` may receive a benchmark: a new or empty folder, or one an earlier
    ``fgins bench`` wrote (its outages.json, outages.md and case plots, replaced by this run's:
    an earlier case's plot is removed, never left beside another run's table). Anything else
    in it is not the benchmark's to replace: an :class:`OutputError`, before any work (as
    ``fgins sim`` treats its folder). ``cases``: this run's case names (their plots)."""
    from fgins.datatypes import OutputError
    from fgins.io.atomic import check_command_folder

    folder = Path(out_dir)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder; choose another -o")
    if not folder.is_dir():
        return
    earlier = _earlier_cases(folder)
    own = {*BENCH_FILES, *(f"{c}.png" for c in [*(earlier or []), *cases])}
    check_command_folder(folder, "bench", own, earlier is not None, "benchmark")


def write_results(cases: list[BenchCase], out_dir: Path, baseline: str = "ekf") -> None:
    from fgins.bench.plots import plot_outage_errors

    check_bench_dir(out_dir, [case.name for case in cases])
    earlier = _earlier_cases(out_dir) or []
    out_dir.mkdir(parents=True, exist_ok=True)
    payload = {
        case.name: {
            "windows": case.windows,
            "reference": "truth" if case.truth is not None else "withheld GNSS",
            "methods": {
                **{
                    r.method: {**r.metrics, "wall_s": r.wall_s, "warnings": r.warnings, "windows": r.windows}
                    for r in case.results
                },
                # A method that produced no result: recorded with why, not left out.
                **{method: {"error": why} for method, why in case.failed.items()},
            },
            "windows_left_out": [
                {"window": list(window), "why": why} for window, why in case.left_out
            ],
        }
        for case in cases
    }
    write_json(out_dir / "outages.json", payload)  # NaN (an unknown metric) as null
    with atomic_path(out_dir / "outages.md") as tmp:
        tmp.write_text(markdown_table(cases, baseline) + "\n")
    for case in cases:
        plot_outage_errors(case, out_dir / f"{case.name}.png")
    # An earlier run's plots of other cases: not this benchmark's, not left beside it.
    for name in set(earlier) - {case.name for case in cases}:
        (out_dir / f"{name}.png").unlink(missing_ok=True)


@dataclass
class SweepResult:
    """Mean horizontal error at the end of the outages, per method, per outage length."""

    name: str
    lengths: list[float]
    end_error: dict[str, list[float]]
    rms_error: dict[str, list[float]]


def outage_length_sweep(
    name: str,
    dataset: Dataset,
    config: RunConfig,
    methods: list[str],
    lengths: list[float],
    *,
    truth: Trajectory | None = None,
    start_s: float = 60.0,
    gap_s: float = 60.0,
) -> SweepResult:
    """Error growth with outage length: for each length L, windows of L seconds every
    L + gap_s seconds from start_s; every method sees the same windows."""
    from fgins.outages import periodic_windows

    span = float(dataset.gnss.t[-1] - dataset.t0)
    result = SweepResult(name, list(lengths), {}, {})
    for length in lengths:
        windows = periodic_windows(length, length + gap_s, start_s, span)
        case = run_case(
            BenchCase(f"{name}-{length:g}s", dataset, config, windows, truth=truth), methods
        )
        for method_result in case.results:
            result.end_error.setdefault(method_result.method, []).append(
                method_result.metrics["h_end_outage_mean"]
            )
            result.rms_error.setdefault(method_result.method, []).append(
                method_result.metrics["h_rms_outage"]
            )
    return result


def sweep_table(sweep: SweepResult) -> str:
    """Two markdown tables: RMS inside the outages, and the error at their end (the drift a
    filter has accumulated; a smoother is pinned there by the fixes after the outage)."""
    header = "| method | " + " | ".join(f"{length:g} s" for length in sweep.lengths) + " |"
    rule = "|---|" + "---|" * len(sweep.lengths)
    lines = []
    for title, table in (
        ("horizontal RMS inside the outages (m)", sweep.rms_error),
        ("horizontal error at the end of the outages (m), mean over windows", sweep.end_error),
    ):
        lines += [f"{sweep.name}: {title}", header, rule]
        lines += [
            f"| {m} | " + " | ".join(f"{e:.2f}" for e in errors) + " |"
            for m, errors in table.items()
        ]
        lines.append("")
    return "\n".join(lines)
