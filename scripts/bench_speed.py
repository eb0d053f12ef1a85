#!/usr/bin/env python3
"""Speed of the smoothers on demo:kitti: wall time, IMU samples/s, peak memory.

Ratios are against the preintegration pass measured in the same run (the floor any
GTSAM-based method pays), so the numbers travel between machines.
"""

from __future__ import annotations

import argparse
import resource
import time

from fgins.config import load_config
from fgins.graph.problem import build_problem
from fgins.graph.smoother import smooth_batch, smooth_isam2
from fgins.io.kitti import read_kitti


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    dataset = read_kitti()
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    n = len(dataset.imu)
    rows = []
    for name in ("build+preintegrate", "batch (total)", "isam2 (total)"):
        best = float("inf")
        for _ in range(args.repeat):
            started = time.perf_counter()
            problem = build_problem(dataset, config, progress=False)
            if name.startswith("batch"):
                smooth_batch(problem, progress=False)
            elif name.startswith("isam2"):
                smooth_isam2(problem, progress=False)
            best = min(best, time.perf_counter() - started)
        rows.append((name, best))
    floor = rows[0][1]
    print(f"demo:kitti: {n} IMU samples, {dataset.imu.t[-1] - dataset.imu.t[0]:.0f} s of data")
    print(f"{'stage':22s} {'wall s':>8s} {'IMU samples/s':>14s} {'x preintegration':>17s}")
    for name, seconds in rows:
        print(f"{name:22s} {seconds:8.3f} {n / seconds:14,.0f} {seconds / floor:17.2f}")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"peak RSS {peak_mb:.0f} MB; real time factor of batch: {(dataset.imu.t[-1] - dataset.imu.t[0]) / rows[1][1]:.0f}x"
    )


if __name__ == "__main__":
    main()
