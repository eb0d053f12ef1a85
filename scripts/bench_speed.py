#!/usr/bin/env python3
"""Speed of the smoothers on demo:kitti: wall time, IMU samples/s, peak memory.

Ratios are against the forward EKF measured in the same run (the classic real-time
baseline) and against the preintegration pass (the floor any GTSAM-based method pays).
"""

from __future__ import annotations

import argparse
import resource
import time

from fgins.baseline.ekf import run_ekf
from fgins.config import config_for_dataset
from fgins.graph.problem import build_problem
from fgins.graph.smoother import smooth_batch, smooth_isam2
from fgins.io.kitti import read_kitti


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3, help="best of N runs per stage")
    args = parser.parse_args()
    dataset = read_kitti()
    n = len(dataset.imu)
    span = dataset.imu.t[-1] - dataset.imu.t[0]
    rows = []
    for vehicle in ("car", "other"):
        config = config_for_dataset(dataset, vehicle=vehicle)
        stages = {
            "ekf (forward)": lambda config=config: run_ekf(dataset, config, progress=False),
            "build+preintegrate": lambda config=config: build_problem(dataset, config, progress=False),
            "batch (total)": lambda config=config: smooth_batch(build_problem(dataset, config, progress=False), progress=False),
            "isam2 (total)": lambda config=config: smooth_isam2(build_problem(dataset, config, progress=False), progress=False),
        }  # fmt: skip
        for name, stage in stages.items():
            best = float("inf")
            for _ in range(args.repeat):
                started = time.perf_counter()
                stage()
                best = min(best, time.perf_counter() - started)
            rows.append((vehicle, name, best))
    print(f"demo:kitti: {n} IMU samples, {span:.0f} s of data (best of {args.repeat})")
    print(
        f"{'constraints':12s} {'stage':20s} {'wall s':>7s} {'IMU samples/s':>14s} {'x EKF':>6s} {'x real time':>12s}"
    )
    for vehicle, name, seconds in rows:
        ekf = next(s for v, m, s in rows if v == vehicle and m.startswith("ekf"))
        label = "car (NHC)" if vehicle == "car" else "none"
        print(
            f"{label:12s} {name:20s} {seconds:7.3f} {n / seconds:14,.0f} {seconds / ekf:6.2f} {span / seconds:11.0f}x"
        )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
