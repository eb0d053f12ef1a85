"""GNSS fault exclusion (fgins.graph.gnss_faults): a run of multipath fixes is left out.

Found by mutating a drive's fixes: ten consecutive fixes 20 m off (an NLOS stretch in an
urban canyon) pulled batch, iSAM2 and EKF+RTS alike ~5 m off with the default Huber kernel,
while every reported sigma stayed ~0.6 m (NEES 34), exit code 0. The drives here come from
the independent car simulator (industrial IMU, 1 m fixes at 1 Hz, five turns); the faults
are fixes moved by a constant offset for 5-15 s, in turns and on straights, in every
direction. Each case is measured against the same drive without the fault, and against the
faulty drive with the exclusion off (what the kernel alone does), in the same run.
"""

from __future__ import annotations

import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import horizontal_errors, move_fixes, write_rtk_drive, write_turning_drive

STEPS = [(5, 5, 12.0)]  # off at 5 s to 12 m/s


def _smooth(folder: Path, method: str = "batch", extra: str = "", robust: str | None = None):
    (folder / "run.toml").write_text((folder / "cfg.toml").read_text() + extra)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        dataset = fgins.load(
            folder / "imu.csv", folder / "gnss.csv", config=folder / "run.toml", vehicle="car",
            robust=robust,
        )  # fmt: skip
        return fgins.smooth(dataset, method)


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[int, Path]:
    root = tmp_path_factory.mktemp("gnss_faults")
    out = {}
    for seed in (1, 2, 4):
        out[seed] = root / f"clean{seed}"
        write_turning_drive(out[seed], STEPS, seed)
    return out


def _faulty(clean: Path, start: float, count: int, offset_m) -> Path:
    folder = clean.parent / f"{clean.name}-fault-{start:g}-{count}-{offset_m[0]:g}-{offset_m[1]:g}"
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(clean, folder)
    move_fixes(folder, [start + i for i in range(count)], offset_m)
    return folder


def _around(track, folder: Path, start: float, count: int) -> tuple[float, float]:
    """(RMS horizontal error, mean squared error over the reported horizontal variance)
    from 5 s before the fault to 5 s after it."""
    t, error = horizontal_errors(track, folder)
    inside = (t >= start - 5) & (t <= start + count + 5)
    std_e = np.interp(t, track.t, track.position_std[:, 0])
    std_n = np.interp(t, track.t, track.position_std[:, 1])
    nees = np.mean(error[inside] ** 2 / (std_e[inside] ** 2 + std_n[inside] ** 2))
    return float(np.sqrt(np.mean(error[inside] ** 2))), float(nees)


@pytest.mark.parametrize(
    ("seed", "start", "count", "offset_m", "method"),
    [
        pytest.param(1, 90.0, 10, (8.0, 6.0), "batch", id="turn-10-fixes-10m"),
        pytest.param(2, 150.0, 12, (-10.0, 0.0), "batch", id="straight-12-fixes-west"),
        pytest.param(4, 60.0, 8, (0.0, -12.0), "batch", id="straight-8-fixes-south"),
        pytest.param(4, 200.0, 15, (6.0, 6.0), "isam2", id="isam2-15-fixes"),
        pytest.param(1, 130.0, 5, (9.0, -9.0), "batch", id="turn-5-fixes"),
    ],
)
def test_a_run_of_multipath_fixes_is_left_out(drives, seed, start, count, offset_m, method):
    clean_folder = drives[seed]
    folder = _faulty(clean_folder, start, count, offset_m)
    clean, _ = _around(_smooth(clean_folder, method), clean_folder, start, count)
    track = _smooth(folder, method)
    excluded = track.info.get("gnss_excluded_times", [])
    faults = [t for t in excluded if start - 0.5 <= t <= start + count - 0.5]
    assert len(faults) == count, track.info.get("gnss_excluded")
    assert len(excluded) - len(faults) <= 2, excluded  # good fixes stay in
    assert "GNSS fault exclusion" in track.summary()["gnss_excluded"]
    rms, nees = _around(track, folder, start, count)
    assert rms <= max(1.5 * clean, clean + 0.15), (rms, clean)
    assert nees < 3.0, nees  # the reported sigmas cover the error again
    # The kernel alone (the exclusion off): pulled metres off, its sigmas far too small.
    kept, kept_nees = _around(
        _smooth(folder, method, "\n[gnss]\nfault_exclusion = false\n"), folder, start, count
    )
    # (NEES above 3, the bound the exclusion meets: the slow-error check now widens the
    # kernel-only sigmas somewhat, 4.1 where 5 had been asked, as a burst is a slow error.)
    assert kept > 2.0 * rms and kept > 0.5 and kept_nees > 3.0, (kept, kept_nees, rms)


@pytest.mark.parametrize("seed", [1, 2, 4])
def test_a_drive_without_faults_keeps_its_fixes_and_its_solution(drives, seed):
    """Gaussian fixes: one in a thousand lies beyond 4 sigma; at most that is left out, and
    the solution is the one without the exclusion, to within what one fix moves."""
    folder = drives[seed]
    track = _smooth(folder)
    assert track.info.get("gnss_excluded_count", 0) <= 1
    plain = _smooth(folder, extra="\n[gnss]\nfault_exclusion = false\n")
    _, error = horizontal_errors(track, folder)
    _, plain_error = horizontal_errors(plain, folder)
    assert np.sqrt(np.mean(error**2)) <= 1.05 * np.sqrt(np.mean(plain_error**2))


def test_without_a_robust_kernel_every_fix_stays(drives):
    """``--robust none`` means every fix at full weight: nothing is excluded, and the large
    residuals are said as such."""
    clean = drives[1]
    folder = _faulty(clean, 90.0, 10, (8.0, 6.0))
    track = _smooth(folder, robust="none")
    assert "gnss_excluded_times" not in track.info
    assert "no robust kernel" in track.summary()["gnss_rejected"]


def test_fixes_whose_sigmas_are_too_small_are_not_taken_for_faults(drives):
    """Every fix 4x tighter than its scatter: a quarter and more lie beyond 4 sigma. That is a
    noise model to fix (said), not a set of faults to leave out."""
    folder = drives[2]
    extra = "\n[gnss]\nsigma_m = [0.25, 0.25, 0.4]\nsigma_from_fit = false\n"
    track = _smooth(folder, extra=extra)
    assert track.info.get("gnss_excluded_count", 0) == 0
    assert "too many to be faults" in track.info["gnss_excluded"]


def test_an_exclusion_that_keeps_growing_is_a_wrong_solution_not_faults(tmp_path):
    """A car that reverses for its first 200 m, given a heading 180 deg off (here as a
    configured initial heading; the alignment of an unstated vehicle did the same): each
    round left more fixes out, 67 of 141 in the end, and the fit stayed at chi2/dof 4.4,
    under a summary that called them faults. Where the rounds grow the set beyond the
    fraction faults can be, nothing is left out and the summary says the solution is at
    fault; the fit's own warning stands."""
    from independent_sim import INDUSTRIAL, CarProfile, write_drive

    profile = CarProfile(
        steps=[(10, 4, -4.0), (60, 4, 4.0), (70, 5, 10.0)],
        turns=[(25, 40, 3, 0.08), (90, 100, 3, -0.1)],
        gamma=lambda t: 0.0 * np.asarray(t, float),
    )
    write_drive(tmp_path, profile, 140.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=2)  # fmt: skip
    config = tmp_path / "cfg.toml"
    # The nose points at 60 deg while the car backs along 240 deg: the track's course.
    # (The gyro-scale check would refuse this wrong solution outright: off here, as the
    # faults' own verdict is under test.)
    config.write_text(config.read_text() + "\n[smoother]\ninitial_heading_deg = 240.0\n"
                      "estimate_gyro_scale = false\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=config)
        track = fgins.smooth(dataset, "batch")
    summary = track.summary()
    assert summary.get("gnss_excluded_count", 0) == 0, summary.get("gnss_excluded")
    assert "the solution, not the fixes, is at fault" in summary["gnss_excluded"]
    assert any("inconsistent" in line for line in summary["fit_warnings"]), summary["fit_warnings"]


@pytest.mark.parametrize(("seed", "seconds"), [(1, 30), (2, 20)])
def test_an_rtk_fix_on_wrong_integers_is_left_out_not_the_good_fixes_beside_it(tmp_path, seed, seconds):
    """An RTK receiver holds a wrong-integer fix for 20-30 s: every fix of it 0.5 m off,
    still at 1.5 cm sigmas, consistent with each other. The robust solution ramps onto it,
    so the fixes beyond 5 sigma were the good ones on the ramps: they were left out "as
    multipath", the false fix kept, and the track sat on it, 0.44 m off at 8 mm (z 51;
    outside tester). The stretch between the ramps is now the other reading, kept where it
    fits better."""
    write_rtk_drive(tmp_path, seed)
    start = 70.0
    move_fixes(tmp_path, [start + i for i in range(seconds)], (0.4, -0.3, 0.2))
    track = _smooth(tmp_path)
    left_out = np.array(track.info.get("gnss_excluded_times", [])) - float(track.t[0])
    false = (left_out >= start - 0.5) & (left_out < start + seconds - 0.5)
    assert false.sum() >= seconds - 2, left_out
    assert (~false).sum() <= 2, left_out
    t, error = horizontal_errors(track, tmp_path)
    during = (t >= start + t[0]) & (t < start + seconds + t[0])
    assert np.sqrt(np.mean(error[during] ** 2)) < 0.1


@pytest.mark.parametrize("method", ["ekf", "isam2-online"])
def test_a_few_gross_fixes_are_not_a_filters_divergence(tmp_path, method):
    """Seven fixes 15-20 m off among 280, under the default kernel: the online estimate (and
    a filter) was called "diverged" from the mean chi-square those seven alone made, on a
    track 0.46 m off at the fixes, sending the user after IMU gaps, axes and clocks (outside
    tester). The worst 5 % of fixes stay out of that check; a diverged track misses most."""
    write_turning_drive(tmp_path, [(10, 8, 15.0)], 3)
    for t in (30.0, 50.0, 130.0, 150.0, 230.0, 250.0, 270.0):
        move_fixes(tmp_path, [t], (15.0, -12.0, 20.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml", vehicle="car")
        if method == "isam2-online":
            track = fgins.smooth(dataset, "isam2", online=True)
        else:
            track = fgins.smooth(dataset, method)
    assert not any("does not fit the GNSS fixes" in w for w in track.info.get("fit_warnings", [])), track.info.get("fit_warnings")
