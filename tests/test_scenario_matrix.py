"""Issue 12 acceptance: the smoother holds on simulated inputs it was never tuned on.

A matrix of simulated drives and flights that vary the IMU's body-axis convention (FLU, FRD,
a rotated mounting), the bias model (constant only; random walk), the IMU grade, the vehicle
(car, aircraft) and GNSS with and without velocity, each with 30-60 s GNSS outages placed
over turns of the motion (taken from the simulator's turn windows, checked here). Every cell
goes the way a user's run goes: ``fgins sim`` folder -> ``load_dataset`` -> the dataset's
config (plus the folder's ``[smoother]`` mounting, passed as a ``--config`` file) ->
``run_method``. In every cell:

- batch and iSAM2 (final) are within 2 % of EKF+RTS or better inside the outages,
- batch is at most half the forward EKF's error inside the outages,
- the position NEES per degree of freedom of batch and iSAM2, averaged over 4-10 seeds of the
  cell, lies in [0.5, 2] (one run's NEES is too time-correlated to be judged alone).

Also: the simulator draws the IMU errors in the vehicle's axes, so FLU, FRD and mounted runs
of one seed are the same physical run; their outage RMS must agree within 5 %
(``test_imu_axes_do_not_change_the_answer``, the issue's mounting acceptance), and a sim
folder's mounting must reach the run's config.

Reference: simulator truth (exact, independent of the estimators). Outage errors are
horizontal RMS at 10 Hz truth epochs inside the windows (fgins.bench.metrics).

``python tests/test_scenario_matrix.py [CELL ...]`` prints the table of numbers.
"""

from __future__ import annotations

import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fgins.bench.metrics import errors_against
from fgins.config import config_for_dataset
from fgins.io.inputs import load_dataset
from fgins.outages import outage_mask
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import dumps_toml, write_sim_dir

METHODS = ("batch", "isam2", "ekf", "ekf-rts")
MOUNTING = "[20,-10,35]"


@dataclass(frozen=True)
class Cell:
    scenario: str
    options: dict[str, Any]
    windows: tuple[tuple[float, float], ...]
    seed: int = 0
    min_turn_deg: float = 20.0  # every window must hold at least this much heading change
    # Outage RMS and NEES pooled over this many seeds (see run_cell). Ten, not five: with
    # five, one seed on which EKF+RTS happens to linearise luckily decides the comparison
    # (hwy-frd-const-novel: seeds 0-4 batch 0.513 vs EKF+RTS 0.483 m; seeds 0-9 0.626 vs
    # 0.820 m).
    nees_seeds: int = 10
    slow: bool = True
    notes: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


# Outage windows over turns (turns from the scenarios' [scenario] turns, seconds from the
# first GNSS epoch): car-urban turns at 37-45, 76-83, 89-99, 153-161, 192-199 s; highway
# curves at 60-80, 129-151 s; aircraft turns at 194-226, 304-341 s.
CAR = {"duration_s": 240.0, "grade": "industrial-mems"}
CAR_WINDOWS = ((30.0, 70.0), (150.0, 200.0))
HIGHWAY = {"duration_s": 200.0}
HIGHWAY_WINDOWS = ((55.0, 95.0), (125.0, 160.0))
PLANE = {"duration_s": 400.0, "grade": "tactical", "outage_start_s": 1e6}
PLANE_WINDOWS = ((190.0, 240.0), (300.0, 350.0))
FAST_CAR = {"duration_s": 110.0, "grade": "industrial-mems", "imu_rate_hz": 50}
FAST_CAR_WINDOWS = ((30.0, 70.0),)

CELLS: dict[str, Cell] = {
    # fast, representative (unmarked): FRD axes; rotated mounting with a constant bias
    "car-frd-rw-fast": Cell(
        "car-urban",
        {**FAST_CAR, "body_frame": "frd"},
        FAST_CAR_WINDOWS,
        seed=1,
        slow=False,
        nees_seeds=4,
    ),
    "car-flu-rw-fast": Cell("car-urban", FAST_CAR, FAST_CAR_WINDOWS, seed=1),
    # Fixes without velocity: the batch's stops are confirmed by the speed of a first solve
    # in which a 25 m outlier at the start-up stop (2 % of fixes) pulls it 3.5-4 sigma off
    # zero; a 3-sigma test refused those stops (seeds 11, 12: 2.5 / 3.8 m where EKF+RTS has
    # 1.2 / 1.6 m; pooled 1.57 vs 1.32 m over seeds 1-24).
    "car-flu-rw-novel-fast": Cell(
        "car-urban", {**FAST_CAR, "gnss_velocity": False}, FAST_CAR_WINDOWS, seed=1, nees_seeds=24
    ),
    "car-mount-const-fast": Cell(
        "car-urban",
        {**FAST_CAR, "mounting_rpy_deg": MOUNTING, "bias_model": "constant"},
        FAST_CAR_WINDOWS,
        seed=2,
        slow=False,
        nees_seeds=4,
    ),
    # car: one factor at a time over FLU / random walk / industrial / velocity
    "car-flu-rw": Cell("car-urban", CAR, CAR_WINDOWS),
    "car-frd-rw": Cell("car-urban", {**CAR, "body_frame": "frd"}, CAR_WINDOWS),
    "car-mount-rw": Cell("car-urban", {**CAR, "mounting_rpy_deg": MOUNTING}, CAR_WINDOWS),
    "car-frd-mount-rw": Cell(
        "car-urban", {**CAR, "body_frame": "frd", "mounting_rpy_deg": MOUNTING}, CAR_WINDOWS
    ),
    "car-flu-const": Cell("car-urban", {**CAR, "bias_model": "constant"}, CAR_WINDOWS),
    "car-flu-rw-novel": Cell("car-urban", {**CAR, "gnss_velocity": False}, CAR_WINDOWS),
    "car-consumer-rw": Cell("car-urban", {**CAR, "grade": "consumer-mems"}, CAR_WINDOWS),
    "car-tactical-const": Cell(
        "car-urban", {**CAR, "grade": "tactical", "bias_model": "constant"}, CAR_WINDOWS
    ),
    # highway (consumer MEMS, 200 Hz)
    "hwy-flu-rw-200hz": Cell(
        "highway", {**HIGHWAY, "imu_rate_hz": 200}, HIGHWAY_WINDOWS, min_turn_deg=10.0
    ),
    "hwy-frd-const-novel": Cell(
        "highway",
        {
            **HIGHWAY,
            "body_frame": "frd",
            "bias_model": "constant",
            "gnss_velocity": False,
            "grade": "tactical",
        },
        HIGHWAY_WINDOWS,
        min_turn_deg=10.0,
    ),
    "hwy-mount-rw": Cell(
        "highway", {**HIGHWAY, "mounting_rpy_deg": MOUNTING}, HIGHWAY_WINDOWS, min_turn_deg=10.0
    ),
    # aircraft (coordinated turns, no land-vehicle constraints). With a tactical IMU and GNSS
    # velocity both smoothers are near optimal and which one a seed favours is chance
    # (air-tactical-rw, batch / EKF+RTS per seed 0.75-1.08 over seeds 10-39): pooled over
    # seeds 0-9 batch was 0.724 vs 0.690 m (+5 %), over seeds 10-39 0.870 vs 0.904 m (-4 %,
    # batch better on 17 of 30). The pooled ratio's standard error (bootstrap) is ~3 % over
    # ten seeds, too coarse for a 2 % line, and ~2 % over thirty.
    "air-tactical-rw": Cell(
        "aircraft-ekf", {**PLANE, "bias_model": "random_walk"}, PLANE_WINDOWS, nees_seeds=30
    ),
    "air-tactical-const": Cell(
        "aircraft-ekf", {**PLANE, "bias_model": "constant"}, PLANE_WINDOWS, nees_seeds=30
    ),
    "air-frd-nav-const-novel": Cell(
        "aircraft-ekf",
        {
            **PLANE,
            "grade": "navigation",
            "body_frame": "frd",
            "bias_model": "constant",
            "gnss_velocity": False,
        },
        PLANE_WINDOWS,
    ),
    "air-mount-industrial-rw": Cell(
        "aircraft-ekf",
        {
            **PLANE,
            "grade": "industrial-mems",
            "mounting_rpy_deg": MOUNTING,
            "bias_model": "random_walk",
        },
        PLANE_WINDOWS,
    ),
}


def _nees_per_dof(error: np.ndarray, covariance: np.ndarray) -> float:
    return float(np.mean(np.einsum("ni,nij,nj->n", error, np.linalg.inv(covariance), error)) / 3)


def _config_file(folder: Path, out: Path) -> Path | None:
    """The folder's ``[smoother]`` table (the IMU mounting) as a ``--config`` file."""
    table = tomllib.loads((folder / "config.toml").read_text()).get("smoother")
    if not table:
        return None
    out.write_text(dumps_toml({"smoother": table}))
    return out


def _prepare(cell: Cell, seed: int, work: Path):
    """Simulate one seed of ``cell`` into a folder and read it back as a user's run would."""
    run = SCENARIOS[cell.scenario](seed=seed, **cell.options)
    folder = work / f"drive-{seed}"
    write_sim_dir(run, folder)
    dataset = load_dataset([str(folder)])
    config_path = _config_file(folder, work / f"smoother-{seed}.toml")
    return run, dataset, config_path, outage_mask(dataset, list(cell.windows))


def _nees(trajectory, truth) -> float:
    """Position NEES per degree of freedom at ~1 Hz over the whole run; NaN if the reported
    covariance is missing, non-finite or singular (that is a failure too)."""
    step = max(1, round(1.0 / float(np.median(np.diff(trajectory.t)))))
    rows = slice(None, None, step)
    cov = trajectory.position_cov
    if cov is None or not np.all(np.isfinite(cov[rows])):
        return float("nan")
    error = trajectory.position[rows] - truth.at(trajectory.t[rows])
    try:
        return _nees_per_dof(error, cov[rows])
    except np.linalg.LinAlgError:
        return float("nan")


def run_cell(cell: Cell, work: Path, *, catch: bool = False) -> dict[str, Any]:
    """Simulate, read back and solve one cell; every method on the same outages.

    The outage RMS and the NEES are pooled over ``nees_seeds`` seeds (the cell's and the
    following ones), for every method. One draw decides neither: a single run's NEES is
    time-correlated and spreads from 0.2 to 2.5 for a consistent 110 s car run, and the
    EKF+RTS reference itself depends on how its start-up heading happens to linearise (on
    hwy-frd-const-novel, seeds 0-7, it beats the batch by 16-48 % on three seeds and loses
    by 14-136 % on two; given the true start heading its seed-0 RMS goes 0.365 -> 0.449 m
    while the batch stays at 0.479 m). So "within 2 % of EKF+RTS" is a property of the
    pooled RMS (sqrt of the mean squared per-seed RMS), as the NEES band is of the mean.
    ``catch`` (table mode): a method that raises is recorded as NaN with its error."""
    run, dataset, config_path, mask = _prepare(cell, cell.seed, work)
    windows = list(cell.windows)
    truth = run.truth
    # The windows really hold turns: heading change of the truth inside each window.
    turn_deg = []
    heading = np.unwrap(np.radians(truth.roll_pitch_heading_deg()[:, 2]))
    rel = truth.t - dataset.t0
    for a, b in windows:
        inside = (rel >= a) & (rel < b)
        turn_deg.append(float(np.degrees(np.ptp(heading[inside]))))
    result: dict[str, Any] = {"turn_deg": turn_deg, "withheld": int((~mask).sum())}
    reference = slice(None, None, max(1, round(0.1 / float(np.median(np.diff(truth.t))))))
    nan = float("nan")
    for method in METHODS:
        config = config_for_dataset(dataset, config_path)
        start = time.perf_counter()
        try:
            trajectory = run_method(dataset, config, method, gnss_mask=mask, progress=False)
        except Exception as exc:
            if not catch:
                raise
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            result[method] = {"outage": nan, "aided": nan, "s": nan, "nees": nan,
                              "nees_runs": [], "error": f"{type(exc).__name__}: {first}"}  # fmt: skip
            continue
        elapsed = time.perf_counter() - start
        summary = errors_against(
            trajectory, truth.t[reference], truth.position[reference], dataset.t0, windows
        ).summary()
        entry = {"outage": summary["h_rms_outage"], "aided": summary["h_rms_aided"], "s": elapsed}
        entry["outage_runs"] = [entry["outage"]]
        if method in ("batch", "isam2"):
            entry["nees_runs"] = [_nees(trajectory, truth)]
        result[method] = entry
    for seed in range(cell.seed + 1, cell.seed + cell.nees_seeds):
        run, dataset, config_path, mask = _prepare(cell, seed, work)
        reference = slice(None, None, max(1, round(0.1 / float(np.median(np.diff(run.truth.t))))))
        for method in METHODS:
            if "error" in result[method]:
                continue
            config = config_for_dataset(dataset, config_path)
            try:
                trajectory = run_method(dataset, config, method, gnss_mask=mask, progress=False)
            except Exception as exc:
                if not catch:
                    raise
                result[method]["error"] = f"seed {seed}: {type(exc).__name__}"
                continue
            summary = errors_against(
                trajectory, run.truth.t[reference], run.truth.position[reference],
                dataset.t0, windows,
            ).summary()  # fmt: skip
            result[method]["outage_runs"].append(summary["h_rms_outage"])
            if method in ("batch", "isam2"):
                result[method]["nees_runs"].append(_nees(trajectory, run.truth))
    for method in METHODS:
        if "error" in result[method]:
            continue
        runs = np.asarray(result[method]["outage_runs"], dtype=float)
        result[method]["outage_seed0"] = result[method]["outage"]
        result[method]["outage"] = float(np.sqrt(np.mean(runs**2)))
    for method in ("batch", "isam2"):
        runs = result[method].get("nees_runs", [])
        result[method]["nees"] = float(np.mean(runs)) if runs else nan
    return result


def failures(cell: Cell, result: dict[str, Any]) -> list[str]:
    """Every acceptance condition the cell breaks, with its numbers."""
    out = [f"{m} raised {result[m]['error']}" for m in METHODS if "error" in result[m]]
    for i, turn in enumerate(result["turn_deg"]):
        if turn < cell.min_turn_deg:
            out.append(f"window {cell.windows[i]} holds only {turn:.0f} deg of turn")
    rts = result["ekf-rts"]["outage"]
    ekf = result["ekf"]["outage"]
    for method in ("batch", "isam2"):
        value = result[method]["outage"]
        if not value <= 1.02 * rts:
            out.append(f"{method} pooled outage RMS {value:.3f} m > 1.02 x EKF+RTS {rts:.3f} m")
        nees = result[method]["nees"]
        if not 0.5 <= nees <= 2.0:
            out.append(f"{method} position NEES {nees:.2f} outside [0.5, 2]")
    batch = result["batch"]["outage"]
    if not batch <= 0.5 * ekf:
        out.append(f"batch pooled outage RMS {batch:.3f} m > 0.5 x forward EKF {ekf:.3f} m")
    return out


def _params() -> list[Any]:
    return [
        pytest.param(name, id=name, marks=[pytest.mark.slow] if cell.slow else [])
        for name, cell in CELLS.items()
    ]


@pytest.mark.parametrize("name", _params())
def test_scenario_matrix_cell(name: str, tmp_path: Path) -> None:
    cell = CELLS[name]
    result = run_cell(cell, tmp_path)
    problems = failures(cell, result)
    assert not problems, f"{name}: " + "; ".join(problems) + f" | {row(name, result)}"


def _outage_rms(scenario: str, options: dict[str, Any], windows, method: str, work: Path):
    run = SCENARIOS[scenario](seed=7, **options)
    folder = work / "drive"
    write_sim_dir(run, folder)
    dataset = load_dataset([str(folder)])
    config = config_for_dataset(dataset, _config_file(folder, work / "smoother.toml"))
    mask = outage_mask(dataset, list(windows))
    trajectory = run_method(dataset, config, method, gnss_mask=mask, progress=False)
    reference = slice(None, None, 10)
    return errors_against(
        trajectory, run.truth.t[reference], run.truth.position[reference], dataset.t0,
        list(windows),
    ).summary()["h_rms_outage"]  # fmt: skip


ROTATIONS = {
    "frd": {"body_frame": "frd"},
    "mount": {"mounting_rpy_deg": MOUNTING},
    "frd-mount": {"body_frame": "frd", "mounting_rpy_deg": MOUNTING},
    "mount-yaw-90": {"mounting_rpy_deg": "[0,0,90]"},
    "mount-upside-down": {"mounting_rpy_deg": "[180,0,-30]"},
}


@pytest.mark.parametrize(
    "rotation, method",
    [pytest.param("frd-mount", "batch", id="frd-mount-batch")]
    + [
        pytest.param(r, m, id=f"{r}-{m}", marks=pytest.mark.slow)
        for r in ROTATIONS
        for m in ("batch", "isam2", "ekf-rts")
        if (r, m) != ("frd-mount", "batch")
    ],
)
def test_imu_axes_do_not_change_the_answer(rotation: str, method: str, tmp_path: Path) -> None:
    """The simulator draws the IMU errors in the vehicle's axes, so a rotated IMU (other
    convention, or a mounting given as its angles) is the same physical run as the unrotated
    one: the outage RMS must agree within 5 % (issue 12, mounting acceptance)."""
    options = {**FAST_CAR, "grade": "industrial-mems"}
    base = _outage_rms("car-urban", options, FAST_CAR_WINDOWS, method, tmp_path / "base")
    turned = _outage_rms(
        "car-urban", {**options, **ROTATIONS[rotation]}, FAST_CAR_WINDOWS, method, tmp_path / "rot"
    )
    assert abs(turned - base) <= 0.05 * base, (
        f"{method}: outage RMS {turned:.3f} m with the IMU {rotation} vs {base:.3f} m unrotated"
    )


def test_sim_folder_mounting_reaches_the_run_config(tmp_path: Path) -> None:
    """``fgins smooth DIR`` on a folder whose config.toml states the IMU mounting must use it
    (today the folder reader keeps only [imu]/[gnss]/[origin]/[scenario], so the run silently
    assumes no mounting); with write_mounting=false the folder states none."""
    options = {"duration_s": 20.0, "mounting_rpy_deg": MOUNTING}
    write_sim_dir(SCENARIOS["car-urban"](seed=0, **options), tmp_path / "with")
    config = config_for_dataset(load_dataset([str(tmp_path / "with")]))
    assert tuple(config.smoother.imu_to_vehicle_rpy_deg) == (20.0, -10.0, 35.0)
    write_sim_dir(
        SCENARIOS["car-urban"](seed=0, write_mounting=False, **options), tmp_path / "without"
    )
    config = config_for_dataset(load_dataset([str(tmp_path / "without")]))
    assert tuple(config.smoother.imu_to_vehicle_rpy_deg) == (0.0, 0.0, 0.0)


def row(name: str, result: dict[str, Any]) -> str:
    r = result
    return (
        f"| {name} | {r['batch']['outage']:.3f} | {r['isam2']['outage']:.3f} | "
        f"{r['ekf']['outage']:.3f} | {r['ekf-rts']['outage']:.3f} | {r['batch']['nees']:.2f} | "
        f"{r['isam2']['nees']:.2f} | {r['batch']['s']:.1f} / {r['isam2']['s']:.1f} | "
        f"{' '.join(f'{v:.2f}' for v in r['batch'].get('nees_runs', []))} | "
        f"{' '.join(f'{v:.2f}' for v in r['batch'].get('outage_runs', []))} / "
        f"{' '.join(f'{v:.2f}' for v in r['ekf-rts'].get('outage_runs', []))} |"
    )


if __name__ == "__main__":
    import tempfile

    names = sys.argv[1:] or list(CELLS)
    print(
        "| cell | batch | isam2 | EKF | EKF+RTS | NEES batch | NEES isam2 | s batch/isam2 "
        "| NEES batch per seed | outage RMS per seed batch / EKF+RTS | pass |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for cell_name in names:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                res = run_cell(CELLS[cell_name], Path(tmp), catch=True)
            except Exception as exc:  # report and go on: the table is the point
                print(f"| {cell_name} | error: {type(exc).__name__}: {exc} |", flush=True)
                continue
            bad = failures(CELLS[cell_name], res)
            print(row(cell_name, res) + (" ok |" if not bad else " FAIL: " + "; ".join(bad) + " |"),
                  flush=True)  # fmt: skip
