#!/usr/bin/env python3
"""Evidence for the land-vehicle model on ``demo:kitti``: what a real car's IMU-frame velocity
does, from the all-GNSS batch solution (issue 12 item 7).

Solves the whole drive with all GNSS twice, with the car constraints and without
(``use_nhc = use_zupt = false``; its lateral/vertical velocity is what the NHC would see as
residual, not forced to zero). For each it prints, over samples at 10 Hz with speed > 3 m/s:

* lateral velocity fit ``v_lat = a + b v_fwd + x w_z + k w_z v_fwd``: ``b`` is a yaw
  misalignment (rad), ``x`` the IMU's forward offset from the non-holonomic point (m; lateral
  velocity at the IMU is w_z x), ``k`` a slip gain (s; slip velocity per lateral acceleration);
* vertical: ``v_up = a + b v_fwd`` (``b`` a pitch misalignment);
* the heading change across each suspect (interpolated) IMU stretch: solution vs gyro
  integral (how wrong the interpolated gyro is);
* the ZUPT keyframes (none on this drive) and the slowest GNSS speeds.

and plots lateral velocity against yaw rate x speed (lateral acceleration), and against yaw
rate, and vertical velocity against speed. ``--set KEY=VALUE`` changes [smoother] settings of
both solves (e.g. ``suspect_noise_factor=300``).
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

import numpy as np

from fgins.config import config_for_dataset
from fgins.pipeline import run_method


def body_series(dataset, trajectory, min_speed: float = 3.0, every: int = 10) -> dict:
    """Body-frame velocity, bias-corrected yaw rate (1 s mean) at 1/every of the samples."""
    vb = np.einsum("nji,nj->ni", trajectory.rotation, trajectory.velocity)
    gyro = np.interp(trajectory.t, dataset.imu.t, dataset.imu.gyro[:, 2])
    wz = gyro - (trajectory.gyro_bias[:, 2] if trajectory.gyro_bias is not None else 0.0)
    kernel = np.ones(101) / 101  # 1 s at 100 Hz: the keyframe-to-keyframe scale
    wz = np.convolve(wz, kernel, mode="same")
    pick = np.arange(100, len(trajectory.t) - 100, every)
    out = {"t": trajectory.t[pick] - dataset.t0, "vf": vb[pick, 0], "vl": vb[pick, 1],
           "vu": vb[pick, 2], "wz": wz[pick]}
    moving = out["vf"] > min_speed
    return {key: value[moving] for key, value in out.items()}


def fits(s: dict) -> dict[str, float]:
    a = np.column_stack([np.ones_like(s["vf"]), s["vf"], s["wz"], s["wz"] * s["vf"]])
    c, *_ = np.linalg.lstsq(a, s["vl"], rcond=None)
    residual = s["vl"] - a @ c
    b = np.column_stack([np.ones_like(s["vf"]), s["vf"]])
    d, *_ = np.linalg.lstsq(b, s["vu"], rcond=None)
    return {
        "lat_rms": float(np.sqrt(np.mean(s["vl"] ** 2))), "lat_p99": float(np.percentile(abs(s["vl"]), 99)),
        "lat_a": c[0], "yaw_mis_deg": float(np.degrees(c[1])), "lever_x_m": c[2], "slip_k_s": c[3],
        "lat_resid_rms": float(residual.std()),
        "up_rms": float(np.sqrt(np.mean(s["vu"] ** 2))), "up_mean": float(s["vu"].mean()),
        "pitch_mis_deg": float(np.degrees(d[1])), "up_resid_rms": float(np.std(s["vu"] - b @ d)),
    }


def stretch_table(dataset, trajectory) -> list[tuple[float, float, float, float]]:
    """(start, length, solution yaw change, gyro-integral yaw change) per suspect stretch."""
    rows = []
    t = trajectory.t
    rotation = trajectory.rotation
    for a, b in dataset.imu.suspect:
        ia, ib = np.searchsorted(t, a), min(np.searchsorted(t, b), len(t) - 1)
        if ia == 0:
            continue
        yaw = np.degrees(np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0]))
        change = (yaw[ib] - yaw[ia] + 180) % 360 - 180
        inside = (dataset.imu.t >= t[ia]) & (dataset.imu.t < t[ib])
        dt = np.gradient(dataset.imu.t)[inside]
        bias = trajectory.gyro_bias[ia, 2] if trajectory.gyro_bias is not None else 0.0
        integral = float(np.degrees(np.sum((dataset.imu.gyro[inside, 2] - bias) * dt)))
        rows.append((a - dataset.t0, b - a, float(change), integral))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=Path("out/kitti_nhc"))
    args = parser.parse_args()
    from fgins.io.inputs import load_dataset

    dataset = load_dataset(["demo:kitti"], progress=False)
    series = {}
    for name in ("car", "no-car"):
        config = config_for_dataset(dataset, vehicle="car")
        for item in args.set:
            key, _, text = item.partition("=")
            setattr(config.smoother, key, ast.literal_eval(text))
        if name == "no-car":
            config.smoother.use_nhc = config.smoother.use_zupt = False
        trajectory = run_method(dataset, config, "batch", progress=False)
        s = body_series(dataset, trajectory)
        series[name] = s
        f = fits(s)
        print(f"== all-GNSS batch, {name}: ZUPT keyframes {trajectory.info.get('zupt_keyframes')}")
        print(f"  lateral velocity: RMS {f['lat_rms']:.3f} m/s, |.| p99 {f['lat_p99']:.3f}; fit a "
              f"{f['lat_a']:.3f} m/s, yaw misalignment {f['yaw_mis_deg']:.2f} deg, lever x "
              f"{f['lever_x_m']:.2f} m, slip k {f['slip_k_s']:.4f} s; residual RMS "
              f"{f['lat_resid_rms']:.3f}")
        print(f"  vertical velocity: RMS {f['up_rms']:.3f}, mean {f['up_mean']:.3f} m/s; pitch "
              f"misalignment {f['pitch_mis_deg']:.2f} deg; residual RMS {f['up_resid_rms']:.3f}")
        print("  suspect IMU stretches (start s, length s): solution yaw change vs gyro integral")
        for start, length, change, integral in stretch_table(dataset, trajectory):
            print(f"    {start:6.1f} ({length:.2f} s): {change:7.2f} vs {integral:7.2f} deg "
                  f"(gyro wrong by {change - integral:+.2f} deg)")
    gnss = dataset.gnss_enu()
    speed = np.linalg.norm(np.diff(gnss[:, :2], axis=0), axis=1) / np.diff(dataset.gnss.t)
    slow = np.argsort(speed)[:5]
    print("slowest GNSS speeds (m/s at s): " + ", ".join(
        f"{speed[i]:.2f} at {dataset.gnss.t[i] - dataset.t0:.0f}" for i in slow))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    for name, s in series.items():
        axes[0].plot(s["wz"] * s["vf"], s["vl"], ".", ms=1.5, alpha=0.5, label=name)
        axes[1].plot(np.degrees(s["wz"]), s["vl"], ".", ms=1.5, alpha=0.5, label=name)
        axes[2].plot(s["vf"], s["vu"], ".", ms=1.5, alpha=0.5, label=name)
    axes[0].set_xlabel("yaw rate x forward speed (m/s^2)")
    axes[0].set_ylabel("IMU-frame lateral velocity (m/s)")
    axes[1].set_xlabel("yaw rate (deg/s)")
    axes[1].set_ylabel("IMU-frame lateral velocity (m/s)")
    axes[2].set_xlabel("forward speed (m/s)")
    axes[2].set_ylabel("IMU-frame vertical velocity (m/s)")
    for ax in axes:
        ax.axhline(0.1, color="r", ls="--", lw=0.8)
        ax.axhline(-0.1, color="r", ls="--", lw=0.8)
        ax.legend(markerscale=6)
    fig.suptitle("demo:kitti all-GNSS batch: IMU-frame velocity the NHC sees (red: 0.1 m/s)"
                 + (f" {args.set}" if args.set else ""))
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / "kitti_nhc_residuals.png", dpi=110)
    print(f"wrote {args.out / 'kitti_nhc_residuals.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
