"""TUM output read by evo (an independent evaluator): files, APE and RPE agree with fgins.

evo's own reader, association and metrics are the independent side; fgins writes the files
(``Trajectory.write``, ``fgins convert -o ref.tum``) and computes its metrics
(``fgins.bench.metrics``) on its in-memory trajectory.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.bench.metrics import errors_against, relative_position_error
from fgins.cli import main
from fgins.datatypes import Origin, Trajectory
from fgins.io.trajectory_csv import read_trajectory_csv

evo_trajectory = pytest.importorskip("evo.core.trajectory")
evo_metrics = pytest.importorskip("evo.core.metrics")
evo_sync = pytest.importorskip("evo.core.sync")
evo_files = pytest.importorskip("evo.tools.file_interface")


def _identity(traj):
    """The same positions and times with identity orientations (position-only metrics)."""
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (traj.num_poses, 1))  # evo: w, x, y, z
    return evo_trajectory.PoseTrajectory3D(
        positions_xyz=traj.positions_xyz, orientations_quat_wxyz=quat, timestamps=traj.timestamps
    )


def _evo_ape(ref, est) -> float:
    metric = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    metric.process_data((ref, est))
    return float(metric.get_statistic(evo_metrics.StatisticsType.rmse))


def _evo_rpe(ref, est, delta_m: float) -> float:
    metric = evo_metrics.RPE(
        evo_metrics.PoseRelation.translation_part,
        delta=delta_m,
        delta_unit=evo_metrics.Unit.meters,
        all_pairs=False,
        pairs_from_reference=True,
    )
    metric.process_data((_identity(ref), _identity(est)))
    return float(metric.get_statistic(evo_metrics.StatisticsType.rmse))


@pytest.fixture(scope="module", params=[("car-urban", 3, "batch"), ("highway", 11, "ekf-rts")])
def run(request, tmp_path_factory):
    scenario, seed, method = request.param
    folder = tmp_path_factory.mktemp("evo")
    drive = fgins.simulate(scenario, folder / "drive", duration=90, seed=seed)
    dataset = fgins.load(drive)
    track = fgins.smooth(dataset, method, gnss_outage=[(30, 60)])
    track.write(folder / "track.tum")
    truth = read_trajectory_csv(drive / "truth.csv", dataset.origin)
    truth.write(folder / "truth.tum")
    return folder, dataset, track, truth


def test_tum_file_is_what_evo_reads(run):
    folder, _, track, _ = run
    est = evo_files.read_tum_trajectory_file(str(folder / "track.tum"))
    # Full precision: times and positions round-trip exactly.
    assert np.array_equal(est.timestamps, track.t)
    assert np.array_equal(est.positions_xyz, track.position)
    # evo's quaternion -> matrix (its own conversion) gives back the body-to-ENU rotation.
    rotations = np.array([pose[:3, :3] for pose in est.poses_se3])
    np.testing.assert_allclose(rotations, track.rotation, atol=1e-12)
    header = (folder / "track.tum").read_text().splitlines()[:2]
    assert header[0].startswith("# fgins trajectory") and "ENU" in header[1]


def test_evo_ape_agrees_with_fgins_against_truth(run):
    folder, dataset, track, truth = run
    ref = evo_files.read_tum_trajectory_file(str(folder / "truth.tum"))
    est = evo_files.read_tum_trajectory_file(str(folder / "track.tum"))
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=1e-3)
    evo_rmse = _evo_ape(ref, est)
    # fgins: errors at the truth's epochs (the trajectory interpolated there).
    errors = errors_against(track, truth.t, truth.position, dataset.t0, [(30, 60)])
    fgins_rmse = float(np.sqrt(np.mean(errors.horizontal**2 + errors.vertical**2)))
    assert fgins_rmse > 0.05  # a real error, not a trajectory compared with itself
    assert evo_rmse == pytest.approx(fgins_rmse, rel=0.01)


def test_evo_rpe_agrees_with_fgins(run):
    folder, _, track, truth = run
    ref = evo_files.read_tum_trajectory_file(str(folder / "truth.tum"))
    est = evo_files.read_tum_trajectory_file(str(folder / "track.tum"))
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=1e-3)
    # Every 10th pose (10 Hz): evo's pair search is a Python loop over poses.
    ids = np.arange(0, ref.num_poses, 10)
    ref.reduce_to_ids(ids)
    est.reduce_to_ids(ids)
    for delta in (50.0, 100.0):
        ours = relative_position_error(track, truth.t[::10], truth.position[::10], delta)
        assert np.isfinite(ours) and ours > 0
        assert _evo_rpe(ref, est, delta) == pytest.approx(ours, rel=0.01)


def test_rpe_closed_form():
    """Straight line at 10 m/s; an estimate with a 1 % scale error and an offset: every 100 m
    segment is 1 m too long, whatever the offset (RPE ignores it)."""
    t = np.arange(0.0, 100.0, 0.01)
    ref = np.column_stack([10.0 * t, np.zeros_like(t), np.zeros_like(t)])
    rotation = np.broadcast_to(np.eye(3), (t.size, 3, 3))
    est = Trajectory(
        t=t, position=1.01 * ref + [5.0, -3.0, 2.0], velocity=np.zeros((t.size, 3)),
        rotation=rotation, origin=Origin(0.0, 0.0, 0.0),
    )  # fmt: skip
    assert relative_position_error(est, t, ref, 100.0) == pytest.approx(1.0, rel=1e-9)
    assert relative_position_error(est, t, ref, 250.0) == pytest.approx(2.5, rel=1e-9)
    # Shorter than one segment: no value.
    assert np.isnan(relative_position_error(est, t[:50], ref[:50], 100.0))


@pytest.fixture(scope="module")
def csv_pair_run(tmp_path_factory):
    """A CSV pair (origin = first fix, as for NMEA/MCAP), smoothed and converted by the CLI."""
    folder = tmp_path_factory.mktemp("evo_cli")
    drive = fgins.simulate("car-urban", folder / "drive", duration=80, seed=5)
    imu, gnss = str(drive / "imu.csv"), str(drive / "gnss.csv")
    assert main(["smooth", imu, gnss, "--method", "ekf-rts", "--gnss-outage", "30:50",
                 "-o", str(folder / "track.tum"), "--no-progress"]) == 0  # fmt: skip
    assert main(["convert", gnss, "-o", str(folder / "ref.tum")]) == 0
    dataset = fgins.load(imu, gnss)
    track = fgins.smooth(dataset, "ekf-rts", gnss_outage=[(30, 50)])
    return folder, dataset, track


def test_convert_writes_the_fixes_as_a_tum_reference(csv_pair_run):
    folder, dataset, _ = csv_pair_run
    ref = evo_files.read_tum_trajectory_file(str(folder / "ref.tum"))
    assert np.array_equal(ref.timestamps, dataset.gnss.t)
    np.testing.assert_allclose(ref.positions_xyz, dataset.gnss_enu(), atol=1e-9)
    np.testing.assert_array_equal(
        ref.orientations_quat_wxyz, [[1.0, 0.0, 0.0, 0.0]] * len(ref.timestamps)
    )


def test_evo_ape_on_gnss_reference_matches_fgins_metrics(csv_pair_run):
    folder, dataset, track = csv_pair_run
    ref = evo_files.read_tum_trajectory_file(str(folder / "ref.tum"))
    est = evo_files.read_tum_trajectory_file(str(folder / "track.tum"))
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=1e-3)
    errors = errors_against(track, dataset.gnss.t, dataset.gnss_enu(), dataset.t0, [(30, 50)])
    ours = float(np.sqrt(np.mean(errors.horizontal**2 + errors.vertical**2)))
    assert _evo_ape(ref, est) == pytest.approx(ours, rel=0.01)
    rpe = relative_position_error(track, dataset.gnss.t, dataset.gnss_enu())
    assert _evo_rpe(ref, est, 100.0) == pytest.approx(rpe, rel=0.01)


def test_evo_ape_command_on_files_fgins_wrote(csv_pair_run, tmp_path):
    folder, dataset, track = csv_pair_run
    command = shutil.which("evo_ape") or str(Path(sys.executable).with_name("evo_ape"))
    if not Path(command).exists():
        pytest.skip("evo_ape entry point not installed")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}  # evo keeps settings in ~
    result = subprocess.run(
        [command, "tum", str(folder / "ref.tum"), str(folder / "track.tum")],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rmse = float(re.search(r"^\s*rmse\s+([0-9.eE+-]+)", result.stdout, flags=re.M).group(1))
    errors = errors_against(track, dataset.gnss.t, dataset.gnss_enu(), dataset.t0, [(30, 50)])
    assert rmse == pytest.approx(
        float(np.sqrt(np.mean(errors.horizontal**2 + errors.vertical**2))), rel=0.01
    )


def test_bench_reports_rpe_beside_outage_errors(run):
    _, dataset, _, _ = run
    table = fgins.bench(dataset, methods=["ekf"], outages=[(30, 60)])
    assert np.isfinite(table["rpe_100m_m"][0]) and table["rpe_100m_m"][0] > 0


def test_the_demo_drives_tum_reference_is_in_the_frame_smooth_writes(tmp_path):
    """demo:kitti has its own origin, 13.7 m from its first fix: the README's evo recipe
    (`convert -o ref.tum`, `smooth -o track.tum`) read 13.7 m of error for a 0.14 m track
    when convert wrote about the first fix (outside tester)."""
    assert main(["convert", "demo:kitti", "-o", str(tmp_path / "ref.tum")]) == 0
    ref = evo_files.read_tum_trajectory_file(str(tmp_path / "ref.tum"))
    dataset = fgins.load("demo:kitti")
    np.testing.assert_allclose(ref.positions_xyz, dataset.gnss_enu(), atol=1e-6)
