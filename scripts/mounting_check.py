#!/usr/bin/env python3
"""IMU-to-vehicle mounting: the convention of ``imu_to_vehicle_rpy_deg``, and a check that a
wrong or missing mounting is flagged (issue 12 item 8).

A simulated urban car (``car-urban``, whose ``mounting_rpy_deg`` option turns the IMU in the
vehicle: R_vehicle_imu = Rz(yaw) Ry(pitch) Rx(roll) maps IMU-axis vectors into vehicle axes) is
solved by the batch smoother with the car constraints and a configured mounting; errors inside
two outages are scored against the simulator's truth. For every solve it prints two statistics
the summary can use, both computed from the solution alone:

``nhc_rms``  RMS over moving keyframes (speed > 3 m/s) of the vehicle-frame lateral and
             vertical velocity normalised by the NHC sigmas, with the mounting the solve used.
             ~<= 1 when the mounting is right; >> 1 when it is wrong (the constraint fights the
             IMU and GNSS).
``mount_err`` angle (deg) between the configured mounting and the mounting *estimated* from
             the same solution (:func:`estimate_mounting`): forward axis = mean direction of
             the body-frame velocity when speed > 5 m/s; up axis = mean of the navigation up
             direction in IMU axes (roads are level on average). Both need only R and v.

Examples::

    python scripts/mounting_check.py --quick
    python scripts/mounting_check.py --duration 300
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fgins.bench.metrics import errors_against
from fgins.config import config_for_dataset
from fgins.datatypes import FginsError
from fgins.outages import outage_mask
from fgins.pipeline import run_method


def rotation_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll) (degrees), = GTSAM Rot3.Ypr(yaw, pitch, roll)."""
    r, p, y = np.radians([roll, pitch, yaw])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def rpy_of(matrix: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_zyx` (degrees)."""
    pitch = -np.arcsin(np.clip(matrix[2, 0], -1.0, 1.0))
    roll = np.arctan2(matrix[2, 1], matrix[2, 2])
    yaw = np.arctan2(matrix[1, 0], matrix[0, 0])
    return tuple(float(x) for x in np.degrees([roll, pitch, yaw]))


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def estimate_mounting(
    rotation: np.ndarray, velocity: np.ndarray, min_speed: float = 5.0
) -> np.ndarray | None:
    """R_vehicle_imu from a solution: rotation (N,3,3) IMU->ENU, velocity (N,3) ENU.

    Vehicle x (forward) in IMU axes: the normalised mean of the unit body-frame velocity while
    the speed exceeds ``min_speed`` (a car moves along its x axis; slip averages out). Vehicle
    z (up) in IMU axes: the mean of R^T e_up over the same samples (road pitch/roll average
    out), made orthogonal to x. None when fewer than 50 samples are fast enough.
    """
    speed = np.linalg.norm(velocity, axis=1)
    moving = speed > min_speed
    if moving.sum() < 50:
        return None
    body = np.einsum("nji,nj->ni", rotation[moving], velocity[moving]) / speed[moving, None]
    forward = body.mean(axis=0)
    forward /= np.linalg.norm(forward)
    up = rotation[moving][:, 2, :].mean(axis=0)  # row 2 of R = e_up in IMU axes
    up -= forward * (up @ forward)
    up /= np.linalg.norm(up)
    left = np.cross(up, forward)
    imu_vehicle = np.column_stack([forward, left, up])  # vehicle axes in IMU coordinates
    return imu_vehicle.T  # R_vehicle_imu


def nhc_rms(
    rotation: np.ndarray, velocity: np.ndarray, vehicle_imu: np.ndarray,
    sigma: tuple[float, float], min_speed: float = 3.0,
) -> float:
    """RMS of vehicle-frame (lateral, vertical) velocity / NHC sigma over moving samples."""
    speed = np.linalg.norm(velocity, axis=1)
    moving = speed > min_speed
    body = np.einsum("nji,nj->ni", rotation[moving], velocity[moving])
    vehicle = body @ vehicle_imu.T
    normalised = vehicle[:, 1:3] / np.asarray(sigma)
    return float(np.sqrt(np.mean(normalised**2)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=240.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="convention cases only")
    parser.add_argument("--errors-only", action="store_true", help="mounting-error cases only")
    parser.add_argument("--fixed-convention", action="store_true",
                        help="the code reads imu_to_vehicle_rpy_deg as R_vehicle_imu (after the "
                             "issue-12 fix); default: today's code (reads it as R_imu_vehicle)")
    args = parser.parse_args()
    from fgins.sim.scenarios import SCENARIOS

    windows = [(80.0, 110.0), (170.0, 200.0)]
    mounted = (20.0, -10.0, 35.0)
    runs = {}
    for mounting in [(0.0, 0.0, 0.0), mounted]:
        runs[mounting] = SCENARIOS["car-urban"](
            seed=args.seed, duration_s=args.duration, mounting_rpy_deg=list(mounting),
            write_mounting=False,
        )
    inverse = rpy_of(rotation_zyx(*mounted).T)
    cases = [  # (sim mounting, configured angles, label)
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "unrotated, mounting 0"),
        (mounted, (0.0, 0.0, 0.0), "rotated, no car constraints (NHC/ZUPT off)"),
        (mounted, mounted, "rotated, its angles (as documented)"),
        (mounted, inverse, "rotated, inverse angles"),
        (mounted, (0.0, 0.0, 0.0), "rotated, mounting missing"),
    ]
    if args.errors_only:
        cases = []
    if not args.quick:
        true = rotation_zyx(*mounted)
        for axis, size in [("yaw", 5.0), ("yaw", 20.0), ("yaw", 90.0), ("pitch", 5.0),
                           ("roll", 20.0)]:
            error = {"roll": (size, 0, 0), "pitch": (0, size, 0), "yaw": (0, 0, size)}[axis]
            wrong = rotation_zyx(*error) @ true  # true mounting, then an error in vehicle axes
            angles = rpy_of(wrong if args.fixed_convention else wrong.T)
            cases.append((mounted, angles, f"rotated, {axis} error {size:g} deg"))
    print("| case | configured rpy (deg, as the code reads it) | outage RMS (m) | "
          "aided RMS (m) | nhc_rms | mount_err (deg) | est. rpy (deg) | time (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for sim_mounting, configured, label in cases:
        run = runs[sim_mounting]
        config = config_for_dataset(run.dataset, vehicle="car")
        config.smoother.imu_to_vehicle_rpy_deg = tuple(configured)
        if "no car constraints" in label:
            config.smoother.use_nhc = config.smoother.use_zupt = False
        started = time.perf_counter()
        try:
            trajectory = run_method(
                run.dataset, config, "batch", gnss_mask=outage_mask(run.dataset, windows),
                progress=False,
            )
        except FginsError as exc:  # the pre-solve mounting check (fgins.mounting) refused it
            print(f"| {label} | [{', '.join(f'{x:.1f}' for x in configured)}] | refused: "
                  f"{str(exc)[:160]} |", flush=True)  # fmt: skip
            continue
        elapsed = time.perf_counter() - started
        errors = errors_against(
            trajectory, run.truth.t, run.truth.position, run.dataset.t0, windows
        ).summary()
        # Today's code uses Ypr(angles) as R_imu_vehicle (v_vehicle = M^T v_imu).
        used_vehicle_imu = rotation_zyx(*configured)
        if not args.fixed_convention:
            used_vehicle_imu = used_vehicle_imu.T
        smoother = config.smoother
        sigma = (smoother.nhc_sigma_lateral_m_per_s, smoother.nhc_sigma_vertical_m_per_s)
        stat = nhc_rms(trajectory.rotation, trajectory.velocity, used_vehicle_imu, sigma)
        estimate = estimate_mounting(trajectory.rotation, trajectory.velocity)
        if estimate is None:
            err, est = float("nan"), "n/a"
        else:
            err = angle_between(estimate, used_vehicle_imu)
            est = "[" + ", ".join(f"{x:.1f}" for x in rpy_of(estimate)) + "]"
        print(f"| {label} | [{', '.join(f'{x:.1f}' for x in configured)}] | "
              f"{errors['h_rms_outage']:.2f} | {errors['h_rms_aided']:.2f} | {stat:.2f} | "
              f"{err:.1f} | {est} | {elapsed:.0f} |", flush=True)
    print(f"(true mounting of the rotated run: rpy {list(mounted)}; inverse angles "
          f"{[round(x, 2) for x in inverse]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
