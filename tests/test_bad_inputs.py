"""The bad-input table (issue 12, items 4-6): every user mistake ends in one clear line.

Each case runs ``fgins.cli.main([...])`` in-process on a short simulated drive (``fgins sim
car-urban``, 20 s) with one thing wrong, and checks what the user sees and what is left on
disk: exit code 2 and exactly one ``error:`` line on stderr (or, where the input can be
repaired, exit 0 with a counted ``warning:`` line), never a traceback or an "internal error",
no output file for an error, and every input byte-identical afterwards. For an error the solver
must not run at all: ``run_method`` is replaced by one that fails the test, so an error
raised only after the solve (the old ``-o somefile.csv/out.csv`` behaviour) is caught.

"""

from __future__ import annotations

import hashlib
import math
import re
import shutil
import time
from dataclasses import dataclass, field
from functools import reduce
from pathlib import Path

import numpy as np
import pytest

from fgins import cli, pipeline

DURATION_S = 20.0


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory) -> Path:
    """A 20 s urban car drive written by the simulator's own CLI command."""
    folder = tmp_path_factory.mktemp("sim") / "drive"
    assert cli.main(["sim", "car-urban", "-o", str(folder), "--duration", str(DURATION_S)]) == 0
    return folder


# --- how a case changes the input ------------------------------------------------------------


def _edit_csv(path: Path, edit) -> None:
    """Rewrite a CSV through ``edit(header, rows)`` (rows: a float array, NaN for empty)."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    rows = np.array([[float(v) if v else math.nan for v in line.split(",")] for line in lines[1:]])
    edited = edit(header, rows)  # in place, or a new table returned
    rows = rows if edited is None else edited
    text = [",".join(header)]
    text += [",".join("" if math.isnan(v) else repr(float(v)) for v in row) for row in rows]
    path.write_text("\n".join(text) + "\n")


def _column(header: list[str], name: str) -> int:
    return header.index(name)


def _set_fix(column: str, value: float, row: int = 7):
    def edit(header, rows):
        rows[row, _column(header, column)] = value

    return edit


def _baro_csv(pressure: float, start: float = 0.0) -> bytes:
    """20 s of a barometer at 10 Hz from ``start`` reading ``pressure`` (a unit mistake if not
    pascals)."""
    rows = "".join(f"{start + k / 10:.1f},{pressure!r}\n" for k in range(200))
    return ("time,pressure_pa\n" + rows).encode()


def _set_rows(column: str, value: float, rows: range):
    def edit(header, table):
        table[list(rows), _column(header, column)] = value

    return edit


def _scale_imu(columns: tuple[str, ...], factor: float):
    def edit(header, rows):
        for name in columns:
            rows[:, _column(header, name)] *= factor

    return edit


def _freeze_position(header, rows):
    for name in ("lat", "lon", "alt"):
        rows[:, _column(header, name)] = rows[0, _column(header, name)]


def _without_velocity(header, rows):
    keep = [i for i, name in enumerate(header) if not name.startswith("vel_")]
    header[:] = [header[i] for i in keep]
    return rows[:, keep]


def _logged_twice(header, rows):
    return np.vstack([rows, rows])


def _two_files_overlapping(header, rows):
    """Two recordings of one span, their clocks 0.37 of a period apart, one after the other."""
    other = rows.copy()
    other[:, 0] += 0.37 * float(np.median(np.diff(rows[:, 0])))
    return np.vstack([rows, other])


def _shuffled(header, rows):
    return rows[np.random.default_rng(0).permutation(len(rows))]


def _with_checksum(body: str) -> str:
    checksum = reduce(lambda acc, char: acc ^ ord(char), body, 0)
    return f"${body}*{checksum:02X}"


def _nmea_from_gnss_csv(gnss_csv: Path, corrupt: bool) -> str:
    """GGA lines of the drive's fixes (no date: times are seconds of the UTC day, the same
    base as the simulator's IMU). ``corrupt`` mixes in what a damaged log holds: binary noise,
    a truncated line, a bad checksum (all without a usable time), and two fixes with valid
    checksums but impossible content (altitude 1e30 m; a jump of ~860 km to longitude 0)."""
    lines = gnss_csv.read_text().splitlines()
    header = lines[0].split(",")
    out = []
    for k, line in enumerate(lines[1:]):
        v = dict(zip(header, line.split(","), strict=True))
        t = float(v["time"])
        lat, lon, alt = float(v["lat"]), float(v["lon"]), float(v["alt"])
        if corrupt and k == 8:
            alt = 1e30
        if corrupt and k == 12:
            lon = 0.0
        hh, mm, ss = int(t // 3600), int(t % 3600 // 60), t % 60
        lat_txt = f"{int(abs(lat)):02d}{abs(lat) % 1 * 60:08.5f},{'N' if lat >= 0 else 'S'}"
        lon_txt = f"{int(abs(lon)):03d}{abs(lon) % 1 * 60:08.5f},{'E' if lon >= 0 else 'W'}"
        stamp = f"{hh:02d}{mm:02d}{ss:05.2f}"
        gga = f"GPGGA,{stamp},{lat_txt},{lon_txt},1,12,{float(v['hdop']):.2f},{alt:.3f},M,0.0,M,,"
        out.append(_with_checksum(gga))
        if corrupt and k % 5 == 2:
            out.append("$GPGGA,\x00\x07\xff garbage")  # binary noise
            out.append(_with_checksum(gga)[:30])  # truncated
            out.append(f"${gga}*00")  # bad checksum
    return "\r\n".join(out) + "\r\n"


@dataclass
class Case:
    """One bad input: files written into the drive folder, the command, what must happen.

    ``args`` may use {drive}, {config}, {out}, {imu}, {gnss}, {nmea}, {file} placeholders.
    ``expect`` is a regex the error (or warning) line must match. ``warning_ok``: the input
    may instead be repaired with a counted warning (exit 0, output written).
    """

    name: str
    args: list[str]
    expect: str
    config: str | None = None
    edit_gnss: object = None
    edit_imu: object = None
    edit_sim_config: object = None
    nmea: str | None = None  # "good" or "corrupt"
    warning_ok: bool = False
    out: str = "{tmp}/out.csv"
    extra_files: dict[str, bytes] = field(default_factory=dict)


SMOOTH = ["smooth", "{drive}", "--method", "ekf", "-o", "{out}", "--no-progress"]
WITH_CONFIG = [*SMOOTH, "--config", "{config}"]


def _toml_case(name: str, toml: str, expect: str) -> Case:
    return Case(name, WITH_CONFIG, expect, config=toml)


CONFIG_CASES = [
    _toml_case(
        "non-number",
        '[imu]\ngyro_arw_deg_per_sqrt_hr = "abc"\n',
        r'\[imu\]\.gyro_arw_deg_per_sqrt_hr = "abc": expected a number',
    ),
    _toml_case(
        "nan-noise",
        "[imu]\naccel_vrw_m_per_s_per_sqrt_hr = nan\n",
        r"\[imu\]\.accel_vrw_m_per_s_per_sqrt_hr = nan: expected a finite number",
    ),
    _toml_case(
        "inf-noise",
        "[imu]\ngyro_bias_instability_deg_per_hr = inf\n",
        r"gyro_bias_instability_deg_per_hr = inf: expected a finite number",
    ),
    _toml_case(
        "negative-noise",
        "[imu]\ngyro_arw_deg_per_sqrt_hr = -0.3\n",
        r"gyro_arw_deg_per_sqrt_hr = -0\.3: must be > 0",
    ),
    _toml_case(
        "negative-bias-instability",
        "[imu]\naccel_bias_instability_mg = -0.1\n",
        r"accel_bias_instability_mg = -0\.1: must be >= 0 \(0 means a constant bias",
    ),
    _toml_case(
        "negative-bias-rw",
        "[imu]\ngyro_bias_rw_rad_per_s_per_sqrt_s = -1e-6\n",
        r"gyro_bias_rw_rad_per_s_per_sqrt_s = -1e-06: must be >= 0",
    ),
    _toml_case(
        "zero-white-noise",
        "[imu]\naccel_vrw_m_per_s_per_sqrt_hr = 0\n",
        r"accel_vrw_m_per_s_per_sqrt_hr = 0: must be > 0 \(zero white noise makes the IMU "
        r"factors singular; give the datasheet value",
    ),
    _toml_case(
        "boolean-noise",
        "[imu]\naccel_turn_on_bias_mg = true\n",
        r"accel_turn_on_bias_mg = true: expected a number, got a boolean",
    ),
    _toml_case(
        "zero-turn-on-bias",
        "[imu]\ngyro_turn_on_bias_deg_per_s = 0\n",
        r"gyro_turn_on_bias_deg_per_s = 0: must be > 0 \(it is the prior sigma",
    ),
    _toml_case(
        "unknown-preset", '[imu]\npreset = "potato"\n', r'\[imu\]\.preset = "potato".*tactical'
    ),
    _toml_case("unknown-imu-key", "[imu]\ngyro_arw = 0.3\n", r"unknown key.*gyro_arw"),
    _toml_case("imu-not-a-table", "imu = 5\n", r"\[imu\] = 5: expected a table"),
    _toml_case("unknown-section", "[imus]\npreset = 'tactical'\n", r"unknown section.*imus"),
    _toml_case("bad-toml", "[imu\n", r"config file .*config\.toml"),
    _toml_case(
        "sigma-zeros",
        "[gnss]\nsigma_m = [0, 0, 0]\n",
        r"\[gnss\]\.sigma_m = \[0, 0, 0\]: must be >= 0\.001",
    ),
    _toml_case(
        "sigma-negative", "[gnss]\nsigma_m = -1.0\n", r"\[gnss\]\.sigma_m = -1\.0: must be >= 0\.001"
    ),
    # 1e-9 m pinned the track to every fix: the solve diverged, blaming the IMU noise.
    _toml_case(
        "sigma-nanometres",
        "[gnss]\nsigma_m = [1e-9, 1e-9, 1e-9]\n",
        r"\[gnss\]\.sigma_m = \[1e-09, 1e-09, 1e-09\]: must be >= 0\.001 .*RTK",
    ),
    _toml_case(
        "velocity-sigma-tiny",
        "[gnss]\nvelocity_sigma_m_per_s = 1e-6\n",
        r"\[gnss\]\.velocity_sigma_m_per_s = 1e-06: must be >= 0\.001",
    ),
    _toml_case(
        "lever-arm-length",
        "[gnss]\nlever_arm_m = [0.5, 0.0]\n",
        r"\[gnss\]\.lever_arm_m = \[0\.5, 0\.0\]: expected 3 numbers",
    ),
    _toml_case(
        "lever-arm-non-number",
        '[gnss]\nlever_arm_m = [0.5, "x", 1.2]\n',
        r'\[gnss\]\.lever_arm_m = \[0\.5, "x", 1\.2\]: expected numbers',
    ),
    _toml_case(
        "lever-arm-in-mm",
        "[gnss]\nlever_arm_m = [500, 0, 1200]\n",
        r"\[gnss\]\.lever_arm_m = \[500, 0, 1200\]: must be within \+-100 \(metres",
    ),
    _toml_case(
        "uere-negative",
        "[gnss]\nuere_m = { autonomous = -3.0 }\n",
        r"\[gnss\]\.uere_m\.autonomous = -3\.0: must be > 0",
    ),
    _toml_case(
        "uere-unknown-quality",
        "[gnss]\nuere_m = { rtk = 0.05 }\n",
        r"\[gnss\]\.uere_m\.rtk = 0\.05: unknown key; valid keys are autonomous, dgps",
    ),
    _toml_case(
        "uere-not-a-table", "[gnss]\nuere_m = 3.0\n", r"\[gnss\]\.uere_m = 3\.0: expected a table"
    ),
    _toml_case("pdop-zero", "[gnss]\npdop_max = 0\n", r"\[gnss\]\.pdop_max = 0: must be > 0"),
    _toml_case(
        "pdop-string", '[gnss]\npdop_max = "5"\n', r'\[gnss\]\.pdop_max = "5": expected a number'
    ),
    _toml_case(
        "use-velocity-number",
        "[gnss]\nuse_velocity = 1\n",
        r"\[gnss\]\.use_velocity = 1: expected true or false",
    ),
    _toml_case(
        "vehicle-boat-toml",
        '[smoother]\nvehicle = "boat"\n',
        r'\[smoother\]\.vehicle = "boat": expected one of car, aircraft, uav, pedestrian, other',
    ),
    _toml_case(
        "mounting-two-angles",
        "[smoother]\nimu_to_vehicle_rpy_deg = [0.0, 10.0]\n",
        r"imu_to_vehicle_rpy_deg = \[0\.0, 10\.0\]: expected 3 numbers",
    ),
    _toml_case(
        "mounting-nan",
        "[smoother]\nimu_to_vehicle_rpy_deg = [0.0, nan, 0.0]\n",
        r"imu_to_vehicle_rpy_deg = \[0\.0, nan, 0\.0\]: expected a finite number",
    ),
    _toml_case(
        "iterations-fraction",
        "[smoother]\nbatch_max_iterations = 2.5\n",
        r"batch_max_iterations = 2\.5: expected a whole number",
    ),
    _toml_case("iterations-zero", "[smoother]\nbatch_max_iterations = 0\n", r"must be >= 1"),
    _toml_case(
        "nhc-sigma-zero",
        "[smoother]\nnhc_sigma_lateral_m_per_s = 0.0\n",
        r"nhc_sigma_lateral_m_per_s = 0\.0: must be > 0",
    ),
    _toml_case(
        "use-nhc-string",
        '[smoother]\nuse_nhc = "yes"\n',
        r'use_nhc = "yes": expected true or false',
    ),
    _toml_case(
        "keyframe-intervals-crossed",
        "[smoother]\nmin_keyframe_interval_s = 2.0\nmax_keyframe_interval_s = 1.0\n",
        r"min_keyframe_interval_s = 2\.0: must not exceed max_keyframe_interval_s",
    ),
    Case(
        "config-missing",
        [*SMOOTH, "--config", "{tmp}/nope.toml"],
        r"config file .*nope\.toml not found",
    ),
    Case("config-is-a-folder", [*SMOOTH, "--config", "{tmp}"], r"is a folder"),
    Case(
        "config-binary",
        [*SMOOTH, "--config", "{tmp}/blob.toml"],
        r"config file .*blob\.toml: not a text",
        extra_files={"blob.toml": b"\xff\xfe\x00\x81binary"},
    ),
    # The dataset's own settings (a sim folder's config.toml) are checked the same way.
    Case(
        "dataset-sigma-zeros",
        SMOOTH,
        r"sensor settings of drive: \[gnss\]\.sigma_m = \[0, 0, 0\]: must be >= 0\.001",
        edit_sim_config=lambda text: text.replace("[gnss]\n", "[gnss]\nsigma_m = [0, 0, 0]\n"),
    ),
    Case(
        "dataset-noise-string",
        SMOOTH,
        r'sensor settings of drive: \[imu\]\.gyro_noise_rad_per_s_per_sqrt_hz = "abc"',
        edit_sim_config=lambda text: re.sub(
            r"gyro_noise_rad_per_s_per_sqrt_hz = \S+",
            'gyro_noise_rad_per_s_per_sqrt_hz = "abc"',
            text,
        ),
    ),
    # A misspelt section of the folder's own config.toml was ignored without a word.
    Case(
        "dataset-unknown-section",
        SMOOTH,
        r"config\.toml: unknown section\(s\) \[smoothr\] \(valid: .*\[smoother\]",
        edit_sim_config=lambda text: text + '\n[smoothr]\nvehicle = "car"\n',
    ),
    Case(
        "dataset-vehicle-boat",
        SMOOTH,
        r'sensor settings of drive: vehicle = "boat": expected one of car',
        edit_sim_config=lambda text: text.replace('vehicle = "car"', 'vehicle = "boat"'),
    ),
    # A sim folder's [origin] (hand-edited): every key checked like the rest (an outside
    # tester: a missing alt was "internal error: KeyError", a list a TypeError, a quoted
    # number or an unknown key passed; an origin 3,900 km off the fixes gave 43 m errors).
    Case(
        "origin-missing-alt",
        SMOOTH,
        r"config\.toml: \[origin\]: missing alt",
        edit_sim_config=lambda text: re.sub(r"(\[origin\][^\[]*?)alt = \S+\n", r"\1", text),
    ),
    Case(
        "origin-list",
        SMOOTH,
        r"\[origin\]\.lat = \[48\.0\]: expected a number",
        edit_sim_config=lambda text: re.sub(r"(\[origin\]\n)lat = \S+", r"\1lat = [48.0]", text),
    ),
    Case(
        "origin-quoted",
        SMOOTH,
        r'\[origin\]\.lat = "48\.1": expected a number',
        edit_sim_config=lambda text: re.sub(r"(\[origin\]\n)lat = \S+", r'\1lat = "48.1"', text),
    ),
    Case(
        "origin-unknown-key",
        SMOOTH,
        r"\[origin\]: unknown key\(s\) foo",
        edit_sim_config=lambda text: text.replace("[origin]\n", "[origin]\nfoo = 1\n"),
    ),
    Case(
        "origin-far-from-the-fixes",
        SMOOTH,
        r"frame: the origin .* lies [\d,]+ km from the nearest fix",
        edit_sim_config=lambda text: re.sub(r"(\[origin\]\n)lat = \S+", r"\1lat = 10.0", text),
    ),
    # Two keys for one quantity in one table: one would be ignored.
    _toml_case(
        "arw-and-density",
        "[imu]\ngyro_arw_deg_per_sqrt_hr = 0.3\ngyro_noise_rad_per_s_per_sqrt_hz = 1e-2\n",
        r"gyro_arw_deg_per_sqrt_hr and gyro_noise_rad_per_s_per_sqrt_hz both given",
    ),
    # CLI choices: argparse refuses them (exit 2, one "error:" line, no usage block).
    Case("vehicle-boat-cli", [*SMOOTH, "--vehicle", "boat"], r"--vehicle: invalid choice: 'boat'"),
    Case("preset-cli", [*SMOOTH, "--imu-preset", "potato"], r"--imu-preset: invalid choice"),
    Case(
        "method-cli", ["smooth", "{drive}", "--method", "magic", "-o", "{out}"], r"invalid choice"
    ),
]

OUTPUT_CASES = [
    # An output path under an existing file must fail before the solve, not after it.
    pytest.param(
        Case(
            "output-under-a-file",
            SMOOTH,
            r"somefile\.csv",
            out="{tmp}/somefile.csv/out.csv",
            extra_files={"somefile.csv": b"not a folder\n"},
        ),
        id="output-under-a-file",
    ),
    pytest.param(
        Case("output-is-the-input", SMOOTH, r"imu\.csv", out="{drive}/imu.csv"),
        id="output-is-the-input",
    ),
    pytest.param(
        Case(
            "output-is-the-input-pair",
            ["smooth", "{imu}", "{gnss}", "--method", "ekf", "-o", "{out}"],
            r"gnss\.csv",
            out="{drive}/gnss.csv",
        ),
        id="output-is-the-input-pair",
    ),
    Case("output-bad-suffix", SMOOTH, r"output format must be one of", out="{tmp}/out.txt"),
]

def _gnss_times_scaled(factor: float):
    def edit(header, rows):
        rows[:, _column(header, "time")] *= factor

    return edit


DATA_CASES = [
    pytest.param(
        Case(
            "latitude-91",
            SMOOTH,
            r"latitude|lat\b",
            edit_gnss=_set_fix("lat", 91.0),
            warning_ok=True,
        ),
        id="latitude-91",
    ),
    pytest.param(
        Case(
            "altitude-1e7",
            SMOOTH,
            r"altitude|height|alt\b",
            edit_gnss=_set_fix("alt", 1e7),
            warning_ok=True,
        ),
        id="altitude-1e7",
    ),
    pytest.param(
        Case(
            "gyro-in-deg-per-s",
            SMOOTH,
            r"deg/s",
            edit_imu=_scale_imu(("gyro_x", "gyro_y", "gyro_z"), 180.0 / math.pi),
        ),
        id="gyro-in-deg-per-s",
    ),
    pytest.param(
        Case(
            "accel-in-g",
            SMOOTH,
            r"\bg\b|units? of g|in g",
            edit_imu=_scale_imu(("accel_x", "accel_y", "accel_z"), 1.0 / 9.80665),
        ),
        id="accel-in-g",
    ),
    pytest.param(
        Case(
            "accel-1e300-records",
            SMOOTH,
            r"11 sample\(s\) with values no IMU measures \(\|accel\| up to 1e\+300",
            edit_imu=_set_rows("accel_x", 1e300, range(1000, 1011)),
            warning_ok=True,
        ),
        id="accel-1e300-records",
    ),
    pytest.param(
        Case(
            "gyro-in-mrad-per-s",
            SMOOTH,
            r"samples hold values no IMU measures .* unit or scale mistake",
            edit_imu=_scale_imu(("gyro_x", "gyro_y", "gyro_z"), 1e5),
        ),
        id="gyro-scaled-1e5",
    ),
    pytest.param(
        Case(
            "baro-in-hpa",
            ["smooth", "{imu}", "{gnss}", "{tmp}/baro.csv", "--method", "ekf", "-o", "{out}"],
            r"median pressure is 955 Pa.*hPa \(mbar\): multiply by 100",
            extra_files={"baro.csv": _baro_csv(955.0)},
        ),
        id="baro-in-hpa",
    ),
    pytest.param(
        Case(
            "baro-in-kpa",
            ["smooth", "{imu}", "{gnss}", "{tmp}/baro.csv", "--method", "ekf", "-o", "{out}"],
            r"median pressure is 95\.5 Pa.*kPa: multiply by 1000",
            extra_files={"baro.csv": _baro_csv(95.5)},
        ),
        id="baro-in-kpa",
    ),
    pytest.param(
        Case(
            "frozen-position",
            SMOOTH,
            r"gnss: the position never changes .* while the IMU (turns|accelerates)",
            edit_gnss=_freeze_position,
        ),
        id="frozen-position",
    ),
    pytest.param(
        Case(
            "frozen-position-without-velocity",
            SMOOTH,
            r"gnss: the position never changes .* while the IMU (turns|accelerates)",
            edit_gnss=lambda header, rows: _without_velocity(header, rows)
            if _freeze_position(header, rows) is None else None,
        ),
        id="frozen-position-without-velocity",
    ),
    pytest.param(
        Case(
            "fix-without-time",
            SMOOTH,
            r"dropped 1 fix\(es\) without a time",
            edit_gnss=_set_fix("time", math.nan),
            warning_ok=True,
        ),
        id="fix-without-time",
    ),
    pytest.param(
        Case(
            "imu-logged-twice",
            SMOOTH,
            r"IMU time goes backwards at sample \d+ .* the log mixes clocks or files",
            edit_imu=_logged_twice,
        ),
        id="imu-logged-twice",
    ),
    pytest.param(
        Case(
            "imu-rows-shuffled",
            SMOOTH,
            r"IMU time goes backwards at sample \d+ .* the log mixes clocks or files",
            edit_imu=_shuffled,
        ),
        id="imu-rows-shuffled",
    ),
    pytest.param(
        Case(
            "imu-two-files-interleaved",
            SMOOTH,
            r"IMU time goes backwards at sample \d+ .* the log mixes clocks or files",
            edit_imu=_two_files_overlapping,
        ),
        id="imu-two-files-interleaved",
    ),
    pytest.param(
        Case(
            "baro-negative",
            ["smooth", "{imu}", "{gnss}", "{tmp}/baro.csv", "--method", "ekf", "-o", "{out}"],
            r"baro: 200 of 200 samples have a pressure no barometer gives \(e\.g\. -95500 Pa\)",
            extra_files={"baro.csv": _baro_csv(-95500.0)},
        ),
        id="baro-negative",
    ),
    pytest.param(
        Case(
            "baro-off-the-imu-clock",
            ["smooth", "{imu}", "{gnss}", "{tmp}/baro.csv", "--method", "ekf", "-o", "{out}"],
            r"baro: none of its 200 samples .* lies within the IMU's span",
            extra_files={"baro.csv": _baro_csv(95500.0, start=5000.0)},
            warning_ok=True,
        ),
        id="baro-off-the-imu-clock",
    ),
    pytest.param(
        Case(
            "nmea-and-gnss-csv",
            ["smooth", "{gnss}", "{nmea}", "{imu}", "--method", "ekf", "-o", "{out}"],
            r"two GNSS sources: log\.nmea and gnss\.csv; give one of them",
            nmea="good",
        ),
        id="nmea-and-gnss-csv",
    ),
    pytest.param(
        Case(
            "corrupt-nmea-with-imu-csv",
            ["smooth", "{nmea}", "{imu}", "--method", "ekf", "-o", "{out}"],
            r"altitude|height|jump|implausible|impossible|range|outside",
            nmea="corrupt",
            warning_ok=True,
        ),
        id="corrupt-nmea-with-imu-csv",
    ),
]


def _snapshot(folder: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every file below ``folder``."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _prepare(case: Case, sim_dir: Path, tmp_path: Path) -> tuple[list[str], Path]:
    drive = tmp_path / "drive"
    shutil.copytree(sim_dir, drive)
    (drive / "truth.csv").unlink()  # keep the folder to the inputs a user has
    if case.edit_gnss is not None:
        _edit_csv(drive / "gnss.csv", case.edit_gnss)
    if case.edit_imu is not None:
        _edit_csv(drive / "imu.csv", case.edit_imu)
    if case.edit_sim_config is not None:
        path = drive / "config.toml"
        edited = case.edit_sim_config(path.read_text())
        assert edited != path.read_text(), "the case did not change config.toml"
        path.write_text(edited)
    nmea = tmp_path / "log.nmea"
    if case.nmea is not None:
        nmea.write_text(_nmea_from_gnss_csv(drive / "gnss.csv", case.nmea == "corrupt"))
    config = tmp_path / "config.toml"
    if case.config is not None:
        config.write_text(case.config)
    for name, data in case.extra_files.items():
        (tmp_path / name).write_bytes(data)
    names = {
        "drive": drive, "config": config, "imu": drive / "imu.csv", "gnss": drive / "gnss.csv",
        "nmea": nmea, "tmp": tmp_path,
    }  # fmt: skip
    out = Path(case.out.format(**names))
    args = [a.format(out=out, **names) for a in case.args]
    return args, out


def _run(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(args)
    except SystemExit as exc:  # argparse refusing an option
        code = exc.code if isinstance(exc.code, int) else 2
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _solver_must_not_run(*_args, **_kwargs):
    raise AssertionError("the solver ran although the input is invalid")


def _check_case(case: Case, sim_dir: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    args, out = _prepare(case, sim_dir, tmp_path)
    before = _snapshot(tmp_path)
    if not case.warning_ok:
        # An error must be found before any solving: fail loudly if the solver is reached.
        monkeypatch.setattr(pipeline, "run_method", _solver_must_not_run)
        monkeypatch.setattr(cli, "run_method", _solver_must_not_run, raising=False)
    started = time.perf_counter()
    code, stdout, stderr = _run(args, capsys)
    elapsed = time.perf_counter() - started
    text = stdout + stderr
    assert "Traceback" not in text and "internal error" not in text, stderr
    after = _snapshot(tmp_path)
    out_key = str(out.relative_to(tmp_path)) if out.is_relative_to(tmp_path) else None
    # Inputs untouched: every file that was there is byte-identical.
    changed = [name for name, digest in before.items() if after.get(name) != digest]
    assert not changed, f"inputs changed: {changed}"
    error_lines = [line for line in stderr.splitlines() if re.match(r"fgins[ \w]*: error: ", line)]
    if code == 0 and case.warning_ok:
        warnings = [line for line in stderr.splitlines() if line.startswith("warning: ")]
        matching = [w for w in warnings if re.search(case.expect, w) and re.search(r"\d", w)]
        assert matching, f"no counted warning matching {case.expect!r} in:\n{stderr}"
        assert not error_lines
        return
    assert code == 2, f"exit code {code}; stderr:\n{stderr}"
    assert len(error_lines) == 1, stderr
    assert "usage:" not in stderr, stderr  # one line, not argparse's usage block before it
    assert re.search(case.expect, error_lines[0]), error_lines[0]
    assert not out.exists() or (out_key in before), f"{out} was written"
    new_files = sorted(set(after) - set(before))
    assert not new_files, f"files left behind: {new_files}"
    assert elapsed < 10.0, f"an input error took {elapsed:.1f} s to report"


@pytest.mark.parametrize("case", CONFIG_CASES, ids=lambda c: c.name)
def test_bad_config(case, sim_dir, tmp_path, capsys, monkeypatch):
    _check_case(case, sim_dir, tmp_path, capsys, monkeypatch)


@pytest.mark.parametrize("case", OUTPUT_CASES, ids=lambda c: getattr(c, "name", None))
def test_bad_output_path(case, sim_dir, tmp_path, capsys, monkeypatch):
    _check_case(case, sim_dir, tmp_path, capsys, monkeypatch)


@pytest.mark.parametrize("case", DATA_CASES)
def test_bad_data(case, sim_dir, tmp_path, capsys, monkeypatch):
    _check_case(case, sim_dir, tmp_path, capsys, monkeypatch)


@pytest.fixture(scope="module")
def highway_dir(tmp_path_factory) -> Path:
    """60 s of a motorway drive (~30 m/s): far more track than the fixes' scatter."""
    folder = tmp_path_factory.mktemp("highway") / "drive"
    assert cli.main(["sim", "highway", "-o", str(folder), "--duration", "60"]) == 0
    return folder


@pytest.mark.parametrize("factor", [1e-3, 1e-2])
def test_gnss_times_in_other_units_than_seconds_are_refused(factor, highway_dir, tmp_path, capsys,
                                                            monkeypatch):
    """Fixes 1 or 10 ms apart moving ~30 m each stay within their sigmas of their neighbours,
    so the jump checks passed them: a car drive with its GNSS times divided by 1000 came out
    516 m off with exit code 0 (its fit only "inconsistent"). The track's speed over chords far
    beyond the fixes' scatter is 3,000-30,000 m/s."""
    case = Case(
        "gnss-times-scaled",
        SMOOTH,
        r"gnss: the track moves at [\d,]+ m/s .*faster than any vehicle.*not in seconds",
        edit_gnss=_gnss_times_scaled(factor),
    )
    _check_case(case, highway_dir, tmp_path, capsys, monkeypatch)


def _posix_times_some_fixes_at_zero(header, rows):
    rows[:, _column(header, "time")] += 1.7e9
    rows[[3, 9, 14], _column(header, "time")] = 0.0  # a driver's unset stamps (1970)


def _posix_times(header, rows):
    rows[:, _column(header, "time")] += 1.7e9


def test_a_few_fixes_stamped_zero_among_posix_times_are_counted_not_fatal(sim_dir, tmp_path, capsys,
                                                                         monkeypatch):
    """Three fixes stamped 0 (1970) among POSIX-time ones: the clock check built its grid of
    windows over the fixes' whole span, 54 years (25 GiB), and the run ended in "out of
    memory". Two repeat the first's stamp (dropped, counted); the one left lies outside the
    IMU's span: counted, and the drive smoothed."""
    case = Case(
        "fixes-stamped-zero",
        SMOOTH,
        r"1 of \d+ GNSS epoch\(s\) lie outside the IMU time span",
        edit_gnss=_posix_times_some_fixes_at_zero,
        edit_imu=_posix_times,
        warning_ok=True,
    )
    _check_case(case, sim_dir, tmp_path, capsys, monkeypatch)


def test_good_inputs_pass_the_same_harness(sim_dir, tmp_path, capsys):
    """The harness is not vacuous: the unchanged drive, its NMEA version with an IMU CSV and
    a constant-bias config (zero bias instability is valid) all run, exit 0, write output."""
    cases = [
        Case("plain", SMOOTH, ""),
        Case(
            "nmea", ["smooth", "{nmea}", "{imu}", "--method", "ekf", "-o", "{out}"], "", nmea="good"
        ),
        Case(
            "constant-bias",
            WITH_CONFIG,
            "",
            config="[imu]\ngyro_bias_instability_deg_per_hr = 0\naccel_bias_instability_mg = 0\n",
        ),
    ]
    for case in cases:
        folder = tmp_path / case.name
        folder.mkdir()
        args, out = _prepare(case, sim_dir, folder)
        before = _snapshot(folder / "drive")
        code, _, stderr = _run(args, capsys)
        assert code == 0, f"{case.name}: {stderr}"
        assert out.exists() and out.stat().st_size > 0
        assert _snapshot(folder / "drive") == before
        rows = out.read_text().count("\n") - 1
        assert rows == int(DURATION_S * 100), (case.name, rows)


def test_output_inside_a_sim_folder_keeps_it_readable(sim_dir, tmp_path, capsys):
    """``-o drive/out.csv`` inside a sim folder: either refused up front (one error line) or
    written, and then the folder still reads as the same drive (the reader takes only its
    own file names, not every CSV with a GNSS-like header)."""
    drive = tmp_path / "drive"
    shutil.copytree(sim_dir, drive)
    before = _snapshot(drive)
    code, _, stderr = _run(
        ["smooth", str(drive), "--method", "ekf", "-o", str(drive / "out.csv")], capsys
    )
    assert "Traceback" not in stderr and "internal error" not in stderr, stderr
    if code == 2:
        assert len([line for line in stderr.splitlines() if "error:" in line]) == 1
        assert _snapshot(drive) == before
        return
    assert code == 0, stderr
    assert all(_snapshot(drive).get(name) == digest for name, digest in before.items())
    code, _, stderr = _run(
        ["smooth", str(drive), "--method", "ekf", "-o", str(tmp_path / "again.csv")], capsys
    )
    assert code == 0, f"the folder no longer reads after writing into it: {stderr}"


def test_no_fix_epochs_dropped_on_reading_appear_in_the_gnss_count_line(sim_dir, tmp_path, capsys):
    """GGA epochs with fix quality 0 are dropped by the NMEA reader, before the gates count:
    the count line used to show only the epochs left (a file of N epochs reported as fewer,
    the difference in a separate warning). It now names them on the same line, and its own
    counts still add up to the epochs that reached the gates."""
    lines = _nmea_from_gnss_csv(sim_dir / "gnss.csv", corrupt=False).split("\r\n")
    fixes = [line for line in lines if line]
    no_fix = set(range(5, len(fixes), 7))
    edited = []
    for k, line in enumerate(fixes):
        if k in no_fix:
            fields = line[1:].split("*")[0].split(",")
            fields[6] = "0"  # fix quality: invalid
            line = _with_checksum(",".join(fields))
        edited.append(line)
    nmea = tmp_path / "log.nmea"
    nmea.write_text("\r\n".join(edited) + "\r\n")
    out = tmp_path / "out.csv"
    args = ["smooth", str(nmea), str(sim_dir / "imu.csv"), "--method", "ekf", "-o", str(out)]
    code, stdout, stderr = _run([*args, "--no-progress"], capsys)
    assert code == 0, stderr
    printed = (stdout + stderr).splitlines()
    count_line = next(line for line in printed if line.startswith("GNSS: "))
    total = int(re.match(r"GNSS: (\d+) epochs", count_line).group(1))
    assert total == len(fixes) - len(no_fix)
    assert f"(+{len(no_fix)} epochs without a fix, dropped on reading)" in count_line


def test_no_fix_epochs_before_the_first_fix_do_not_move_the_outage_windows(sim_dir, tmp_path):
    """``--gnss-outage A:B`` counts from the first GNSS epoch in the input, usable or not
    (DESIGN.md). The NMEA reader drops quality-0 epochs, and t0 used to be the first *fix*:
    a log whose receiver needed 4 s for its first fix had every window 4 s late."""
    from fgins.io.inputs import load_dataset
    from fgins.outages import outage_mask

    lines = _nmea_from_gnss_csv(sim_dir / "gnss.csv", corrupt=False).split("\r\n")
    fixes = [line for line in lines if line]
    edited = []
    for k, line in enumerate(fixes):
        if k < 4:
            fields = line[1:].split("*")[0].split(",")
            fields[6] = "0"  # no fix yet
            line = _with_checksum(",".join(fields))
        edited.append(line)
    nmea = tmp_path / "log.nmea"
    nmea.write_text("\r\n".join(edited) + "\r\n")
    reference = load_dataset([str(sim_dir / "gnss.csv"), str(sim_dir / "imu.csv")], progress=False)
    dataset = load_dataset([str(nmea), str(sim_dir / "imu.csv")], progress=False)
    assert len(dataset.gnss) == len(reference.gnss) - 4
    assert dataset.t0 == pytest.approx(reference.t0, abs=0.01)
    withheld = dataset.gnss.t[~outage_mask(dataset, [(10.0, 20.0)])] - reference.t0
    assert len(withheld) and withheld.min() >= 10.0 - 0.01 and withheld.max() < 20.0


@pytest.mark.parametrize("errno_code", [28, 13, 30])  # ENOSPC, EACCES, EROFS
def test_the_machine_refusing_an_output_is_one_line(errno_code, sim_dir, tmp_path, capsys,
                                                     monkeypatch):  # fmt: skip
    """Disk full, no permission, a read-only file system while the output is written: one
    ``fgins: error:`` line naming the user's path and the reason, exit 2, no temporary file
    left (outside tester: "internal error: OSError: [Errno 28] No space left on device ...
    please report it", and the API raised a bare OSError)."""
    import errno
    import os

    from fgins.io import trajectory_csv

    def refuse(*_args, **_kwargs):
        raise OSError(errno_code, os.strerror(errno_code))

    monkeypatch.setattr(trajectory_csv, "write_table", refuse)
    out = tmp_path / "out.csv"
    code, _, stderr = _run(["smooth", str(sim_dir), "--method", "ekf", "-o", str(out)], capsys)
    lines = [line for line in stderr.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1, stderr
    assert lines[0] == f"fgins: error: cannot write {out}: {os.strerror(errno_code)}"
    assert "internal error" not in stderr and errno.errorcode[errno_code]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "edit, expect",
    [
        # A second gyro_x column of zeros: the last copy silently won (gyro x all zeros).
        (lambda h, rows: (h + ",gyro_x", [r + ",0.0" for r in rows]),
         r"imu\.csv: column\(s\) gyro_x appear more than once in the header"),
        # 'n/a' in accel_x on all but 10 rows: blamed on time spans, the drop never said.
        (lambda h, rows: (h, [_cell(r, 4, "n/a") for r in rows[:-10]] + rows[-10:]),
         r"imu\.csv: \d+ of \d+ data rows are malformed .*'n/a'"),
        # A trailing comma on every row: "no data rows".
        (lambda h, rows: (h, [r + "," for r in rows]),
         r"imu\.csv: (\d+) of \1 data rows are malformed \(a field count other than"),
    ],
    ids=["duplicate-column", "most-rows-not-numbers", "trailing-comma"],
)
def test_csv_rows_and_columns_that_cannot_be_read_are_named(edit, expect, sim_dir, tmp_path,
                                                            capsys):  # fmt: skip
    """Outside tester: each of these ran (the first at exit 0 with a zero gyro axis) or was
    refused for another cause; each is now its own one-line error."""
    lines = (sim_dir / "imu.csv").read_text().splitlines()
    header, rows = edit(lines[0], lines[1:])
    (tmp_path / "imu.csv").write_text("\n".join([header, *rows]) + "\n")
    out = tmp_path / "out.csv"
    args = ["smooth", str(tmp_path / "imu.csv"), str(sim_dir / "gnss.csv"), "-o", str(out)]
    code, _, stderr = _run(args, capsys)
    errors = [line for line in stderr.splitlines() if line.startswith("fgins: error: ")]
    assert code == 2 and len(errors) == 1, stderr
    assert re.search(expect, errors[0]), errors[0]
    assert not out.exists()


def _cell(row: str, column: int, value: str) -> str:
    cells = row.split(",")
    cells[column] = value
    return ",".join(cells)


def test_a_barometer_beside_an_nmea_log_is_read(sim_dir, tmp_path):
    """baro.csv (and wheel.csv) given with an NMEA log and its IMU CSV were dropped without
    a word, like a second GNSS source; the barometer is now read (the low-cost study's UAV
    flies NMEA with a barometer)."""
    import fgins

    nmea = tmp_path / "log.nmea"
    nmea.write_text(_nmea_from_gnss_csv(sim_dir / "gnss.csv", corrupt=False))
    (tmp_path / "baro.csv").write_bytes(_baro_csv(95500.0))
    dataset = fgins.load(nmea, sim_dir / "imu.csv", tmp_path / "baro.csv")
    assert dataset.baro is not None and len(dataset.baro.t) == 200


@pytest.mark.parametrize("method", ["ekf", "batch"])
def test_gnss_count_line_adds_up_for_every_method(method, sim_dir, tmp_path, capsys):
    """GNSS 5 s late: the epochs past the IMU's end are counted as such, and the line's
    counts add up, for the Kalman baselines as for the graph (the EKF said "20 pass the
    gates" after a warning that 5 of them lie outside the IMU span; outside tester)."""
    lines = (sim_dir / "gnss.csv").read_text().splitlines()
    shifted = [lines[0]] + [f"{float(r.split(',', 1)[0]) + 5.0!r},{r.split(',', 1)[1]}"
                            for r in lines[1:]]  # fmt: skip
    (tmp_path / "gnss.csv").write_text("\n".join(shifted) + "\n")
    out = tmp_path / "out.csv"
    args = ["smooth", str(sim_dir / "imu.csv"), str(tmp_path / "gnss.csv"), "--method", method,
            "--gnss-outage", "2:4", "-o", str(out)]  # fmt: skip
    code, _, stderr = _run(args, capsys)
    line = next(x for x in stderr.splitlines() if x.startswith("GNSS: "))
    total = int(re.match(r"GNSS: (\d+) epochs", line).group(1))
    counts = [int(n) for n in re.findall(r"(\d+) (?:used|withheld|outside|gated|by)", line)]
    assert code == 0 and sum(counts) == total, line
    assert re.search(r"[1-9]\d* outside the IMU time span", line), line
    assert re.search(r" 2 withheld by outage", line), line


@pytest.mark.parametrize(
    ("make", "command", "expect"),
    [
        (lambda d: (d / "imu.csv").write_bytes(b""), "smooth", r"imu\.csv: empty file \(0 bytes\)"),
        (lambda d: (d / "imu.csv").write_bytes(b""), "smooth-folder", r"imu\.csv: empty file \(0 bytes\)"),
        (lambda d: (d / "log.ubx").write_bytes(b""), "convert", r"log\.ubx: empty file"),
        (lambda d: (d / "log.ubx").write_bytes(b""), "inspect", r"log\.ubx: empty file"),
        (
            lambda d: (d / "log.ubx").write_bytes(bytes(30000)),
            "smooth",
            r"log\.ubx: holds only zero bytes \(30,000 of them\)",
        ),
        (
            lambda d: (d / "log.ubx").write_bytes(bytes(range(128, 256)) * 50),
            "smooth",
            r"log\.ubx: binary content that is none of the formats fgins reads",
        ),
        (lambda d: None, "convert-imu", r"imu\.csv: an imu CSV; convert takes a GNSS log"),
        (lambda d: None, "kitti-and-more", r"demo:kitti is a whole drive on its own"),
    ],
    ids=["empty-csv", "empty-csv-in-a-folder", "empty-ubx-convert", "empty-ubx-inspect", "zero-bytes", "binary-garbage",
         "convert-an-imu-csv", "demo-kitti-with-a-file"],
)  # fmt: skip
def test_a_file_that_holds_nothing_usable_is_named_for_what_it_is(
    make, command, expect, sim_dir, tmp_path, capsys
):
    """An outside tester: empty files and zero bytes were "unrecognised CSV header", binary
    garbage "not a text CSV file", an IMU CSV given to convert got advice about SiRF and
    RTCM, demo:kitti with a file was an "unknown built-in input"."""
    drive = tmp_path / "drive"
    shutil.copytree(sim_dir, drive)
    make(drive)
    target = next((p for p in drive.iterdir() if p.suffix == ".ubx"), drive / "imu.csv")
    out = str(tmp_path / "out.csv")
    args = {
        "smooth": ["smooth", str(target), str(drive / "gnss.csv"), "-o", out],
        "smooth-folder": ["smooth", str(drive), "-o", out],  # named as given by name (tester)
        "convert": ["convert", str(target), "-o", out],
        "inspect": ["inspect", str(target)],
        "convert-imu": ["convert", str(drive / "imu.csv"), "-o", out],
        "kitti-and-more": ["smooth", "demo:kitti", str(drive / "imu.csv"), "-o", out],
    }[command]
    code, _, stderr = _run(args, capsys)
    assert code == 2, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and re.search(expect, lines[0]), stderr
    assert not Path(out).exists()


def test_inspect_reads_a_ubx_log_saved_as_csv_by_its_content(shared, tmp_path, capsys):
    """smooth and convert sniff the content; inspect went by the suffix and called a UBX log
    named .csv "not a text CSV file"."""
    source = sorted((shared / "data" / "ubx" / "gpsd").glob("*.log"))[0]
    renamed = tmp_path / "log.csv"
    renamed.write_bytes(source.read_bytes())
    code, stdout, stderr = _run(["inspect", str(renamed)], capsys)
    assert code == 0, stderr
    assert stdout.startswith(f"u-blox UBX log {renamed}")


def test_a_ubx_log_cut_short_is_called_short_not_two_clocks(shared, tmp_path, capsys):
    """One UBX log (IMU and fixes on one clock) cut at half: the error blamed different time
    bases and advised --time-offset (outside tester); it is a recording too short."""
    source = shared / "data" / "ubx" / "gpsd" / "ublox-neo-m8u.log"
    data = source.read_bytes()
    cut = tmp_path / "cut.ubx"
    cut.write_bytes(data[: len(data) // 2])
    code, _, stderr = _run(["smooth", str(cut), "-o", str(tmp_path / "out.csv")], capsys)
    assert code == 2, stderr
    assert "recording is too short" in stderr and "time-offset" not in stderr, stderr
