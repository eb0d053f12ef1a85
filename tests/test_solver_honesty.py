"""Regression tests for the silently-wrong answers of issue 12 (items 1 and 2), and the
solver's own honesty: a result labelled "batch" is a converged batch solution, every solve
reports its consistency, and a solve that cannot be trusted is an error, not an output.

References are independent of the factor graph: simulator truth with known noise and the
Kalman baselines on identical data (with identical models, the batch smoother must match
EKF+RTS and beat the forward EKF inside outages).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgins.config import load_config
from fgins.datatypes import FginsError
from fgins.outages import in_windows, outage_mask
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS


def _constant_bias_config(dataset, vehicle: str):
    """The dataset's own sensor settings with every bias random walk set to zero."""
    imu = {
        k: (0.0 if ("bias_rw" in k or "instability" in k) else v)
        for k, v in dataset.imu_config.items()
    }
    config = load_config(dataset_imu=imu, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = vehicle
    return config


def _outage_rms(trajectory, truth, dataset, windows) -> float:
    inside = in_windows(trajectory.t, dataset.t0, windows)
    error = np.linalg.norm(trajectory.position[:, :2] - truth.at(trajectory.t)[:, :2], axis=1)
    return float(np.sqrt(np.mean(error[inside] ** 2)))


def _check_sigmas(trajectory) -> None:
    std = np.sqrt(np.diagonal(trajectory.position_cov, axis1=1, axis2=2))
    assert np.all(np.isfinite(std)) and np.all(std > 0)


def test_constant_bias_car_batch_and_isam2_are_real_solutions():
    """Item 1: a zero bias instability (a constant bias) made the IMU factor's noise
    singular: batch returned the EKF's guess labelled "batch", iSAM2 an internal error, and
    every std was 0. Now it is a constant bias: both solve, converge, fit consistently, and
    inside the outage match EKF+RTS on the same models. Pooled over five seeds: one 40 s
    window of one drive varies by +-20 % from seed to seed between equally good methods.
    The solvers compare on the same fixes: the Kalman baselines keep the urban car's 25 m
    outliers (Huber-weighted), so the graph's fault exclusion is off here (it leaves them out,
    which moves this window's RMS by up to +-25 % either way, by chance: pooled over seeds
    10-29 12.31 -> 12.23 m; tests/test_gnss_faults.py)."""
    pooled: dict[str, list[float]] = {"ekf": [], "rts": [], "batch": [], "isam2": []}
    for seed in range(5):
        run = SCENARIOS["car-urban"](seed=seed, duration_s=150)
        dataset = run.dataset
        config = _constant_bias_config(dataset, "car")
        config.gnss.fault_exclusion = False
        windows = [(60.0, 100.0)]
        mask = outage_mask(dataset, windows)
        ekf = run_method(dataset, config, "ekf", gnss_mask=mask, progress=False)
        rts = run_method(dataset, config, "ekf-rts", gnss_mask=mask, progress=False)
        batch = run_method(dataset, config, "batch", gnss_mask=mask, progress=False)
        isam2 = run_method(dataset, config, "isam2", gnss_mask=mask, progress=False)
        assert "constant bias" in batch.info["imu_bias_model"]
        assert batch.info["iterations"] > 0
        assert batch.info["final_error"] < batch.info["initial_error"]
        assert 0.3 < batch.info["chi2_per_dof"] < 2.0
        # Not the initial guess: the batch solution differs from the forward filter's.
        assert np.max(np.abs(batch.position - ekf.position)) > 0.05
        for name, track in (("ekf", ekf), ("rts", rts), ("batch", batch), ("isam2", isam2)):
            pooled[name].append(_outage_rms(track, run.truth, dataset, windows))
        _check_sigmas(batch)
        _check_sigmas(isam2)
    total = {name: float(np.sum(values)) for name, values in pooled.items()}
    assert total["batch"] <= 1.02 * total["rts"], pooled
    assert total["isam2"] <= 1.02 * total["rts"], pooled
    assert total["batch"] < total["ekf"], pooled
    assert all(b <= 1.3 * r for b, r in zip(pooled["batch"], pooled["rts"], strict=True)), pooled


@pytest.mark.slow
def test_constant_bias_aircraft_matches_rts():
    """Item 1 on the case it was found on: the aircraft with its 60 s outage."""
    run = SCENARIOS["aircraft-ekf"](seed=0)
    dataset = run.dataset
    config = _constant_bias_config(dataset, "aircraft")
    windows = [(480.0, 540.0)]
    mask = outage_mask(dataset, windows)
    rts = run_method(dataset, config, "ekf-rts", gnss_mask=mask, progress=False)
    for method in ("batch", "isam2"):
        trajectory = run_method(dataset, config, method, gnss_mask=mask, progress=False)
        assert _outage_rms(trajectory, run.truth, dataset, windows) <= 1.05 * _outage_rms(
            rts, run.truth, dataset, windows
        )
        _check_sigmas(trajectory)


def _horizontal_rms(trajectory, truth) -> float:
    error = np.linalg.norm(trajectory.position[:, :2] - truth.at(trajectory.t)[:, :2], axis=1)
    return float(np.sqrt(np.mean(error**2)))


# (grade, GNSS rate): the default scenario and the 0.2 Hz cases run by default; the others
# are slow-marked. Measured, seeds 0-4, 300 s: batch 0.67-0.81 / 0.96-1.47 m (navigation,
# 1 / 0.2 Hz), 1.04-1.15 / 1.76-2.35 m (tactical), 1.12 / 2.15-2.51 m (automotive); ekf18
# 1.3-1.6 / 2.8-3.5, 2.6-2.9 / 50 m, 3.2 / 300 m (at 0.2 Hz its attitude runs away). Since
# stops are found by the specific force (seeds 0-1): 0.64-0.67 / 0.88-1.31, 1.00-1.08 /
# 1.71-2.29, 1.07-1.15 / 2.09-2.45 m; the heading at the initial standstill of automotive
# seed 0 went from 36 to 4 deg off.
GYROFREE_CASES = [
    pytest.param("tactical", 1.0, id="tactical-1hz-default"),
    pytest.param("tactical", 0.2, id="tactical-0.2hz"),
    pytest.param("automotive", 0.2, id="automotive-0.2hz"),
    pytest.param("navigation", 1.0, id="navigation-1hz", marks=pytest.mark.slow),
    pytest.param("navigation", 0.2, id="navigation-0.2hz", marks=pytest.mark.slow),
    pytest.param("automotive", 1.0, id="automotive-1hz", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("grade, rate_hz", GYROFREE_CASES)
def test_gyrofree_scenario_batch_no_worse_than_ekf18(grade: str, rate_hz: float):
    """Item 2 and its acceptance: `fgins sim gyrofree-cube` (defaults: tactical, 1 Hz, 300 s)
    lost attitude in batch (7.9 m, heading errors of 60-140 deg) while the 18-state EKF got
    2.5 m; at 0.2 Hz the EKF itself runs away (50-300 m) and the batch started from it did
    not converge (an error, no output). The graph now starts from the better-fitting of
    ekf18 and the GNSS-track guess, preintegrates about its bias and alternates
    re-preintegration with LM. Every grade and rate: batch no worse than ekf18; at 1 Hz,
    tactical and navigation grade, below 0.7 x the GNSS sigma."""
    run = SCENARIOS["gyrofree-cube"](seed=0, grade=grade, gnss_rate_hz=rate_hz)
    dataset = run.dataset
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = dataset.vehicle or "other"
    sigma = float(dataset.gnss_config["uere_m"]["autonomous"])
    ekf18 = run_method(dataset, config, "ekf", progress=False)  # ekf18 for an accel array
    assert ekf18.method == "ekf18"
    batch = run_method(dataset, config, "batch", progress=False)
    # The candidates the pipeline hands over for an accelerometer array on a car.
    assert set(batch.info["initial_guess_errors"]) == {"ekf18", "GNSS track + gravity"}
    assert batch.info["initial_guess"] in batch.info["initial_guess_errors"]
    error = {"ekf18": _horizontal_rms(ekf18, run.truth), "batch": _horizontal_rms(batch, run.truth)}
    assert error["batch"] <= error["ekf18"], error
    if rate_hz == 1.0 and grade != "automotive":
        assert error["batch"] < 0.7 * sigma, error
    heading = batch.roll_pitch_heading_deg()[:, 2] - run.truth.roll_pitch_heading_deg()[:, 2]
    assert np.max(np.abs((heading + 180) % 360 - 180)) < 30


def test_nan_in_a_factor_is_an_error_not_an_output():
    """A NaN that reaches a factor (here: a GNSS sigma) must stop the solve with a clear
    message; LM would otherwise return its initial guess unchanged."""
    from fgins.graph.problem import build_problem
    from fgins.graph.smoother import smooth_batch

    run = SCENARIOS["car-urban"](seed=2, duration_s=40)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    problem = build_problem(run.dataset, config, progress=False)
    problem.gnss_sigma[3] = np.nan
    with pytest.raises(FginsError, match="not finite"):
        smooth_batch(problem, progress=False)


@pytest.mark.parametrize("method", ["planar-kf", "ekf"])
def test_a_solution_with_nan_in_it_is_an_error_not_an_output(monkeypatch, method):
    """Whatever a method returns passes one last check: a position, velocity or position
    sigma that is not finite is an error naming the method (planar-kf once wrote an all-NaN
    track at exit 0 from a NaN start, and fleet and bench counted it as a result). The
    attitude's sigmas may be NaN: planar-kf estimates no roll and pitch."""
    import fgins.pipeline as pipeline

    run = SCENARIOS["car-urban"](seed=2, duration_s=40)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    clean = run_method(run.dataset, config, method, progress=False)
    assert np.all(np.isfinite(clean.position))
    solve = pipeline._corrected_solution

    def with_nan(*args, **kwargs):
        trajectory = solve(*args, **kwargs)
        trajectory.velocity[len(trajectory.t) // 2 :] = np.nan
        return trajectory

    monkeypatch.setattr(pipeline, "_corrected_solution", with_nan)
    with pytest.raises(FginsError, match=rf"^{method}: the solution is not finite at \d+ of"):
        run_method(run.dataset, config, method, progress=False)


@pytest.mark.parametrize("error", ["non-finite", "not converged", "diverged"])
def test_a_solve_that_breaks_down_over_a_long_gap_in_the_fixes_names_it(monkeypatch, error):
    """A real log (gpsd's nmea-rtk: 10 s of fixes, 630 s without one, 2 s of RTK) beside an
    IMU at rest: the batch's start was not finite ("a NaN or infinite measurement ... check
    the inputs") or LM did not converge in 7,909 iterations ("check the IMU noise
    settings"); iSAM2 blamed the IMU's noise, axes or units (outside tester). Where the
    fixes leave more than LONG_GNSS_GAP_S, a solve that breaks down names that gap."""
    import fgins.graph.smoother as smoother
    from fgins.graph.solve import DivergedError, NonFiniteError, NotConvergedError
    from fgins.pipeline import LONG_GNSS_GAP_S

    run = SCENARIOS["car-urban"](seed=2, duration_s=240)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    failure = {"non-finite": NonFiniteError, "not converged": NotConvergedError,
               "diverged": DivergedError}[error]  # fmt: skip
    message = {
        "non-finite": "batch LM: the factor graph's error at the initial guess is not finite",
        "not converged": "batch: Levenberg-Marquardt did not converge",
        "diverged": "iSAM2 diverged: the solution does not fit the data; check the IMU axes",
    }[error]

    def broken(*args, **kwargs):
        raise failure(message)

    monkeypatch.setattr(smoother, "smooth", broken)
    gap = (40.0, 40.0 + LONG_GNSS_GAP_S + 30.0)
    mask = outage_mask(run.dataset, [gap])
    with pytest.raises(FginsError, match=r"over 1[5-9]\d s without a usable GNSS fix \(t - t0 = 39\.\d+ \.\. \d+\.\d+ s\).*split the log at the gap") as said:
        run_method(run.dataset, config, "batch", gnss_mask=mask, progress=False)
    # A diverged fit's own causes stay first; the gap is named beside them.
    assert str(said.value).startswith(message) == (error == "diverged")
    short = outage_mask(run.dataset, [(40.0, 40.0 + LONG_GNSS_GAP_S - 30.0)])
    with pytest.raises(failure, match=message):  # no long gap: as it was
        run_method(run.dataset, config, "batch", gnss_mask=short, progress=False)


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_a_diverged_fit_names_the_factors_that_carry_its_error(method):
    """GNSS sigmas 0.1 mm for metre-level fixes: no fit exists. The error says which kind of
    factor carries the misfit and what to check, not a generic "check the IMU"."""
    run = SCENARIOS["car-urban"](seed=3, duration_s=60)
    gnss = replace(run.dataset.gnss, std=np.full_like(run.dataset.gnss.lla, 1e-4))
    dataset = replace(run.dataset, gnss=gnss)
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = "car"
    with pytest.raises(FginsError, match="diverged") as info:
        run_method(dataset, config, method, progress=False)
    assert "The GNSS position factors carry" in str(info.value)
    assert "sigmas (std_* columns" in str(info.value)


def test_every_solve_reports_its_consistency():
    run = SCENARIOS["highway"](seed=1, duration_s=90)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    config.smoother.vehicle = "car"
    for method in ("batch", "isam2"):
        trajectory = run_method(run.dataset, config, method, progress=False)
        assert trajectory.info["solver"].startswith(("batch LM", "iSAM2"))
        assert 0.3 < trajectory.info["chi2_per_dof"] < 2.0
        assert trajectory.info["python_callback_factors"] == 0
        assert not trajectory.info.get("fit_warnings")


def test_reports_say_what_happened():
    """Item 6: counts add up (withheld epochs are not "rejected for PDOP"), and without a
    robust kernel nothing is called "rejected": large residuals keep their full weight."""
    from fgins.config import GnssConfig

    run = SCENARIOS["car-urban"](seed=3, duration_s=80)
    dataset = run.dataset
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    windows = [(20.0, 40.0)]
    mask = outage_mask(dataset, windows)
    trajectory = run_method(dataset, config, "batch", gnss_mask=mask, progress=False)
    counts = trajectory.info["gnss_counts"]
    assert counts["withheld"] == int((~mask).sum()) > 0
    assert (
        counts["used"]
        + counts["withheld"]
        + counts["gated_pdop"]
        + counts["gated_quality"]
        + counts["outside_imu_span"]
        + counts["decimated"]
        == counts["total"]
        == len(dataset.gnss)
    )
    assert f"{counts['withheld']} withheld by outage" in trajectory.info["gnss_gating"]
    assert "rejected" not in trajectory.info["gnss_rejected"]
    assert trajectory.info["gnss_rejected_times"] == []
    robust = replace(config, gnss=replace(config.gnss, cauchy_k=3.0))
    assert isinstance(robust.gnss, GnssConfig)
    with_kernel = run_method(dataset, robust, "batch", gnss_mask=mask, progress=False)
    assert "Cauchy" in with_kernel.info["gnss_rejected"]


@pytest.mark.parametrize("window", [(260.0, 310.0), (280.0, 330.0)])
def test_car_constraints_do_not_hurt_in_the_kitti_windows_where_they_did(kitti, window):
    """Item 7: with 50 s outages here the car constraints made batch worse than without
    (7.25 vs 5.93 m): the filled IMU stretches in the turns hid 9-11 deg of yaw behind 30x
    noise, and the constraints turned that heading error into velocity error."""
    from fgins.bench.metrics import errors_against
    from fgins.config import config_for_dataset

    mask = outage_mask(kitti, [window])
    rms = {}
    for vehicle in ("car", "other"):
        config = config_for_dataset(kitti, vehicle=vehicle)
        trajectory = run_method(kitti, config, "batch", gnss_mask=mask, progress=False)
        rms[vehicle] = errors_against(
            trajectory, kitti.gnss.t, kitti.gnss_enu(), kitti.t0, [window]
        ).summary()["h_rms_outage"]
    assert rms["car"] <= 1.1 * rms["other"], rms


def test_gnss_sigmas_far_too_pessimistic_are_said(tmp_path):
    """Sigmas given in cm as if m passed silently: the fit was "consistent" and every reported
    sigma 100x too large. (An absurd IMU noise is refused by the config's ranges.)"""
    import sys
    from pathlib import Path

    import pandas as pd

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, hilly_drive, write_drive

    write_drive(tmp_path, hilly_drive(), 120.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=2, sigma_h=0.05, sigma_u=0.1)  # fmt: skip
    fixes = pd.read_csv(tmp_path / "gnss.csv")
    for column in ("std_east", "std_north", "std_up"):
        fixes[column] *= 100.0
    fixes.to_csv(tmp_path / "gnss.csv", index=False, float_format="%.10f")
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml",
                         vehicle="car")  # fmt: skip
    summary = fgins.smooth(dataset, "batch").summary()
    warned = " ".join(summary.get("fit_warnings", []))
    assert "cm given as m" in warned, (summary.get("gnss_data_sigma_whitened_rms"), warned)


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_a_kalman_baseline_that_fits_no_fix_is_an_error(tmp_path, method):
    """A car on 8 % grades whose gyro_y is negated: the Kalman baselines miss the fixes they
    used at chi2/dof 2.8-2.9e4 (residuals 170 sigmas): no estimate at all, an error without
    output, as the batch's own divergence (it was a file at exit 0 with a warning; an
    aircraft with its gyro's x/y swapped, 207 km off). The drive as recorded fits."""
    import sys
    from pathlib import Path

    import pandas as pd

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, hilly_drive, write_drive

    write_drive(tmp_path, hilly_drive(), 260.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=1)  # fmt: skip
    files = (tmp_path / "imu.csv", tmp_path / "gnss.csv")
    right = fgins.smooth(fgins.load(*files, config=tmp_path / "cfg.toml", vehicle="car"), method)
    assert not [w for w in right.info.get("fit_warnings", []) if "does not fit" in w]
    imu = pd.read_csv(files[0])
    imu["gyro_y"] = -imu["gyro_y"]
    imu.to_csv(files[0], index=False, float_format="%.10e")
    with pytest.raises(FginsError, match=rf"{method} diverged: .* chi2/dof [\d.e+]+, .*no output written"):
        fgins.smooth(fgins.load(*files, config=tmp_path / "cfg.toml", vehicle="car"), method)


@pytest.mark.parametrize("method", ["ekf", "ekf-rts", "ukf"])
def test_a_kalman_baseline_that_diverged_says_so(method):
    """A 25 s IMU gap (let through by raising max_imu_gap_s) sent the Kalman baselines 50-360
    m off the fixes they used, with exit 0 and no word: their fit is now checked as the
    graph's is (horizontal residuals at the used fixes over their sigmas), and the same drive
    without the gap passes the check."""
    run = SCENARIOS["car-urban"](seed=0, duration_s=120.0)
    dataset, imu = run.dataset, run.dataset.imu
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = "car"
    config.smoother.max_imu_gap_s = config.smoother.max_unaided_imu_gap_s = 60.0
    clean = run_method(dataset, config, method, progress=False)
    assert not [w for w in clean.info.get("fit_warnings", []) if "does not fit" in w]
    keep = (imu.t < imu.t[0] + 40.0) | (imu.t >= imu.t[0] + 65.0)
    gapped = replace(dataset, imu=replace(imu, t=imu.t[keep], gyro=imu.gyro[keep],
                                          accel=imu.accel[keep], suspect=[]))  # fmt: skip
    from fgins.io.imu_checks import flag_suspect

    gapped = replace(gapped, imu=flag_suspect(gapped.imu, []))
    track = run_method(gapped, config, method, progress=False)
    notes = [w for w in track.info.get("fit_warnings", []) if "does not fit the GNSS fixes" in w]
    assert notes and notes[0].startswith(f"{method}: ")


@pytest.mark.parametrize("method", ["ekf", "ekf-rts", "ukf"])
def test_a_kalman_baseline_on_gnss_from_another_clock_says_so(method, tmp_path):
    """GNSS 18 s late against the IMU (GPS time against UTC) left the forward EKF 218 m off
    at exit 0 without a word (outside tester): a filter follows the fixes it is given, so
    its residuals at them stay small. Its own innovations do not: their median normalised
    square is checked. On the independent simulator's drive (not fgins's own), the same
    files on one clock pass and GNSS 2 s or 18 s late is said; shifting the clock only
    drops the epochs beyond the IMU span, so the check cannot pass by luck of data."""
    import sys
    from pathlib import Path

    import pandas as pd

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, hilly_drive, write_drive

    write_drive(tmp_path, hilly_drive(), 120.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=3, sigma_h=0.5, sigma_u=1.0)  # fmt: skip
    fixes = pd.read_csv(tmp_path / "gnss.csv")
    medians = {}
    for late_s in (0.0, 2.0, 4.0):
        shifted = fixes.assign(time=fixes["time"] + late_s)
        path = tmp_path / f"gnss_{late_s:g}.csv"
        shifted.to_csv(path, index=False, float_format="%.10f")
        dataset = fgins.load(tmp_path / "imu.csv", path, config=tmp_path / "cfg.toml",
                             vehicle="car")  # fmt: skip
        track = run_method(dataset, load_config(tmp_path / "cfg.toml"), method, progress=False)
        notes = [w for w in track.info.get("fit_warnings", []) if "--time-offset" in w]
        medians[late_s] = track.info["gnss_nis_median"]
        assert bool(notes) == (late_s > 0), (late_s, medians, notes)
        if notes:
            assert notes[0].startswith(f"{method}: ")
    assert 0.3 < medians[0.0] < 2.0, medians


def test_an_online_pass_that_fails_leaves_the_final_estimate_to_the_batch_start(monkeypatch):
    """Where both iSAM2 online runs fail (an indeterminate state: a gyro-free IMU with sparse
    GNSS lost one at keyframe 195), `--method isam2` wrote nothing although the final
    estimate is one LM solve of the same graph away. Now that solve runs from the batch's
    start and says so; no online estimate exists (none is offered, `isam2-online` is the
    error)."""
    import fgins.graph.isam2 as isam2

    config_run = SCENARIOS["car-urban"](seed=4, duration_s=60.0)
    from fgins.config import config_for_dataset

    config = config_for_dataset(config_run.dataset)
    batch = run_method(config_run.dataset, config, "batch", progress=False)

    def fails(*_args, **_kwargs):
        raise FginsError(
            "iSAM2: estimate at keyframe 12 (t = 12.0 s) failed even with QR factorization: "
            "Indeterminate linear system; no output written. Try --method batch"
        )

    monkeypatch.setattr(isam2, "run_isam2", fails)
    final = run_method(config_run.dataset, config, "isam2", progress=False)
    summary = final.summary()
    assert "the online pass failed (iSAM2: estimate at keyframe 12" in summary["fallback"]
    assert (
        "no online estimate" in summary["fallback"]
        and "no output written" not in summary["fallback"]
    )
    assert "from the batch's start" in summary["fallback"]
    assert "online" not in final.info
    assert np.max(np.abs(final.position - batch.position)) < 0.05
    assert np.all(final.position_std > 0)
    with pytest.raises(FginsError, match="keyframe 12"):
        run_method(config_run.dataset, config, "isam2-online", progress=False)


@pytest.mark.parametrize(("window", "said"), [((0.0, 112.0), True), ((40.0, 70.0), False)])
def test_a_track_whose_only_fixes_stand_still_says_its_heading_is_unseen(tmp_path, window, said):
    """GNSS only at a stop at the end of a drive (a start outage of 290 s): EKF+RTS ended
    219-625 m off with 2 m sigmas and its heading 37-113 deg off at 0.2 deg, unsaid; the
    batch on a consumer IMU 111 m off at 5.3 m, blaming the gyro's axes (outside tester).
    Where every fix used lies at one place while the track travels, that is said; an outage
    inside a drive whose fixes show it moving says nothing."""
    import sys
    from pathlib import Path

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, CarProfile, write_drive

    profile = CarProfile(steps=[(10, 8, 12.0), (100, 8, -12.0)], turns=[(40, 50, 3, 0.12)],
                         gamma=lambda t: 0 * t)  # fmt: skip
    write_drive(tmp_path, profile, 125.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=3)  # fmt: skip
    track = fgins.smooth(fgins.load(tmp_path), "ekf-rts", gnss_outage=[window])
    notes = [w for w in track.info.get("fit_warnings", []) if w.startswith("heading: every fix")]
    assert bool(notes) == said, track.info.get("fit_warnings")


def test_a_solve_whose_lm_crawls_has_a_bounded_cost_and_says_its_work(monkeypatch):
    """A real log with 5 fixes and a 307 s gap (outside tester): LM crawled, each round
    spending its whole budget for 1-2 % less error, 40 rounds from every start (8,000
    iterations, 10 minutes), and the summary counted only the first start's and the kept
    one's. Now one solve stops at SOLVE_ITERATION_BUDGET_FACTOR x batch_max_iterations
    (unconverged: batch tries its other starts), and the count is every start's."""
    import fgins.graph.gnss_faults as gnss_faults
    import fgins.graph.solve as solve
    from fgins.graph.solve import SOLVE_ITERATION_BUDGET_FACTOR, NotConvergedError

    run = SCENARIOS["car-urban"](seed=2, duration_s=40)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    config.smoother.vehicle = "other"
    config.smoother.batch_max_iterations = 5
    real = solve.levenberg_marquardt
    calls: list[tuple[int, int]] = []  # (budget, the solve it belongs to)
    solves = [0]
    real_rounds = solve.solve_in_rounds

    def counted_rounds(*args, **kwargs):
        solves[0] += 1
        return real_rounds(*args, **kwargs)

    def crawling(graph, initial, max_iterations, lambda_initial, solver):
        # One real iteration, its error made to fall a little each time (never settled).
        result, _, damping, start, _ = real(graph, initial, 1, lambda_initial, solver)
        calls.append((max_iterations, solves[0]))
        return result, max_iterations, damping, start, 1e3 / len(calls)

    monkeypatch.setattr(solve, "levenberg_marquardt", crawling)
    monkeypatch.setattr(solve, "solve_in_rounds", counted_rounds)
    monkeypatch.setattr(gnss_faults, "solve_in_rounds", counted_rounds)
    with pytest.raises(NotConvergedError, match=r"did not converge \((\d+) iterations") as said:
        run_method(run.dataset, config, "batch", progress=False)
    per_solve = np.bincount([s for _, s in calls], weights=[b for b, _ in calls])
    assert solves[0] >= 3  # the other starts were tried
    assert per_solve.max() == SOLVE_ITERATION_BUDGET_FACTOR * 5
    reported = int(str(said.value).split("(")[1].split()[0])
    assert reported == sum(b for b, _ in calls)


def test_a_fair_but_not_good_first_fit_gets_the_isam2_start_s_opinion(monkeypatch):
    """A converged first fit at chi2/dof 1.5-10 may be a wrong basin (outside tester: a
    walker's phone-grade IMU, the heading swept through 360 deg at chi2/dof 2.2, 12.8 m
    inside an outage at 4.7 times the sigmas; iSAM2's start found chi2/dof 1.2 and 1.5 m).
    The iSAM2 start is solved too and the better fit kept, said; a good first fit is not
    solved again. (Here the first fit is made to look fair by its error.)"""
    import fgins.graph.batch as batch
    from fgins.graph.batch import CHI2_SECOND_OPINION

    run = SCENARIOS["car-urban"](seed=2, duration_s=60)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    good = run_method(run.dataset, config, "batch", progress=False)
    assert good.info["chi2_per_dof"] < CHI2_SECOND_OPINION and not good.info.get("fallback")
    real = batch.solve_from
    calls = [0]

    def first_fair(problem, initial):
        report, result, graph = real(problem, initial)
        calls[0] += 1
        if calls[0] == 1:  # as if the first start had settled in another basin
            report.final_error = 1.5 * CHI2_SECOND_OPINION * report.dof / 2.0
        return report, result, graph

    monkeypatch.setattr(batch, "solve_from", first_fair)
    track = run_method(run.dataset, config, "batch", progress=False)
    assert calls[0] >= 2
    assert "the iSAM2 start fits better: taken" in str(track.info.get("fallback")), track.info.get("fallback")
    assert track.info["chi2_per_dof"] < CHI2_SECOND_OPINION
