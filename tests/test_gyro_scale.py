"""The batch's gyro scale-factor estimate (fgins.graph.gyro_scale).

Against the truth an independent simulator put in: a car's gyro read 1-3 % large or small
(on the axis a car turns about, or on all three), at other rates and seeds, is found to
within its sigma and corrected, and the outages are then bridged as with a true gyro, with
honest sigmas; without the correction they are not. Clean drives, flights and turned IMUs
get no correction. The sparse Schur-complement estimate equals a dense least-squares
solution of the same linearised graph with the scale as three more unknowns.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

import fgins
from fgins.graph import gyro_scale

sys.path.insert(0, str(Path(__file__).parent))
from flight_sim import FixedWing, write_flight
from independent_sim import (
    FIVE_TURNS,
    INDUSTRIAL,
    CarProfile,
    outage_rms_and_sigma,
    scale_gyro,
    turn_imu_axes,
    write_drive,
)

OUTAGES = [(60.0, 105.0), (175.0, 215.0)]


def _drive(folder: Path, rate: float, seed: int, scale: float, axes: str) -> None:
    """The independent simulator's car (rest 10 s, then 15 m/s through five turns), its
    gyro's ``axes`` reading ``1 + scale`` times the true rate."""
    profile = CarProfile(steps=[(10, 8, 15.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 280.0, grade=INDUSTRIAL, imu_rate=rate, jitter=0.0,
                gnss_rate=1.0, seed=seed)  # fmt: skip
    scale_gyro(folder, scale, axes)


def _outage_rms_and_ratio(track, folder: Path) -> tuple[float, float]:
    rms, sigma = outage_rms_and_sigma(track, folder, OUTAGES)
    return rms, rms / sigma


def _smooth(folder: Path, extra: str = "", method: str = "batch"):
    config = folder / "run.toml"
    config.write_text((folder / "cfg.toml").read_text() + extra)
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=config, vehicle="car")
    return fgins.smooth(dataset, method, gnss_outage=OUTAGES)


@pytest.mark.parametrize(
    "scale, axes, rate, seed, method",
    [(0.01, "z", 100.0, 1, "batch"), (-0.02, "xyz", 200.0, 2, "batch"),
     (0.03, "xyz", 50.0, 3, "isam2")],
)  # fmt: skip
def test_a_gyro_scale_error_is_found_and_corrected(tmp_path, scale, axes, rate, seed, method):
    _drive(tmp_path, rate, seed, scale, axes)
    corrected = _smooth(tmp_path, method=method)
    error = np.array(corrected.info["gyro_scale_error"])
    sigma = np.array(corrected.info["gyro_scale_sigma"])
    assert corrected.info["gyro_scale_corrected"] == [False, False, True]  # a car turns about z
    assert abs(error[2] - scale) < max(3 * sigma[2], 0.001), (error, sigma)
    said = [w for w in corrected.info["fit_warnings"] if "scale error z" in w]
    assert len(said) == 1 and "estimate_gyro_scale = false" in said[0]
    if method == "isam2":
        assert "gyro scale corrected" in corrected.info["solver"]
    kept = _smooth(tmp_path, "\n[smoother]\nestimate_gyro_scale = false\n", method)
    # Kept as asked, but said (a 3 % error kept so had left outages at z 4-6.6 with the
    # lines blaming the receiver and the mounting: outside tester).
    assert kept.info["gyro_scale_corrected"] == [False, False, False]
    said_kept = [w for w in kept.info.get("fit_warnings", []) if "scale error z" in w]
    assert len(said_kept) == 1 and "not corrected" in said_kept[0], kept.info.get("fit_warnings")
    # The same drive with a true gyro, for reference.
    _drive(tmp_path, rate, seed, 0.0, "")
    true_gyro = _smooth(tmp_path, method=method)
    assert true_gyro.info["gyro_scale_corrected"] == [False, False, False]
    rms, ratio = _outage_rms_and_ratio(corrected, tmp_path)
    rms_kept, ratio_kept = _outage_rms_and_ratio(kept, tmp_path)
    rms_true, _ = _outage_rms_and_ratio(true_gyro, tmp_path)
    assert rms < 1.15 * rms_true and ratio < 1.3, (rms, rms_true, ratio)
    # Kept, the error stays in the outages, and its spread in their sigmas (kept at the
    # samples' scale, the marginals alone had said 0.5-0.85 of the error).
    assert rms_kept > 1.4 * rms_true and ratio_kept < 1.3, (rms_kept, rms_true, ratio_kept)
    assert "the output's sigmas include it" in said_kept[0]


@pytest.mark.parametrize("turn", ["rfu", "backward"])
def test_a_turned_imu_with_a_true_gyro_gets_no_correction(tmp_path, turn):
    _drive(tmp_path, 100.0, 4, 0.0, "")
    turn_imu_axes(tmp_path, turn)
    track = _smooth(tmp_path)
    assert track.info["gyro_scale_corrected"] == [False, False, False]
    assert not any("scale error" in w for w in track.info.get("fit_warnings", []))


@pytest.mark.parametrize("frame", ["flu", "frd"])
def test_a_banking_aircraft_with_a_true_gyro_gets_no_correction(tmp_path, frame):
    """Every axis turns (bank, climb, turns): every axis is measured, none is corrected."""
    rate = 9.8 * np.tan(np.radians(35)) / 60.0
    motion = FixedWing(speed=60.0, heading0_deg=40.0, turns=[(40, 75, 4, rate), (95, 120, 4, -rate)],
                       climbs=[(20, 45, 5, np.radians(6))])  # fmt: skip
    write_flight(tmp_path, motion, 150.0, seed=5, frame=frame, vehicle="aircraft", gnss_rate=1.0)
    track = fgins.smooth(fgins.load(tmp_path), "batch", gnss_outage=[(80.0, 125.0)])
    sigma = np.array(track.info["gyro_scale_sigma"])
    assert np.all(sigma < 0.01)  # all three axes observable
    assert track.info["gyro_scale_corrected"] == [False, False, False]


def _dense_estimate(problem, graph, values) -> tuple[np.ndarray, np.ndarray, dict]:
    """The scale as three more unknowns of the whole linearised graph, solved densely, and
    every state's sensitivity to it."""
    linear = graph.linearize(values)
    keys = sorted(int(k) for k in linear.keyVector())
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    matrix, rhs = linear.jacobian(ordering)
    gradient = linear.gradientAtZero()
    column, offset = {}, 0
    for key in keys:
        column[key] = offset
        offset += gradient.at(key).shape[0]
    rates = gyro_scale.neighbour_rates(problem)
    scale_columns = np.zeros((matrix.shape[0], 3))
    row = 0
    for index in range(graph.size()):
        rows = linear.at(index).jacobian()[0].shape[0]
        factor = graph.at(index)
        if isinstance(factor, gtsam.CombinedImuFactor):
            bias = column[int(factor.keys()[4])] + 3
            root = factor.noiseModel().R()
            plain = np.linalg.solve(root, matrix[row : row + rows, bias : bias + 3])
            plain[9:15] = 0.0  # the bias random walk is not the scale's
            interval = int(gtsam.Symbol(factor.keys()[4]).index())
            turn = rates[interval] - values.atConstantBias(gtsam.symbol("b", interval)).gyroscope()
            scale_columns[row : row + rows] = (root @ plain) * turn  # the rate, not the bias
        row += rows
    prior = np.hstack([np.zeros((3, matrix.shape[1])), np.eye(3) / gyro_scale.SCALE_PRIOR])
    augmented = np.vstack([np.hstack([matrix, scale_columns]), prior])
    solution, *_ = np.linalg.lstsq(augmented, np.concatenate([rhs, np.zeros(3)]), rcond=None)
    covariance = np.linalg.inv(augmented.T @ augmented)
    # Each state's move with the scale, every other state free: -(A'A)^-1 A'C.
    moves = -np.linalg.solve(matrix.T @ matrix, matrix.T @ scale_columns)
    dims = {key: gradient.at(key).shape[0] for key in keys}
    sensitivity = {key: moves[column[key] : column[key] + dims[key]] for key in keys}
    return solution[-3:], np.sqrt(np.diag(covariance)[-3:]), sensitivity


def test_the_sparse_estimate_is_the_dense_least_squares_one(tmp_path, monkeypatch):
    """On a short drive with a 3 % gyro (one turn): the O(K) Schur complement against the
    dense augmented least squares, to 1e-6 of the scale and its sigma, and the keyframes'
    sensitivity to it (what the output's sigmas take the scale's spread through) to 1e-6 of
    its largest."""
    profile = CarProfile(steps=[(10, 8, 15.0)], turns=[(40, 50, 3, 0.12)], gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 70.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=6)  # fmt: skip
    scale_gyro(tmp_path, 0.03, "z")
    seen = []
    estimate = gyro_scale.estimate_gyro_scale

    def checked(problem, graph, values):
        result = estimate(problem, graph, values)
        if not seen:  # the first estimate, before any correction
            seen.append((result, _dense_estimate(problem, graph, values)))
        return result

    monkeypatch.setattr(gyro_scale, "estimate_gyro_scale", checked)
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv",
                         config=tmp_path / "cfg.toml", vehicle="car")  # fmt: skip
    fgins.smooth(dataset, "batch")
    sparse, (dense, dense_sigma, dense_moves) = seen[0]
    np.testing.assert_allclose(sparse.error, dense, atol=1e-6)
    np.testing.assert_allclose(sparse.sigma, dense_sigma, atol=1e-6)
    assert sparse.sensitivity is not None
    states = [key for k in range(len(sparse.sensitivity) // 2) for key in (gtsam.symbol("x", k), gtsam.symbol("v", k))]
    assert set(sparse.sensitivity) == set(states)
    largest = max(float(np.abs(dense_moves[key]).max()) for key in states)
    assert largest > 1.0  # a 100 % scale error moves the track metres: not a test of zeros
    for key in states:
        np.testing.assert_allclose(sparse.sensitivity[key], dense_moves[key], atol=1e-6 * largest)
    assert abs(sparse.error[2] - 0.03) < 3 * sparse.sigma[2]


def test_an_implausible_scale_on_any_axis_corrects_nothing():
    """A scale estimate beyond 5 % on any axis says the solution is wrong, not the gyro (a
    start heading 120 deg off, its fit at chi2/dof 16, read as +398 % and -44 %; a car's
    pitch axis +6.0 % where its mounting was configured 4 deg off): no axis is corrected,
    while plausible ones are."""
    sigma = np.full(3, 1e-4)
    assert not gyro_scale.ScaleEstimate(np.array([3.98, 0.01, -0.44]), sigma).significant.any()
    assert not gyro_scale.ScaleEstimate(np.array([0.011, 0.01, 0.2]), sigma).significant.any()
    assert not gyro_scale.ScaleEstimate(np.array([0.0, 0.0602, 0.0]), sigma).significant.any()
    # an axis far beyond 5 % but poorly determined (a car's roll axis) does not veto the rest
    loose = np.array([0.03, 1e-4, 1e-4])
    assert gyro_scale.ScaleEstimate(np.array([0.07, 0.0, 0.03]), loose).significant.tolist() == [False, False, True]
    found = gyro_scale.ScaleEstimate(np.array([0.011, 0.001, -0.03]), sigma).significant
    assert found.tolist() == [True, False, True]



def _gentle_hills(amplitude: float) -> CarProfile:
    """At rest 10 s, then 15 m/s over grades of +-``amplitude`` with four turns: its pitch
    rates (about the gyro's y) are all a gyro x/y mistake can show."""
    from independent_sim import _ramp

    def gamma(t):
        return np.arctan(amplitude * np.sin(2 * np.pi * (t - 20) / 70) * _ramp(t, 20, 5))

    turns = [(40, 50, 4, 0.12), (115, 130, 4, 0.09), (170, 180, 4, -0.12), (220, 232, 4, -0.1)]
    return CarProfile(steps=[(10, 10, 15.0)], turns=turns, gamma=gamma)


@pytest.mark.parametrize(("mistake", "amplitude", "seed"),
                         [("gyro_y negated", 0.002, 1), ("gyro x/y swapped", 0.002, 2),
                          ("gyro_y negated", 0.01, 3)])  # fmt: skip
def test_a_gyro_axis_mistake_is_no_scale_error_but_an_error(tmp_path, mistake, amplitude, seed):
    """A car on gentle grades (0.2-1 %) with a gyro column mistaken: the accelerometer's
    handedness is right and the yaw axis too, so nothing before the solve sees it, and the
    batch ran 5-130 m off inside its outages at exit 0 (the fixes' sigmas "scaled" 2-15x).
    Its turns then read as scale errors of 50-150 % at 13-70 sigmas, which no gyro has: an
    error naming the axes. The same drive as recorded fits, says nothing, and bridges."""
    import pandas as pd

    write_drive(tmp_path, _gentle_hills(amplitude), 260.0, grade=INDUSTRIAL, imu_rate=100.0,
                jitter=0.0, gnss_rate=1.0, seed=seed)  # fmt: skip
    files = (tmp_path / "imu.csv", tmp_path / "gnss.csv")
    right = fgins.smooth(fgins.load(*files, config=tmp_path / "cfg.toml", vehicle="car"), "batch",
                         gnss_outage=OUTAGES)  # fmt: skip
    assert not [w for w in right.info.get("fit_warnings", []) if "scale" in w]
    assert outage_rms_and_sigma(right, tmp_path, OUTAGES)[0] < 1.0
    imu = pd.read_csv(files[0])
    if mistake == "gyro_y negated":
        imu["gyro_y"] = -imu["gyro_y"]
    else:
        imu[["gyro_x", "gyro_y"]] = imu[["gyro_y", "gyro_x"]].to_numpy()
    imu.to_csv(files[0], index=False, float_format="%.10e")
    with pytest.raises(fgins.FginsError, match=r"imu: the gyro's turns contradict the solution's, read as scale errors") as said:
        fgins.smooth(fgins.load(*files, config=tmp_path / "cfg.toml", vehicle="car"), "batch",
                     gnss_outage=OUTAGES)  # fmt: skip
    # With the car's constraints on, the vehicle model is named as a cause too (an outside
    # tester's drone and boat given --vehicle car: only the gyro's columns were blamed).
    assert "--vehicle car ties the IMU's heading to its track" in str(said.value)


def test_an_implausible_but_loose_scale_is_said_not_corrected():
    """Beyond 5 % and determined but short of the error's bounds (a highway's gyro_x negated:
    +31 % +- 4.5, 1.7 m inside an outage against 0.5, unsaid): a warning naming the causes."""
    info = gyro_scale._info(np.array([0.307, -0.001, 0.034]), np.array([0.045, 0.002, 0.018]),
                            np.zeros(3, bool), np.array([True, False, False]))  # fmt: skip
    (said,) = info["fit_warnings"]
    assert "x +30.7 % +- 4.5" in said and "sign flipped or two columns swapped" in said
    assert not gyro_scale._info(np.zeros(3), np.full(3, 0.01), np.zeros(3, bool), np.zeros(3, bool)).get("fit_warnings")


@pytest.mark.parametrize("seed", [1, 3])
def test_a_noisy_gyros_axes_that_hardly_turn_read_no_scale_error(tmp_path, seed):
    """A consumer gyro (1 deg/sqrt(h)) on a car with stops and three turns, no scale error:
    its roll and pitch axes hardly turn, and each interval's own mean reading, regressed on,
    carried the noise its IMU factor's residual carries: +17 % and +21 % at 4 sigma on
    every seed, +16.8 % +- 3.3 (5 sigma, a false "gyro column flipped" warning) on an outside
    tester's drive. The neighbours' rate has none of the interval's noise: within 2.5 sigma
    of zero."""
    grade = dict(preset="consumer-mems", gyro_arw=1.0, gyro_bi=10.0, gyro_on=1800.0,
                 accel_vrw=0.1, accel_bi=0.1, accel_on=10.0)  # fmt: skip
    steps = [(10, 8, 12.0), (80, 6, -12.0), (150, 6, 12.0), (220, 6, -12.0)]
    turns = [(40, 50, 3, 0.12), (110, 120, 3, -0.15), (185, 195, 3, 0.1)]
    write_drive(tmp_path, CarProfile(steps=steps, turns=turns, gamma=lambda t: 0 * t), 280.0,
                grade=grade, imu_rate=100.0, jitter=0.0, gnss_rate=1.0, seed=seed)  # fmt: skip
    track = _smooth(tmp_path)
    error, sigma = np.array(track.info["gyro_scale_error"]), np.array(track.info["gyro_scale_sigma"])
    assert np.all(np.abs(error) < 2.5 * sigma), (error, sigma)
    assert not any("scale error" in w for w in track.info.get("fit_warnings", []))


class _RollingProfile(CarProfile):
    """The car's motion with its body rolled ``roll(t)`` about its forward axis through the
    non-slip point (with the IMU ``imu_offset`` above it: a car parked on a ferry in a
    swell, rolling about the ship's axis below the deck)."""

    def __init__(self, *args, roll, **kwargs):
        super().__init__(*args, **kwargs)
        self.roll = roll

    def rotation(self, t):
        level = super().rotation(t)
        angle = self.roll(np.asarray(t, float))
        c, s = np.cos(angle), np.sin(angle)
        about_x = np.zeros((*np.shape(angle), 3, 3))
        about_x[..., 0, 0] = 1.0
        about_x[..., 1, 1], about_x[..., 1, 2], about_x[..., 2, 1], about_x[..., 2, 2] = c, -s, s, c
        return level @ about_x


@pytest.mark.parametrize("seed", [1, 3])
def test_a_real_roll_the_vehicle_constraints_do_not_expect_is_no_axis_mistake(tmp_path, seed):
    """A car parked on a ferry at 2.5 m/s, rolling in a swell: the gyro reads the roll
    right, and the misfit the sway leaves against the car's constraints read as a scale
    error of x at 10 sigmas; the run was refused as "a gyro column with its sign flipped"
    (an outside tester's ferry: x +34-39 %, where EKF+RTS was 0.3 m off; here 4 deg at 0.12
    Hz about an axis 6 m below the IMU: x -29 % +- 2.5). Now the refusal needs a column
    mistake that, undone, fits far better (test_a_gyro_axis_mistake_is_no_scale_error_but_
    an_error: they do); this roll fits no better with any, so the run goes on (0.42 m in
    its outage)."""
    swell = 2 * np.pi * 0.12

    def roll(t):
        from independent_sim import _ramp

        return np.radians(4.0) * np.sin(swell * t) * _ramp(t, 5, 5)

    profile = _RollingProfile(steps=[(10, 10, 2.5)], turns=[(60, 80, 5, 0.03)], gamma=lambda t: 0 * t, roll=roll)
    write_drive(tmp_path, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, imu_offset=(0.0, 0.0, 6.0))  # fmt: skip
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml", vehicle="car")
    track = fgins.smooth(dataset, "batch", gnss_outage=[(120.0, 150.0)])
    assert outage_rms_and_sigma(track, tmp_path, [(120.0, 150.0)])[0] < 1.0


# An outside tester's tactical grade (datasheet: ARW deg/sqrt(h), deg/h, deg/h; m/s/sqrt(h), mg, mg).
TACTICAL = dict(preset="tactical", gyro_arw=0.05, gyro_bi=1.0, gyro_on=36.0,
                accel_vrw=0.03, accel_bi=0.02, accel_on=1.0)  # fmt: skip
HILL_OUTAGES = [(45.0, 75.0), (110.0, 140.0), (165.0, 195.0), (215.0, 245.0)]


@pytest.mark.parametrize(("hills", "pitch_scale", "yaw_scale", "seed", "method"),
                         [(0.03, 0.015, 0.005, 2, "batch"), (0.02, 0.02, 0.0, 4, "isam2")])  # fmt: skip
def test_a_scale_error_too_loose_to_correct_is_in_the_sigmas(tmp_path, hills, pitch_scale, yaw_scale, seed, method):
    """A tactical gyro whose scale is off about an axis the drive turns too little to
    correct it (the car's pitch axis over +-2-3 % hills: read at 2.8-3.2 sigmas, under the 5 a
    correction needs) bends the track in every outage over a hill; the solves hold the scale
    at the samples', so their marginals alone said 0.30 m where the errors were 0.57-0.75 m
    (RMS ratio 1.9-2.5). The scale's spread is in the sigmas; with a true gyro they stay
    close to the errors (not inflated by an axis it cannot tell)."""
    def run(pitch: float, yaw: float) -> tuple[object, float]:
        folder = tmp_path / f"{pitch}_{yaw}"
        write_drive(folder, _gentle_hills(hills), 280.0, grade=TACTICAL, imu_rate=100.0,
                    jitter=0.0, gnss_rate=1.0, seed=seed)  # fmt: skip
        # A low-noise gyro whose scale is known to 2 % only (the tactical preset's 0.05 %
        # would say such errors cannot be).
        config = folder / "cfg.toml"
        config.write_text(config.read_text().replace('preset = "tactical"\n', 'preset = "tactical"\ngyro_scale_sigma_percent = 2.0\n'))
        assert "gyro_scale_sigma_percent = 2.0" in config.read_text()
        if pitch:
            scale_gyro(folder, pitch, "y")
        if yaw:
            scale_gyro(folder, yaw, "z")
        dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=folder / "cfg.toml", vehicle="car")
        track = fgins.smooth(dataset, method, gnss_outage=HILL_OUTAGES)
        rms, sigma = outage_rms_and_sigma(track, folder, HILL_OUTAGES)
        return track, rms / sigma

    scaled, ratio = run(pitch_scale, yaw_scale)
    assert not scaled.info["gyro_scale_corrected"][1]  # the pitch axis: too loose to correct
    assert ratio < 1.4, ratio
    _, true_ratio = run(0.0, 0.0)
    assert 0.6 < true_ratio < 1.4, true_ratio
