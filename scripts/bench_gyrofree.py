"""Gyro-free IMU benchmark: factor graph (batch) vs the 18-state EKF on ``gyrofree-cube``.

For each accelerometer grade x GNSS rate (1 Hz, 0.2 Hz), same seed, prints a markdown table
of horizontal / vertical position RMS, attitude RMS (vs truth) and wall time with the ratio
graph/EKF, then the degradation ratio 0.2 Hz / 1 Hz per grade and method.

    /work/venv/bin/python -m fgins.scripts.bench_gyrofree [--duration 120] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fgins.config import config_for_dataset
from fgins.datatypes import FginsError, Trajectory
from fgins.pipeline import run_method
from fgins.sim.accel_array import GRADES
from fgins.sim.scenarios import SCENARIOS

GNSS_RATES = (1.0, 0.2)
METHODS = ("batch", "ekf18")


def errors(estimate: Trajectory, truth: Trajectory) -> tuple[float, float, float]:
    """Horizontal and vertical position RMS (m), attitude RMS (deg) against the truth."""
    delta = estimate.position - truth.position
    horizontal = float(np.sqrt(np.mean(np.sum(delta[:, :2] ** 2, axis=1))))
    vertical = float(np.sqrt(np.mean(delta[:, 2] ** 2)))
    relative = estimate.rotation @ np.swapaxes(truth.rotation, 1, 2)
    cos_angle = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    attitude = float(np.degrees(np.sqrt(np.mean(np.arccos(cos_angle) ** 2))))
    return horizontal, vertical, attitude


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=120.0, help="drive length, s")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--half-edge", type=float, default=0.1, help="cube half-edge L, m (sigma_alpha ~ 1/L)"
    )
    args = parser.parse_args(argv)
    results: dict[tuple[str, float, str], tuple[float, float, float, float]] = {}
    print(
        f"gyrofree-cube, seed {args.seed}, {args.duration:g} s urban drive, "
        f"cube half-edge {args.half_edge:g} m\n"
    )
    print("| grade | GNSS Hz | method | horiz RMS m | vert RMS m | att RMS deg | time s |")
    print("|---|---|---|---|---|---|---|")
    for grade in GRADES:
        for rate in GNSS_RATES:
            run = SCENARIOS["gyrofree-cube"](
                args.seed,
                grade=grade,
                gnss_rate_hz=rate,
                duration_s=args.duration,
                half_edge_m=args.half_edge,
            )
            config = config_for_dataset(run.dataset)
            for method in METHODS:
                started = time.perf_counter()
                try:
                    estimate = run_method(run.dataset, config, method, progress=False)
                    h, v, a = errors(estimate, run.truth)
                except FginsError as exc:  # a failed run is a result, not a crash
                    print(f"| {grade} | {rate:g} | {method} | failed: {exc} | | | |")
                    continue
                wall = time.perf_counter() - started
                results[(grade, rate, method)] = (h, v, a, wall)
                print(
                    f"| {grade} | {rate:g} | {method} | {h:.2f} | {v:.2f} | {a:.2f} | {wall:.2f} |"
                )
            if all((grade, rate, m) in results for m in METHODS):
                g, e = results[(grade, rate, "batch")], results[(grade, rate, "ekf18")]
                ratios = " | ".join(f"{x / y:.2f}" for x, y in zip(g, e, strict=True))
                print(f"| {grade} | {rate:g} | ratio graph/EKF | {ratios} |")
    print("\nDegradation 0.2 Hz / 1 Hz GNSS (horizontal RMS ratio; > 1 means worse):\n")
    print("| grade | " + " | ".join(METHODS) + " |")
    print("|---|" + "---|" * len(METHODS))
    for grade in GRADES:
        cells = []
        for method in METHODS:
            slow, fast = results.get((grade, 0.2, method)), results.get((grade, 1.0, method))
            cells.append(f"{slow[0] / fast[0]:.2f}" if slow and fast else "n/a")
        print(f"| {grade} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
