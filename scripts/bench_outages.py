#!/usr/bin/env python3
"""Outage-bridging benchmark: factor graph (batch, iSAM2 final/online) vs Kalman baselines.

Runs every method on identical data and outages: demo:kitti (reference: the withheld GNSS)
and simulated scenarios (reference: truth). Prints a markdown table with ratios against the
forward EKF measured in the same run, and writes JSON + plots to --out.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fgins.bench.outages import (
    BenchCase,
    markdown_table,
    outage_length_sweep,
    run_case,
    sweep_table,
    write_results,
)
from fgins.bench.plots import plot_outage_sweep
from fgins.config import config_for_dataset
from fgins.pipeline import METHODS

KITTI_PROTOCOLS = {
    "30s": [(60, 90), (150, 180), (240, 270), (330, 360), (420, 450)],
    "60s": [(60, 120), (210, 270), (360, 420)],
}


def kitti_cases() -> list[BenchCase]:
    from fgins.io.kitti import read_kitti

    dataset = read_kitti()
    config = config_for_dataset(dataset)
    return [
        BenchCase(f"kitti-{name}", dataset, config, windows)
        for name, windows in KITTI_PROTOCOLS.items()
    ]


def sim_cases(names: list[str], seed: int) -> list[BenchCase]:
    from fgins.sim.scenarios import SCENARIOS

    cases = []
    for name in names:
        run = SCENARIOS[name](seed=seed)
        config = config_for_dataset(run.dataset)
        duration = run.dataset.gnss.t[-1] - run.dataset.t0
        # The scenario's own outages when it has them, else 30 s and 60 s windows.
        windows = run.outages or [
            (duration * 0.3, duration * 0.3 + 30),
            (duration * 0.65, duration * 0.65 + 60),
        ]
        # (Scenario outages are already removed from its GNSS; they are scored against truth.)
        cases.append(BenchCase(name, run.dataset, config, windows, truth=run.truth))
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--methods", default="batch,isam2,ekf,ekf-rts,ukf")
    parser.add_argument("--scenarios", default="car-urban,highway,aircraft-ekf,mems-car-pdop")
    parser.add_argument("--no-kitti", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument(
        "--sweep-methods", default="batch,ekf,ekf-rts",
        help="methods of the outage-length sweep (empty: no sweep)",
    )  # fmt: skip
    parser.add_argument("--sweep-lengths", default="10,30,60,90")
    args = parser.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    unknown = set(methods) - set(METHODS)
    if unknown:
        parser.error(f"unknown method(s) {', '.join(sorted(unknown))}")
    started = time.perf_counter()
    cases = [] if args.no_kitti else kitti_cases()
    cases += sim_cases([s for s in args.scenarios.split(",") if s], args.seed)
    for case in cases:
        print(
            f"running {case.name} ({len(case.dataset.imu)} IMU samples, outages {case.windows})",
            flush=True,
        )
        run_case(case, methods)
    print()
    print(markdown_table(cases, baseline="ekf"))
    write_results(cases, args.out, baseline="ekf")
    sweep_methods = [m for m in args.sweep_methods.split(",") if m]
    if sweep_methods:
        lengths = [float(x) for x in args.sweep_lengths.split(",")]
        sweep_cases = [c for c in cases if c.name in ("kitti-30s", "car-urban")]
        for case in sweep_cases:
            name = case.name.split("-30s")[0]
            print(f"\noutage-length sweep on {name} ({', '.join(sweep_methods)})", flush=True)
            sweep = outage_length_sweep(
                name, case.dataset, case.config, sweep_methods, lengths, truth=case.truth
            )
            print(sweep_table(sweep))
            plot_outage_sweep(sweep, args.out / f"{name}-sweep.png")
    print(f"\nbenchmark wall time {time.perf_counter() - started:.1f} s; results in {args.out}/")


if __name__ == "__main__":
    main()
