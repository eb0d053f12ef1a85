#!/usr/bin/env python3
"""Speed of fgins (issue 9): KITTI against a hand-written GTSAM script, long drives, latency.

One run prints three tables, every method measured in its own child process (so peak RSS is
that run's own, read from the child's ``getrusage`` at its end, and no run warms another):

(a) KITTI (``demo:kitti``, car constraints on): fgins batch, iSAM2 and the forward EKF beside
    the plain GTSAM batch script ``scripts/gtsam_reference.py``: wall time, IMU samples/s,
    ratios fgins/reference and fgins/EKF, the no-outage fit (horizontal RMS at the fixes)
    and the RMS inside a 150-180 s GNSS outage (against the withheld fixes).
(b) A simulated 200 Hz highway drive (car constraints on) of 10/20/40/60 min (``--durations``;
    ``--quick``: 10 and 20 only): wall time, peak RSS, samples/s for batch, iSAM2 and EKF, and
    the linearity ratio (wall time per minute of drive at the longest over the shortest).
(a') The same drive end to end, as a user runs it: the whole ``fgins smooth demo:kitti
    --method M -o out.csv`` process against the whole reference script process (median of
    ``--repeats`` runs).
(c) iSAM2 per-update latency p50/p99/max on KITTI and on the longest drive, from
    ``trajectory.timings["isam2_update_s"]`` ("n/a" when the smoother does not record it),
    and beside it the preintegration of each interval (``"isam2_preintegrate_s"``), which
    the smoother times apart: a real-time system integrates the samples as they arrive.

Wall time is that of ``fgins.pipeline.run_method`` (build, guess, solve, covariances, dense
output); module imports (like the reference script's ``import gtsam``) and data loading /
simulation are excluded (the drives are simulated once per duration
and handed to the method children as a pickle).

    python scripts/bench_speed.py [--quick] [--durations 10,20,40,60] [--methods batch,isam2,ekf]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
KITTI_OUTAGE = (150.0, 180.0)
SIM_RATE_HZ = 200.0
SIM_SEED = 0

# What bounds each method today (printed with the tables; revisit when the numbers move).
LIMITS = {
    "batch": "per-keyframe Python: the keyframe-EKF initial guess (~25 % of CPU on the 10 min "
    "drive: factor building, a ~30-column QR, ~1 ms a keyframe) and the rounds that rebuild the "
    "linearised NHC/antenna factors between LM runs (~30 %, LM itself in C++ ~10 %); GTSAM "
    "preintegration fed one sample per Python call (~3-5 us a sample, ~15 %); the dense "
    "IMU-rate output (~13 %)",
    "isam2": "GTSAM preintegration fed one sample per Python call (~5 us a sample, timed apart "
    "from the update as a real-time system would do it as samples arrive), per-update "
    "Python factor building (~0.9 ms, about three times the iSAM2 update itself) and the QR "
    "elimination (Cholesky calls update 1 indeterminate on both drives, so every run restarts "
    "on QR); the running iSAM2 holds a 10 s window (GTSAM's update is O(tree) otherwise): "
    "every 10th update re-eliminates the window to marginalise the oldest keyframes and sets "
    "the p99; the final pass rebuilds the whole graph ~3 times (one Gauss-Newton step each)",
    "ekf": "Python loop over ~1 s blocks: per-block Phi/Q tree reduction over every sample "
    "(15x15 batched matmuls), nominal propagation, GNSS/NHC updates; then the dense IMU-rate "
    "output (~0.8 KB per sample)",
    "gtsam-ref": "GTSAM C++ preintegration fed one sample per Python call, one LM solve",
}


# --- child processes -----------------------------------------------------------------------


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_s() -> float:
    """CPU seconds of this process (all threads): less sensitive than wall time to other
    processes sharing the cores."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _latency(trajectory) -> dict[str, float] | None:
    updates = trajectory.timings.get("isam2_update_s") if trajectory.timings else None
    if updates is None or len(updates) == 0:
        return None
    ms = 1e3 * np.asarray(updates, dtype=float)
    out = {
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "n": len(ms),
    }
    # The interval's preintegration, timed apart from the update (done as samples arrive).
    preintegrate = trajectory.timings.get("isam2_preintegrate_s")
    if preintegrate is not None and len(preintegrate):
        pre = 1e3 * np.asarray(preintegrate, dtype=float)[1:]
        out["preint_p50_ms"] = float(np.percentile(pre, 50))
        out["preint_p99_ms"] = float(np.percentile(pre, 99))
    return out


def make_highway(duration_s: float, path: Path) -> None:
    """Simulate the 200 Hz highway drive and pickle (dataset, truth t/position)."""
    from fgins.sim.scenarios import SCENARIOS

    try:  # the simulator's own rate option (branch sim), when present
        run = SCENARIOS["highway"](seed=SIM_SEED, duration_s=duration_s, imu_rate_hz=SIM_RATE_HZ)
    except Exception:  # older simulator: the same drive through the module API
        from fgins.sim import motion, scenarios

        base = scenarios.highway(seed=SIM_SEED, duration_s=1.0)
        gnss_model = scenarios.GnssModel(
            rate_hz=1.0,
            uere_m=2.5,
            lever_arm_m=(0.0, 0.0, 1.5),
            velocity_sigma_m_per_s=0.1,
            dop_stretches=(scenarios.DopStretch(150.0, 165.0, 2.5),),
        )
        run = scenarios._preset_run(
            "highway",
            SIM_SEED,
            {},
            preset="consumer-mems",
            profile=motion.highway(SIM_RATE_HZ, duration_s),
            origin=base.dataset.origin,
            gnss_model=gnss_model,
            description=f"highway {duration_s:.0f} s at {SIM_RATE_HZ:.0f} Hz",
        )
    every = max(1, round(SIM_RATE_HZ))  # truth at 1 Hz is enough for an RMS
    truth = {"t": run.truth.t[::every], "position": run.truth.position[::every]}
    with path.open("wb") as handle:
        pickle.dump({"dataset": run.dataset, "truth": truth}, handle, protocol=5)


def child(spec: dict) -> dict:
    """One method on one data set; returns the measurements (printed as one JSON line)."""
    from fgins.config import config_for_dataset
    from fgins.outages import outage_mask
    from fgins.pipeline import run_method

    if spec["data"] == "kitti":
        from fgins.io.kitti import read_kitti

        dataset, truth = read_kitti(), None
    else:
        with open(spec["data"], "rb") as handle:
            loaded = pickle.load(handle)
        dataset, truth = loaded["dataset"], loaded["truth"]
    config = config_for_dataset(dataset, vehicle="car")
    if truth is not None:
        # The simulator's IMU is mounted FLU, as the default says: state it, as a user who
        # knows the mounting would (a mounting nobody gave may cost one refining solve).
        from dataclasses import replace

        keys = config.explicit_smoother_keys | {"imu_to_vehicle_rpy_deg"}
        config = replace(config, explicit_smoother_keys=keys)
    windows = [tuple(spec["outage"])] if spec.get("outage") else []
    mask = outage_mask(dataset, windows) if windows else None
    # The reference script's time excludes its imports (gtsam) and file reading: so do ours.
    if spec["method"] in ("batch", "isam2", "isam2-online"):
        import fgins.graph.smoother
    else:
        import fgins.baseline.ekf  # noqa: F401
    rss_loaded = _peak_rss_mb()
    cpu = _cpu_s()
    started = time.perf_counter()
    trajectory = run_method(dataset, config, spec["method"], gnss_mask=mask, progress=False)
    wall = time.perf_counter() - started
    out: dict = {
        "wall_s": wall,
        "cpu_s": _cpu_s() - cpu,
        "imu_samples": len(dataset.imu),
        "drive_s": float(dataset.imu.t[-1] - dataset.imu.t[0]),
        "peak_rss_mb": _peak_rss_mb(),
        "rss_loaded_mb": rss_loaded,
        "latency": _latency(trajectory),
    }
    if truth is None:  # KITTI: against the fixes (used: the fit; withheld: the outage)
        from fgins.bench.metrics import errors_against

        summary = errors_against(
            trajectory, dataset.gnss.t, dataset.gnss_enu(), dataset.t0, windows
        ).summary()
        out["h_rms_fit"] = float(summary["h_rms_aided"])
        out["h_rms_outage"] = float(summary.get("h_rms_outage", float("nan")))
    else:
        estimate = trajectory.at(truth["t"])
        horizontal = np.linalg.norm((estimate - truth["position"])[:, :2], axis=1)
        out["h_rms_truth"] = float(np.sqrt(np.nanmean(horizontal**2)))
    return out


def _run_child(args: list[str], timeout: float) -> dict:
    """Run ``python bench_speed.py ARGS`` (or another script) and parse its last JSON line."""
    try:
        done = subprocess.run(
            [sys.executable, *args], capture_output=True, text=True, timeout=timeout, check=False
        )
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or not lines:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"exit {done.returncode}: {tail}"}
    return json.loads(lines[-1])


def run_method_child(data: str, method: str, outage, timeout: float) -> dict:
    spec = {"data": data, "method": method, "outage": list(outage) if outage else None}
    return _run_child([str(Path(__file__).resolve()), "--child", json.dumps(spec)], timeout)


# --- tables --------------------------------------------------------------------------------


def _fmt(value: float | None, spec: str) -> str:
    if value is None or not np.isfinite(value):
        return "n/a"
    return format(value, spec)


def kitti_table(methods: list[str], timeout: float) -> dict[str, dict]:
    results: dict[str, dict] = {}
    for method in methods:
        fit = run_method_child("kitti", method, None, timeout)
        outage = run_method_child("kitti", method, KITTI_OUTAGE, timeout)
        if "error" in fit or "error" in outage:
            results[method] = {"error": fit.get("error") or outage.get("error")}
            continue
        results[method] = {**fit, "h_rms_outage": outage["h_rms_outage"]}
    reference = HERE / "gtsam_reference.py"
    fit = _run_child([str(reference), "--json"], timeout)
    outage = _run_child(
        [str(reference), "--json", "--gnss-outage", f"{KITTI_OUTAGE[0]:g}:{KITTI_OUTAGE[1]:g}"],
        timeout,
    )
    if "error" in fit or "error" in outage:
        results["gtsam-ref"] = {"error": fit.get("error") or outage.get("error")}
    else:
        results["gtsam-ref"] = {**fit, "h_rms_outage": outage["h_rms_outage"]}

    ref_wall = results["gtsam-ref"].get("wall_s")
    ekf_wall = results.get("ekf", {}).get("wall_s")
    print(
        f"\n(a) demo:kitti, car constraints on; outage {KITTI_OUTAGE[0]:g}-{KITTI_OUTAGE[1]:g} s "
        "after t0 (each method in its own process)"
    )
    print(
        f"{'method':10s} {'wall s':>7s} {'CPU s':>7s} {'IMU samples/s':>14s} {'x ref':>6s} "
        f"{'x EKF':>6s} {'fit m':>7s} {'outage m':>9s} {'peak MB':>8s}"
    )
    for method, r in results.items():
        if "error" in r:
            print(f"{method:10s} failed: {r['error']}")
            continue
        wall = r["wall_s"]
        print(
            f"{method:10s} {wall:7.2f} {_fmt(r.get('cpu_s'), '7.2f')} "
            f"{r['imu_samples'] / wall:14,.0f} "
            f"{_fmt(wall / ref_wall if ref_wall else None, '6.2f')} "
            f"{_fmt(wall / ekf_wall if ekf_wall else None, '6.2f')} "
            f"{r['h_rms_fit']:7.3f} {r['h_rms_outage']:9.2f} {r['peak_rss_mb']:8.0f}"
        )
    print(
        "  fit: horizontal RMS at the fixes used, no outage; outage: RMS against the withheld "
        "fixes. gtsam-ref has no NHC and no robust GNSS (accuracy differs by design)."
    )
    return results


def end_to_end_table(methods: list[str], repeats: int, timeout: float) -> None:
    """Whole processes, as a user runs them (the issue's own measurement): ``fgins smooth
    demo:kitti --method M -o out.csv`` (interpreter start, imports, reading and checking the
    input, solve, covariances, the IMU-rate CSV) against ``python gtsam_reference.py``
    (interpreter start, ``import gtsam``, reading the files, build, solve, no output file)."""

    def timed(command: list[str]) -> float | None:
        walls = []
        for _ in range(repeats):
            started = time.perf_counter()
            try:
                done = subprocess.run(command, capture_output=True, timeout=timeout, check=False)
            except subprocess.TimeoutExpired:
                return None
            if done.returncode != 0:
                return None
            walls.append(time.perf_counter() - started)
        return float(np.median(walls))

    with tempfile.TemporaryDirectory(prefix="fgins-bench-") as tmp:
        walls = {}
        for method in methods:
            output = str(Path(tmp) / f"{method}.csv")
            command = ["smooth", "demo:kitti", "--method", method, "-o", output]
            walls[method] = timed([sys.executable, "-m", "fgins", *command])
    reference = timed([sys.executable, str(HERE / "gtsam_reference.py")])
    print(
        f"\n(a') demo:kitti end to end, whole processes as a user runs them (median of {repeats}): "
        "fgins smooth ... -o out.csv against python gtsam_reference.py"
    )
    print(f"{'command':22s} {'wall s':>7s} {'x ref':>6s}")
    for method, wall in walls.items():
        ratio = wall / reference if wall and reference else None
        print(f"{'fgins smooth ' + method:22s} {_fmt(wall, '7.2f')} {_fmt(ratio, '6.2f')}")
    print(f"{'gtsam_reference.py':22s} {_fmt(reference, '7.2f')} {_fmt(1.0, '6.2f')}")


def sim_table(durations_min: list[float], methods: list[str], timeout: float) -> dict:
    results: dict[float, dict[str, dict]] = {}
    with tempfile.TemporaryDirectory(prefix="fgins-bench-") as tmp:
        for minutes in durations_min:
            path = Path(tmp) / f"highway_{minutes:g}min.pkl"
            made = _run_child(
                [str(Path(__file__).resolve()), "--make-sim", str(60.0 * minutes), str(path)],
                timeout,
            )
            if "error" in made:
                results[minutes] = {m: made for m in methods}
                continue
            results[minutes] = {m: run_method_child(str(path), m, None, timeout) for m in methods}
            path.unlink(missing_ok=True)

    print(
        f"\n(b) simulated highway, {SIM_RATE_HZ:.0f} Hz consumer IMU, 1 Hz GNSS, car constraints "
        "on (each run in its own process; RSS = that process's peak, data included)"
    )
    print(
        f"{'minutes':>7s} {'method':8s} {'wall s':>8s} {'CPU s':>8s} {'s/min':>7s} {'IMU samples/s':>14s} "
        f"{'peak MB':>8s} {'data MB':>8s} {'RMS m':>7s}"
    )
    for minutes, by_method in results.items():
        for method, r in by_method.items():
            if "error" in r:
                print(f"{minutes:7g} {method:8s} failed: {r['error']}")
                continue
            wall = r["wall_s"]
            print(
                f"{minutes:7g} {method:8s} {wall:8.2f} {r['cpu_s']:8.2f} {wall / minutes:7.2f} "
                f"{r['imu_samples'] / wall:14,.0f} {r['peak_rss_mb']:8.0f} "
                f"{r['rss_loaded_mb']:8.0f} {r['h_rms_truth']:7.2f}"
            )
    if len(results) >= 2:
        short, long = min(results), max(results)
        print(f"linearity: wall time per minute at {long:g} min / at {short:g} min (1.0 = linear)")
        for method in methods:
            a, b = results[short].get(method, {}), results[long].get(method, {})
            if "wall_s" in a and "wall_s" in b:
                ratio = (b["wall_s"] / long) / (a["wall_s"] / short)
                cpu_ratio = (b["cpu_s"] / long) / (a["cpu_s"] / short)
                rss = (b["peak_rss_mb"] - b["rss_loaded_mb"]) / max(
                    a["peak_rss_mb"] - a["rss_loaded_mb"], 1.0
                )
                print(
                    f"  {method:8s} wall {ratio:5.2f}, CPU {cpu_ratio:5.2f}  (memory above the data: x{rss:.1f} for "
                    f"x{long / short:g} the drive)"
                )
    return results


def latency_table(kitti: dict, sim: dict) -> None:
    print(
        "\n(c) iSAM2 per-update latency (timings['isam2_update_s']: factors, update, estimate, "
        "online covariance),\n    and apart the interval's preintegration "
        "(timings['isam2_preintegrate_s'], done as the samples arrive)"
    )
    print(
        f"{'data':16s} {'updates':>8s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} "
        f"{'preint p50':>10s} {'preint p99':>10s}"
    )
    rows = [("demo:kitti", kitti.get("isam2", {}))]
    if sim:
        longest = max(sim)
        rows.append((f"highway {longest:g} min", sim[longest].get("isam2", {})))
    for name, r in rows:
        lat = r.get("latency") if "error" not in r else None
        if not lat:
            print(f"{name:16s} {'n/a':>8s} {'n/a':>8s} {'n/a':>8s} {'n/a':>8s}")
            continue
        print(
            f"{name:16s} {lat['n']:8d} {lat['p50_ms']:8.2f} {lat['p99_ms']:8.2f} "
            f"{lat['max_ms']:8.2f} {_fmt(lat.get('preint_p50_ms'), '10.2f')} "
            f"{_fmt(lat.get('preint_p99_ms'), '10.2f')}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="drives of 10 and 20 min only")
    parser.add_argument("--durations", help="drive lengths in minutes, e.g. 10,20,40,60")
    parser.add_argument("--methods", default="batch,isam2,ekf")
    parser.add_argument("--no-kitti", action="store_true", help="skip table (a)")
    parser.add_argument("--no-sim", action="store_true", help="skip table (b)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per end-to-end row")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per child run")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--make-sim", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    if args.make_sim:
        make_highway(float(args.make_sim[0]), Path(args.make_sim[1]))
        print(json.dumps({"ok": True, "peak_rss_mb": _peak_rss_mb()}))
        return

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if args.durations:
        durations = [float(x) for x in args.durations.split(",")]
    else:
        durations = [10.0, 20.0] if args.quick else [10.0, 20.0, 40.0, 60.0]
    load = os.getloadavg()[0]
    print(
        f"fgins bench_speed: {os.cpu_count()} CPUs, load average {load:.1f} at the start, "
        f"python {sys.version.split()[0]}"
    )
    if load > (os.cpu_count() or 1):
        print("  note: the machine is busy: wall times are inflated; compare the CPU column")
    kitti = {} if args.no_kitti else kitti_table(methods, args.timeout)
    if not args.no_kitti:
        end_to_end_table(methods, args.repeats, args.timeout)
    sim = {} if args.no_sim else sim_table(durations, methods, args.timeout)
    latency_table(kitti, sim)
    print("\nwhat limits each method:")
    for method in [*methods, "gtsam-ref"]:
        if method in LIMITS:
            print(f"  {method:9s} {LIMITS[method]}")


if __name__ == "__main__":
    main()
