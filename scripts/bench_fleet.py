"""Parallel speed-up of `fgins fleet` against smoothing the same drives one after another.

    python scripts/bench_fleet.py [--drives 6] [--duration 120] [--workers N] [--method batch]

Simulates N highway drives, smooths them serially in this process (the baseline, measured in
the same run), then as a fleet on a local Dask cluster, and prints both speed-ups: against the
serial wall time, and against the sum of the fleet's own per-drive times.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from fgins.fleet import FleetOptions, expand_drives, run_fleet, smooth_drive, timing_line
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import write_sim_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--drives", type=int, default=6)
    parser.add_argument("--duration", type=float, default=120.0, help="seconds per drive")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--method", default="batch")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="fgins_fleet_bench_") as tmp:
        root = Path(tmp)
        folders = []
        for seed in range(args.drives):
            folder = root / f"highway{seed}"
            write_sim_dir(SCENARIOS["highway"](seed=seed, duration_s=args.duration), folder)
            folders.append(str(folder))
        drives = expand_drives(folders)
        options = FleetOptions(method=args.method)

        started = time.perf_counter()
        serial = [smooth_drive(d, options, str(root / "serial")) for d in drives]
        serial_wall = time.perf_counter() - started
        assert not any(s["error"] for s in serial), [s["error"] for s in serial]

        result = run_fleet(drives, options, root / "fleet", workers=args.workers, progress=False)
        assert not result.failed, [s["error"] for s in result.failed]

    with_start = result.wall_seconds + result.startup_seconds
    print(
        f"{args.drives} highway drives of {args.duration:g} s, method {args.method}, "
        f"{result.workers} workers on {os.cpu_count()} CPUs"
    )
    print(f"serial, one process:   {serial_wall:.2f} s")
    print(timing_line(result))
    print(
        f"speed-up vs serial:    {serial_wall / result.wall_seconds:.2f}x "
        f"({serial_wall / with_start:.2f}x counting the {result.startup_seconds:.2f} s "
        "cluster start)"
    )


if __name__ == "__main__":
    main()
