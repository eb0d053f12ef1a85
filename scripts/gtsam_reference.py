#!/usr/bin/env python3
"""A hand-written GTSAM batch smoother on the KITTI drive: the speed reference of issue 9.

Plain GTSAM, as in GTSAM's own python examples (``IMUKittiExampleGPS.py``,
``CombinedImuFactorExample.py``), and no fgins code at all: it reads the files that ship
inside the gtsam wheel (``KittiEquivBiasedImu.txt``, ``KittiGps_converted.txt`` and the
metadata), puts a keyframe at every GNSS epoch, a ``CombinedImuFactor`` between consecutive
keyframes (biases as random walks inside it), a ``GPSFactor`` at every epoch that is not
withheld, priors on the first state, and solves once with Levenberg-Marquardt.

The initial guess is what a script writer would do: GNSS position with the heading of the
differenced fixes where a fix is used, IMU prediction from the previous guess where one is
withheld. No non-holonomic constraint, no robust kernel, no lever arm (KITTI has none).

Prints one JSON line (``--json``) or a short summary: wall time of build + solve (file
reading excluded), IMU samples, horizontal RMS against the fixes used (the fit) and against
the withheld ones (the outage), peak RSS.

    python scripts/gtsam_reference.py [--gnss-outage 150:180] [--json]
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

GRAVITY = 9.8  # the GTSAM example's value
GPS_SIGMA = np.array([0.3, 0.3, 0.5])  # m: the fixes are smoothed RTK-like positions


def _data_file(name: str) -> Path:
    return Path(gtsam.findExampleDataFile(name))


def load_kitti() -> tuple[np.ndarray, ...]:
    """(imu_t, imu_dt, accel, gyro, metadata) and the GPS (t, xyz) of the wheel's KITTI files."""
    imu = np.loadtxt(_data_file("KittiEquivBiasedImu.txt"), skiprows=1)
    gps = np.loadtxt(_data_file("KittiGps_converted.txt"), skiprows=1, delimiter=",")
    meta = np.loadtxt(_data_file("KittiEquivBiasedImu_metadata.txt"), skiprows=1)
    # The first IMU row's dt is its absolute time (no previous sample): drop it.
    imu = imu[1:]
    return imu[:, 0], imu[:, 1], imu[:, 2:5], imu[:, 5:8], meta, gps


def imu_params(meta: np.ndarray) -> gtsam.PreintegrationCombinedParams:
    accel_sigma, gyro_sigma, integration_sigma, accel_bias_sigma, gyro_bias_sigma = meta[6:11]
    # The metadata's white-noise densities are optimistic for this drive (vibration): double
    # them, as fgins' KITTI preset does (0.02 m/s^2/sqrt(Hz), 3e-4 rad/s/sqrt(Hz)); with the
    # raw values the fit at the fixes is 0.80 m instead of 0.49 m.
    accel_sigma, gyro_sigma = 2.0 * accel_sigma, max(gyro_sigma, 3.0e-4)
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(GRAVITY)
    params.setAccelerometerCovariance(np.eye(3) * accel_sigma**2)
    params.setGyroscopeCovariance(np.eye(3) * gyro_sigma**2)
    params.setIntegrationCovariance(np.eye(3) * max(integration_sigma, 1e-4) ** 2)
    params.setBiasAccCovariance(np.eye(3) * accel_bias_sigma**2)
    params.setBiasOmegaCovariance(np.eye(3) * gyro_bias_sigma**2)
    return params


def yaw_rotation(direction: np.ndarray) -> gtsam.Rot3:
    if np.hypot(direction[0], direction[1]) < 0.5:
        return gtsam.Rot3()
    return gtsam.Rot3.Yaw(float(np.arctan2(direction[1], direction[0])))


def solve(withheld: tuple[float, float] | None) -> dict[str, float]:
    imu_t, imu_dt, accel, gyro, meta, gps = load_kitti()
    started = time.perf_counter()
    cpu = time.process_time()
    gps_t, gps_xyz = gps[:, 0], gps[:, 1:4]
    inside = (gps_t >= imu_t[0]) & (gps_t <= imu_t[-1])
    gps_t, gps_xyz = gps_t[inside], gps_xyz[inside]
    t0 = gps_t[0]
    used = np.ones(len(gps_t), bool)
    if withheld is not None:
        used &= ~((gps_t - t0 >= withheld[0]) & (gps_t - t0 < withheld[1]))
    params = imu_params(meta)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    gps_noise = gtsam.noiseModel.Diagonal.Sigmas(GPS_SIGMA)
    zero_bias = gtsam.imuBias.ConstantBias()

    # Initial guess of the first state: at the first fix, heading of the first motion.
    moved = np.flatnonzero(np.linalg.norm(gps_xyz - gps_xyz[0], axis=1) > 2.0)
    first_dir = gps_xyz[moved[0]] - gps_xyz[0] if len(moved) else np.zeros(3)
    state = gtsam.NavState(yaw_rotation(first_dir), gps_xyz[0], np.zeros(3))
    graph.add(
        gtsam.PriorFactorPose3(
            X(0),
            state.pose(),
            gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.3, 0.5, 0.5, 0.5])),
        )
    )
    graph.add(gtsam.PriorFactorVector(V(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    graph.add(
        gtsam.PriorFactorConstantBias(
            B(0), zero_bias, gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1] * 3 + [5e-3] * 3))
        )
    )
    values.insert(X(0), state.pose())
    values.insert(V(0), state.velocity())
    values.insert(B(0), zero_bias)
    graph.add(gtsam.GPSFactor(X(0), gps_xyz[0], gps_noise))

    # IMU samples between consecutive epochs: sample j is held over [t_j, t_j + dt_j).
    bounds = np.searchsorted(imu_t, gps_t)
    n_imu = 0
    for k in range(1, len(gps_t)):
        pim = gtsam.PreintegratedCombinedMeasurements(params, zero_bias)
        for j in range(bounds[k - 1], bounds[k]):
            pim.integrateMeasurement(accel[j], gyro[j], float(imu_dt[j]))
            n_imu += 1
        graph.add(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), pim))
        predicted = pim.predict(state, zero_bias)
        if used[k]:
            graph.add(gtsam.GPSFactor(X(k), gps_xyz[k], gps_noise))
            # Guess: the fix, with the velocity and heading of the differenced fixes.
            prev = k - 1 if used[k - 1] else k
            nxt = k + 1 if k + 1 < len(gps_t) and used[k + 1] else k
            velocity = (
                (gps_xyz[nxt] - gps_xyz[prev]) / (gps_t[nxt] - gps_t[prev])
                if nxt > prev
                else predicted.velocity()
            )
            state = gtsam.NavState(yaw_rotation(velocity), gps_xyz[k], velocity)
        else:
            state = predicted
        values.insert(X(k), state.pose())
        values.insert(V(k), state.velocity())
        values.insert(B(k), zero_bias)

    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(100)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()
    wall = time.perf_counter() - started
    cpu = time.process_time() - cpu
    position = np.array([result.atPose3(X(k)).translation() for k in range(len(gps_t))])
    horizontal = np.linalg.norm((position - gps_xyz)[:, :2], axis=1)

    def rms(mask: np.ndarray) -> float:
        return float(np.sqrt(np.mean(horizontal[mask] ** 2))) if mask.any() else float("nan")

    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "imu_samples": n_imu,
        "keyframes": len(gps_t),
        "h_rms_fit": rms(used),
        "h_rms_outage": rms(~used),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gnss-outage", metavar="A:B", help="withhold fixes A <= t - t0 < B")
    parser.add_argument("--json", action="store_true", help="print one JSON line")
    args = parser.parse_args()
    window = None
    if args.gnss_outage:
        a, b = (float(x) for x in args.gnss_outage.split(":"))
        window = (a, b)
    out = solve(window)
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"GTSAM reference on KITTI: {out['wall_s']:.2f} s, {out['imu_samples']} IMU samples, "
            f"{out['keyframes']} keyframes, fit {out['h_rms_fit']:.3f} m, "
            f"outage RMS {out['h_rms_outage']:.2f} m, peak RSS {out['peak_rss_mb']:.0f} MB"
        )


if __name__ == "__main__":
    main()
