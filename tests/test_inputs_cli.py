"""Readers' checks and the CLI contract: one-line errors, non-zero exits, no partial outputs."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgins.cli import main
from fgins.config import imu_noise_from_config, load_config
from fgins.datatypes import FginsError, InputError
from fgins.io.csv_pair import read_csv_dataset, read_imu_csv
from fgins.io.imu_checks import find_gaps, find_linear_fills
from fgins.io.trajectory_csv import COLUMNS
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import write_sim_dir


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("sim") / "uav"
    write_sim_dir(SCENARIOS["uav-loop-baro"](seed=2, duration_s=60), folder)
    return folder


def test_datasheet_units_convert_in_closed_form():
    noise = imu_noise_from_config(
        {"gyro_arw_deg_per_sqrt_hr": 0.6, "accel_vrw_m_per_s_per_sqrt_hr": 0.12,
         "gyro_turn_on_bias_deg_per_s": 0.5, "accel_turn_on_bias_mg": 10.0}
    )  # fmt: skip
    assert noise.gyro_noise == pytest.approx(0.6 * math.pi / 180 / 60)
    assert noise.accel_noise == pytest.approx(0.12 / 60)
    assert noise.gyro_bias_prior == pytest.approx(0.5 * math.pi / 180)
    assert noise.accel_bias_prior == pytest.approx(10e-3 * 9.80665)


def test_config_errors_are_clear(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[imu]\ngyro_arw = 1\n")
    with pytest.raises(FginsError, match="unknown key"):
        load_config(bad)
    bad.write_text("[imu\n")
    with pytest.raises(FginsError, match=r"bad\.toml"):
        load_config(bad)
    with pytest.raises(FginsError, match="unknown IMU preset"):
        imu_noise_from_config({"preset": "potato"})


def test_gaps_and_linear_fills_are_found():
    rng = np.random.default_rng(0)
    t = np.arange(0, 20, 0.01)
    data = rng.normal(size=(len(t), 6))
    # A lost stretch filled by straight lines between its end samples (as KITTI's logger did).
    i, j = 500, 580
    data[i : j + 1] = (
        data[i] + (data[j] - data[i]) * ((t[i : j + 1] - t[i]) / (t[j] - t[i]))[:, None]
    )
    fills = find_linear_fills(t, data)
    assert len(fills) == 1
    assert fills[0][0] == pytest.approx(t[i]) and fills[0][1] == pytest.approx(t[j])
    gappy = np.delete(t, np.arange(1000, 1010))
    assert find_gaps(gappy) == [(pytest.approx(t[999]), pytest.approx(t[1010]))]


def _write_imu(path: Path, rows: list[list[float]]) -> None:
    lines = ["time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"]
    lines += [
        ",".join("nan" if isinstance(v, float) and math.isnan(v) else str(v) for v in row)
        for row in rows
    ]
    path.write_text("\n".join(lines) + "\n")


def test_imu_csv_nan_and_duplicates_are_counted_backwards_time_is_an_error(tmp_path):
    rows = [[0.01 * k, 0, 0, 0, 0, 0, 9.8] for k in range(100)]
    rows[10][3] = float("nan")
    rows.insert(20, list(rows[20]))  # repeated timestamp
    path = tmp_path / "imu.csv"
    _write_imu(path, rows)
    warnings: list[str] = []
    imu = read_imu_csv(path, warnings)
    assert len(imu) == 99  # 101 rows - 1 NaN - 1 repeated
    assert any("NaN" in w for w in warnings) and any("repeated" in w for w in warnings)
    rows[50][0] = 0.2  # time jumps backwards
    _write_imu(path, rows)
    with pytest.raises(InputError, match="backwards"):
        read_imu_csv(path, [])


@pytest.mark.parametrize("rate_hz", [50.0, 100.0, 400.0])
def test_corrupted_stamps_are_dropped_and_counted_not_a_refused_log(rate_hz):
    """A few samples whose header stamp alone is corrupt (random bytes in a recording: one
    at the start, three in a row mid-log, two at the end) are dropped and counted; the
    samples around them, a real 2 s gap included, are kept as they were. Two files in one
    log are still refused (an outside tester's damaged bags were refused whole as "two clocks
    or files")."""
    from fgins.io.imu_checks import imu_from_samples

    rng = np.random.default_rng(int(rate_hz))
    t = 1.7e9 + np.arange(6000) / rate_hz
    t[3000:] += 2.0  # a real gap
    gyro, accel = rng.normal(0, 0.01, (6000, 3)), rng.normal(0, 0.1, (6000, 3)) + np.array([0, 0, 9.8])
    stamped = t.copy()
    stray = [0, 1200, 1201, 1202, 5998, 5999]
    # out of order in the file, as a corrupted stamp mostly is (one beyond the log's end
    # without a step back is a gap, which the gap checks refuse)
    stamped[stray] = t[stray] + np.array([30.313, 211.1, -107.7, 200.3, -111.3, -57.7]) * 100.0 / rate_hz
    warnings: list[str] = []
    imu = imu_from_samples(stamped, gyro, accel, source="imu", warnings=warnings)
    keep = np.setdiff1d(np.arange(6000), stray)
    np.testing.assert_array_equal(imu.t, t[keep])
    np.testing.assert_array_equal(imu.gyro, gyro[keep])
    assert len(warnings) == 1 and "dropped 6 IMU sample(s) whose time stamp alone" in warnings[0]
    clean: list[str] = []
    assert len(imu_from_samples(t, gyro, accel, source="imu", warnings=clean)) == 6000 and not clean
    lone = np.concatenate([[t[0] - 1.9], t[1:]])  # a first sample 1.9 s before the rest (KITTI's)
    assert len(imu_from_samples(lone, gyro, accel, source="imu", warnings=clean)) == 6000 and not clean
    # A recorder's bursts of eight messages received seven samples late (h1's bags): sorted,
    # every sample kept, not refused as two files nor dropped as corrupted stamps.
    arrival = np.arange(6000)
    for start in range(100, 5980, 300):
        arrival[start:start + 15] = np.concatenate([arrival[start + 8:start + 15], arrival[start:start + 8]])
    week = 604800.0 - 5.0 + np.arange(6000) / rate_hz  # seconds of the week, rolling over
    with pytest.raises(InputError, match="GPS seconds of the week rolling over into a new week; add 604800 s"):
        imu_from_samples(np.where(week >= 604800.0, week - 604800.0, week), gyro, accel, source="imu", warnings=[])
    # seconds of the day wrapping at midnight (a logger stamping UTC time of day): named, not
    # "the log mixes clocks or files - sort or split it" (outside tester)
    day = 86400.0 - 5.0 + np.arange(6000) / rate_hz
    with pytest.raises(InputError, match="seconds of the day wrapping at midnight; add 86400 s"):
        imu_from_samples(np.where(day >= 86400.0, day - 86400.0, day), gyro, accel, source="imu", warnings=[])
    # one message whose log time was corrupted: first in the file, its own stamp right
    first = np.concatenate([[2963], np.delete(np.arange(6000), 2963)])
    moved: list[str] = []
    imu = imu_from_samples(t[first], gyro[first], accel[first], source="imu", warnings=moved)
    np.testing.assert_array_equal(imu.t, t)
    assert len(moved) == 1 and "sorted by time" in moved[0], moved
    late: list[str] = []
    imu = imu_from_samples(t[arrival], gyro[arrival], accel[arrival], source="imu", warnings=late)
    np.testing.assert_array_equal(imu.t, t)
    np.testing.assert_array_equal(imu.accel, accel)
    assert len(late) == 1 and "sorted by time, their stamps one regular series" in late[0], late
    with pytest.raises(InputError, match="mixes clocks or files"):
        imu_from_samples(np.concatenate([t, t]), *(np.vstack([a, a]) for a in (gyro, accel)),
                         source="imu", warnings=[])  # fmt: skip


def test_sim_folder_and_csv_pair_in_any_order(sim_dir):
    folder = read_csv_dataset([sim_dir])
    pair = read_csv_dataset([sim_dir / "gnss.csv", sim_dir / "imu.csv"])
    np.testing.assert_array_equal(folder.imu.t, pair.imu.t)
    np.testing.assert_allclose(folder.gnss.lla, pair.gnss.lla)
    assert folder.baro is not None
    with pytest.raises(InputError, match="no GNSS CSV"):
        read_csv_dataset([sim_dir / "imu.csv"])


def test_cli_smooth_writes_design_columns_at_imu_rate(sim_dir, tmp_path):
    out = tmp_path / "out.csv"
    assert (
        main(
            ["smooth", str(sim_dir), "--method", "batch", "--gnss-outage", "20:30", "-o", str(out)]
        )
        == 0
    )
    header = out.read_text().splitlines()[0].split(",")
    assert header[: len(COLUMNS)] == COLUMNS
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    imu = np.loadtxt(sim_dir / "imu.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 0], imu[:, 0], atol=1e-6)
    assert np.all(np.isfinite(table[:, : len(COLUMNS)]))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["smooth", "missing.csv", "-o", "{out}"], "no such file"),
        (["smooth", "demo:kitti", "--gnss-outage", "90:60", "-o", "{out}"], "START < END"),
        (["smooth", "demo:kitti", "--gnss-outage", "abc", "-o", "{out}"], "START:END"),
        (["smooth", "demo:nope", "-o", "{out}"], "demo:kitti"),
        (["smooth", "{sim}/imu.csv", "-o", "{out}"], "no GNSS CSV"),
    ],
)
def test_bad_input_is_one_line_and_leaves_no_output(tmp_path, sim_dir, capsys, args, message):
    out = tmp_path / "result.csv"
    argv = [a.format(out=out, sim=sim_dir) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]
    assert list(tmp_path.iterdir()) == []


def _prepare(kind: str, tmp_path: Path, sim_dir: Path) -> list[str]:
    """A user's mistake or a damaged file, and the command given it."""
    if kind == "csv-renamed":
        (tmp_path / "fixes.ubx").write_bytes((sim_dir / "gnss.csv").read_bytes())
        return ["inspect", str(tmp_path / "fixes.ubx")]
    if kind == "convert-folder":
        return ["convert", str(sim_dir), "-o", str(tmp_path / "o.csv")]
    if kind == "convert-toml":
        return ["convert", str(sim_dir / "config.toml"), "-o", str(tmp_path / "o.csv")]
    if kind in ("arw-huge", "rpy-two"):
        line = "[imu]\ngyro_arw_deg_per_sqrt_hr = 1e30" if kind == "arw-huge" else (
            "[smoother]\nimu_to_vehicle_rpy_deg = [0, 0]"
        )  # fmt: skip
        (tmp_path / "c.toml").write_text(line + "\n")
        return ["smooth", str(sim_dir), "--config", str(tmp_path / "c.toml"), "-o", str(tmp_path / "o.csv")]
    if kind == "bag-empty-yaml":
        (tmp_path / "bag").mkdir()
        (tmp_path / "bag" / "metadata.yaml").write_text("")
        return ["inspect", str(tmp_path / "bag")]
    if kind == "mcap-magic-only":
        (tmp_path / "cut.mcap").write_bytes(b"\x89MCAP0\r\n")
        return ["inspect", str(tmp_path / "cut.mcap")]
    lines = (sim_dir / "imu.csv").read_text().splitlines()  # an Excel export's trailing commas
    (tmp_path / "imu.csv").write_text("\n".join(line + "," for line in lines) + "\n")
    return ["inspect", str(tmp_path / "imu.csv")]


@pytest.mark.parametrize(
    ("kind", "code", "said", "not_said"),
    [
        ("csv-renamed", 0, "GNSS, 60 fixes", "not a log"),
        ("convert-folder", 2, "is a folder: convert takes one GNSS log file", "Is a directory"),
        ("convert-toml", 2, "not a log fgins reads", "corrupt lines"),
        ("arw-huge", 2, "must be > 0 and <= 100", "within"),
        ("rpy-two", 2, "3 numbers [roll, pitch, yaw]", "[x, y, z]"),
        ("bag-empty-yaml", 2, "not a readable ROS 2 bag metadata file (empty)", "NoneType"),
        ("mcap-magic-only", 2, "truncated at byte 8", "EndOfFile"),
        ("trailing-comma", 0, "column 8 (no name: a trailing comma?)", "ignored: ;"),
    ],
)
def test_messages_name_the_cause(tmp_path, sim_dir, capsys, kind, code, said, not_said):
    """An outside tester's inputs whose message named something else: a CSV under another
    name called no log, a folder "Is a directory", a TOML "29 corrupt lines", a range for a
    positive value as "+-100", a library's "'NoneType' object", "EndOfFile: " at exit 0."""
    assert main(_prepare(kind, tmp_path, sim_dir)) == code
    said_all = " ".join(capsys.readouterr())
    assert said in said_all and not_said not in said_all and "Traceback" not in said_all


def test_no_usable_gnss_in_span_is_a_clear_error(tmp_path, sim_dir, capsys):
    gnss = (sim_dir / "gnss.csv").read_text().splitlines()
    shifted = [gnss[0]] + [
        ",".join([str(float(r.split(",")[0]) + 1e6), *r.split(",")[1:]]) for r in gnss[1:]
    ]
    (tmp_path / "gnss.csv").write_text("\n".join(shifted) + "\n")
    out = tmp_path / "x.csv"
    assert (
        main(["smooth", str(sim_dir / "imu.csv"), str(tmp_path / "gnss.csv"), "-o", str(out)]) == 2
    )
    assert "time span" in capsys.readouterr().err
    assert not out.exists()


def test_python_dash_m_entry_point():
    result = subprocess.run(
        [sys.executable, "-m", "fgins", "--version"], capture_output=True, text=True
    )
    assert result.returncode == 0 and result.stdout.startswith("fgins ")


def test_long_imu_gap_and_gnss_clock_jump_are_reported_not_fatal(tmp_path, sim_dir, capsys):
    folder = tmp_path / "broken"
    folder.mkdir()
    imu = np.loadtxt(sim_dir / "imu.csv", delimiter=",", skiprows=1)
    gap = (imu[:, 0] > 20.0) & (imu[:, 0] < 30.0)
    header = (sim_dir / "imu.csv").read_text().splitlines()[0]
    np.savetxt(folder / "imu.csv", imu[~gap], delimiter=",", header=header, comments="", fmt="%.9f")
    gnss = (sim_dir / "gnss.csv").read_text().splitlines()
    jumped = [
        ",".join([str(float(r.split(",")[0]) + 1000.0), *r.split(",")[1:]]) for r in gnss[-10:]
    ]
    (folder / "gnss.csv").write_text("\n".join(gnss[:-10] + jumped) + "\n")
    out = tmp_path / "out.csv"
    assert main(["smooth", str(folder), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "IMU gap" in err and "time jump" in err and "outside the IMU time span" in err
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.all(np.isfinite(table[:, :16]))


def test_robust_flag_reaches_the_gnss_model_and_outputs_are_readable(tmp_path, sim_dir, capsys):
    import stat

    from fgins.cli import _config_for, build_parser
    from fgins.io.csv_pair import read_csv_dataset

    dataset = read_csv_dataset([sim_dir])
    for flag, field in (("huber", "huber_k"), ("cauchy", "cauchy_k")):
        args = build_parser().parse_args(["smooth", str(sim_dir), "-o", "x.csv", "--robust", flag])
        assert getattr(_config_for(dataset, args).gnss, field) is not None
    out = tmp_path / "robust.csv"
    assert main(["smooth", str(sim_dir), "--robust", "cauchy", "-o", str(out)]) == 0
    assert "GNSS outliers" in capsys.readouterr().err
    assert out.stat().st_mode & stat.S_IRGRP  # not the 0600 of a temporary file


def test_time_offset_applies_to_every_input_format(tmp_path, sim_dir, capsys):
    """``--time-offset`` was applied to NMEA only: on the CSV pair (and MCAP) it was ignored
    silently, while the "do not overlap" error told the user to give it."""
    import fgins

    gnss = (sim_dir / "gnss.csv").read_text().splitlines()
    shifted = [gnss[0]] + [
        ",".join([f"{float(r.split(',')[0]) + 200.0:.6f}", *r.split(",")[1:]]) for r in gnss[1:]
    ]
    (tmp_path / "gnss.csv").write_text("\n".join(shifted) + "\n")
    inputs = [str(sim_dir / "imu.csv"), str(tmp_path / "gnss.csv")]
    reference = fgins.load(sim_dir / "imu.csv", sim_dir / "gnss.csv")
    moved = fgins.load(*inputs, time_offset=-200.0)
    np.testing.assert_allclose(moved.gnss.t, reference.gnss.t, atol=1e-6)
    out = tmp_path / "x.csv"
    assert main(["smooth", *inputs, "--method", "ekf", "-o", str(out), "--no-progress",
                 "--time-offset", "-200"]) == 0  # fmt: skip
    assert out.exists()
    capsys.readouterr()
    for bad in ("nan", "inf"):
        assert main(["smooth", *inputs, "-o", str(tmp_path / "y.csv"), "--time-offset", bad]) == 2
        assert "--time-offset" in capsys.readouterr().err
    sys.path.insert(0, str(Path(__file__).parent))
    from mcap_fixtures import make_drive, write_ros2_bag

    bag = write_ros2_bag(tmp_path / "bag", make_drive())
    plain = fgins.load(bag)
    offset = fgins.load(bag, time_offset=0.25)
    np.testing.assert_allclose(offset.gnss.t, plain.gnss.t + 0.25, atol=1e-9)


def _imu_without(sim_dir: Path, folder: Path, start: float, end: float) -> Path:
    folder.mkdir()
    imu = np.loadtxt(sim_dir / "imu.csv", delimiter=",", skiprows=1)
    header = (sim_dir / "imu.csv").read_text().splitlines()[0]
    keep = (imu[:, 0] <= start) | (imu[:, 0] >= end)
    np.savetxt(folder / "imu.csv", imu[keep], delimiter=",", header=header, comments="", fmt="%.9f")
    for name in ("gnss.csv", "config.toml"):
        if (sim_dir / name).exists():
            (folder / name).write_bytes((sim_dir / name).read_bytes())
    return folder


@pytest.mark.parametrize("method", ["batch", "ekf"])
def test_imu_gaps_no_method_can_bridge_are_refused_naming_the_gap(tmp_path, sim_dir, capsys, method):
    """A 25-30 s IMU gap left the EKF 50-360 m off with 0 % of the truth in its 3-sigma and
    exit 0 (a simulated urban drive); a 10 s gap inside an outage (neither IMU nor GNSS) did
    the same, and the batch did not converge. Such gaps are refused before any solve, for
    every method, with the gap and the setting named; shorter ones are bridged, and a gap
    with GNSS inside is bridged up to max_imu_gap_s."""
    long_gap = _imu_without(sim_dir, tmp_path / "long", 20.0, 32.0)  # 12 s
    out = tmp_path / "out.csv"
    assert main(["smooth", str(long_gap), "--method", method, "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("fgins: error: imu: the 12.0 s gap in the IMU data at t - t0 = 20.0")
    assert "max_imu_gap_s" in err[-1] and not out.exists()
    # The reader's note before it does not claim a bridge the run then refuses (outside tester).
    noted = [line for line in err if "IMU gap(s) longer than" in line]
    assert noted and "the longest 12.00 s); bridged with inflated noise up to [smoother] max_imu_gap_s" in noted[0], err

    short_gap = _imu_without(sim_dir, tmp_path / "short", 20.0, 26.0)  # 6 s, GNSS inside
    args = ["smooth", str(short_gap), "--method", method, "-o", str(out), "--no-progress"]
    assert main([*args, "--gnss-outage", "10:30"]) == 2  # ... but withheld: 6 s of neither
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "goes 6.0 s without IMU or GNSS (the outage windows withhold its fixes)" in err
    assert "max_unaided_imu_gap_s" in err and not out.exists()
    assert main(args) == 0 and out.exists()  # with its fixes: bridged
    config = tmp_path / "wider.toml"
    config.write_text("[smoother]\nmax_imu_gap_s = 15\n")
    out.unlink()
    assert main(["smooth", str(long_gap), "--config", str(config), "--method", method,
                 "-o", str(out), "--no-progress"]) == 0  # fmt: skip


def test_a_dead_imu_axis_is_said_and_shown_when_the_solve_fails(tmp_path, capsys):
    """gyro_y all zeros on an independent simulator's hilly drive ran to "batch LM diverged"
    blamed on the GNSS sigmas, and the input checks' warnings were never printed when a
    solve failed. Now each constant axis is a warning (not an error: a level car simulated
    without noise has exactly zero roll and pitch rates), printed before the solve's error."""
    import pandas as pd

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, hilly_drive, write_drive

    write_drive(tmp_path, hilly_drive(), 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=3)  # fmt: skip
    imu = pd.read_csv(tmp_path / "imu.csv")
    imu["gyro_y"] = 0.0
    imu.to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
    files = [str(tmp_path / "imu.csv"), str(tmp_path / "gnss.csv")]
    dataset = read_csv_dataset([Path(f) for f in files])
    from fgins.io.validate import validate_dataset

    checked = validate_dataset(dataset, vehicle="car")
    dead = [w for w in checked.warnings if "gyro_y reads 0 in every one of" in w]
    assert len(dead) == 1, checked.warnings
    assert not [w for w in checked.warnings if "accel_" in w and "every one of" in w]
    capsys.readouterr()
    code = main(["smooth", *files, "--config", str(tmp_path / "cfg.toml"), "--vehicle", "car",
                 "-o", str(tmp_path / "out.csv"), "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "fgins: error:" in err, err
    assert err.index("gyro_y reads 0 in every one of") < err.index("fgins: error:"), err
    assert not (tmp_path / "out.csv").exists()
