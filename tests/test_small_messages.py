"""Outside tester s47/h1, findings 2-6: inspect's DOP statistics, inspect of a folder,
demo:kitti given to convert/inspect, ``load("")`` and plot()'s error type."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.cli import main
from fgins.io.gnss_checks import check_gnss_records
from fgins.io.nmea import read_nmea, summarize_nmea
from fgins.tests.cli_checks import cli_error
from fgins.tests.conftest import shared_dir


def _line(body: str) -> str:
    checksum = 0
    for char in body:
        checksum ^= ord(char)
    return f"${body}*{checksum:02X}"


def _log_with_placeholder_dops(path: Path) -> Path:
    """Four fixes: two with real DOPs, one with NMEA's 0.00 and one with 99.99."""
    lines = []
    for second, dops in enumerate(["1.8,1.0,1.5", "1.9,1.1,1.6", "0.00,0.00,0.00", "99.99,99.99,99.99"]):
        tod = f"1200{second:02d}.00"
        lines.append(_line(f"GPGGA,{tod},4807.038,N,01131.000,E,1,08,,545.4,M,46.9,M,,"))
        lines.append(_line(f"GPGSA,A,3,04,05,09,12,,,,,,,,,{dops}"))
    path.write_text("\n".join(lines) + "\n")
    return path


# --- 2. inspect's DOP statistics: the rule convert uses ------------------------------------


def test_inspect_dop_statistics_leave_out_not_available_values(tmp_path: Path) -> None:
    log = _log_with_placeholder_dops(tmp_path / "dops.nmea")
    summary = summarize_nmea(log)
    # hdop 1.0 and 1.1 only (not 0.00 or 99.99); pdop 1.8, 1.9
    assert "hdop min / median / max: 1.00 / 1.05 / 1.10" in summary, summary
    assert "pdop min / median / max: 1.80 / 1.85 / 1.90" in summary, summary
    # counted, in the words convert uses (one function for both)
    checks: list[str] = []
    check_gnss_records(read_nmea(log).gnss, checks)
    (note,) = [c for c in checks if "not available" in c]
    assert f"  warning: {note}" in summary.splitlines()
    assert "6 DOP value(s) in 2 fix(es)" in note


def test_inspect_of_a_log_with_only_zero_dops_says_n_a() -> None:
    shared = shared_dir()
    log = shared / "data" / "nmea" / "gpsd" / "jl-micro-jlt.log" if shared else None
    if log is None or not log.is_file():
        pytest.skip("shared gpsd logs absent")
    summary = summarize_nmea(log)
    for name in ("hdop", "vdop", "pdop"):
        assert f"{name} min / median / max: n/a" in summary
    assert "24 DOP value(s) in 8 fix(es) are the receiver's 'not available'" in summary


@pytest.mark.parametrize("name, dops", [("ublox-lea-m8f.log", 74), ("ublox-neo-m8t-s.log", 87)])
def test_inspect_of_a_ubx_log_leaves_out_its_99_99_dops(name: str, dops: int) -> None:
    """u-blox's 99.99 'not available' DOPs: left out of inspect's statistics (they printed
    99.990 / 99.990 / 99.990) and counted as convert counts them."""
    from fgins.io.ubx import summarize_ubx

    shared = shared_dir()
    log = shared / "data" / "ubx" / "gpsd" / name if shared else None
    if log is None or not log.is_file():
        pytest.skip("shared gpsd logs absent")
    summary = summarize_ubx(log)
    for dop in ("hdop", "vdop", "pdop"):
        assert f"  {dop}: n/a" in summary.splitlines(), summary
    assert f"{dops} DOP value(s)" in summary and "'not available'" in summary


# --- 3. inspect FOLDER -----------------------------------------------------------------------


def test_inspect_of_a_sim_folder_summarises_its_csvs(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "sim"
    folder.mkdir()
    t = np.arange(0.0, 2.0, 0.01)
    imu = np.column_stack([t, np.zeros((t.size, 5)), np.full(t.size, 9.81)])
    np.savetxt(folder / "imu.csv", imu, delimiter=",", comments="",
               header="time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z")  # fmt: skip
    gnss = np.column_stack([[0.0, 1.0], [48.0, 48.00001], [11.0, 11.0], [500.0, 500.0]])
    np.savetxt(folder / "gnss.csv", gnss, delimiter=",", comments="", header="time,lat,lon,alt")
    capsys.readouterr()
    assert main(["inspect", str(folder)]) == 0
    out = capsys.readouterr().out
    # not written by fgins sim (no config.toml with a [scenario]): not called one
    assert f"input folder {folder}" in out and "fgins sim" not in out
    assert "imu.csv: IMU, 200 samples" in out and "gnss.csv: GNSS, 2 fixes" in out
    assert "NMEA" not in out
    (folder / "config.toml").write_text('[scenario]\nname = "car-urban"\n')
    assert main(["inspect", str(folder)]) == 0
    assert f"fgins sim folder {folder}" in capsys.readouterr().out


def test_inspect_of_another_folder_says_it_is_no_log(tmp_path: Path, capsys) -> None:
    (tmp_path / "notes.txt").write_text("hello\n")
    message = cli_error(capsys, ["inspect", str(tmp_path)])
    assert message.startswith(f"{tmp_path}: is a folder, not a log: inspect takes one log file")
    assert "NMEA log" not in message and "Is a directory" not in message


# --- 4. demo:kitti given to convert and inspect ----------------------------------------------


def test_convert_demo_kitti_writes_its_fixes(tmp_path: Path, capsys) -> None:
    out = tmp_path / "kitti_fixes.csv"
    assert main(["convert", "demo:kitti", "-o", str(out)]) == 0
    assert "wrote 470 fixes" in capsys.readouterr().err
    table = np.genfromtxt(out, delimiter=",", names=True)
    kitti = fgins.load("demo:kitti")
    assert len(table) == len(kitti.gnss) == 470
    assert np.allclose(table["lat"], kitti.gnss.lla[:, 0], atol=1e-9)
    assert np.allclose(table["time"], kitti.gnss.t, atol=1e-6)


def test_inspect_demo_kitti_and_convert_imu_say_what_demo_kitti_is(capsys) -> None:
    message = cli_error(capsys, ["inspect", "demo:kitti"])
    assert message.startswith("demo:kitti is the built-in KITTI drive, not a log file")
    assert "fgins convert demo:kitti" in message and "no such file" not in message
    message = cli_error(capsys, ["convert", "demo:kitti", "--imu", "-o", "imu.csv"])
    assert "u-blox UBX" in message and "no such file" not in message
    assert "unknown built-in input" in cli_error(capsys, ["inspect", "demo:kit"])


# --- 5. load("") -----------------------------------------------------------------------------


def test_load_of_an_empty_path_is_an_input_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # a cwd whose content must not matter
    with pytest.raises(fgins.InputError, match=r"^empty input path"):
        fgins.load("")
    with pytest.raises(fgins.InputError, match=r"^empty input path \(input 2 of 2\)"):
        fgins.load("imu.csv", "")


# --- 6. plot(): a wrong-type argument is an InputError ----------------------------------------


@pytest.mark.parametrize("bad", ["abc", b"abc", {"a": 1}, [1, 2], 42])
def test_plot_wrong_type_trajectories_is_an_input_error(bad: object) -> None:
    with pytest.raises(fgins.InputError, match="must be a Trajectory"):
        fgins.plot(bad, None)  # type: ignore[arg-type]


@pytest.mark.parametrize("method", ["batch", "ekf", "ukf"])
def test_a_single_usable_fix_names_why_the_rest_are_not(method: str) -> None:
    """Nine fixes, eight of them at PDOP 23 (a real MiTAC log): the error names the gate
    (it was 'alignment needs at least 2 usable GNSS fixes')."""
    from fgins.datatypes import Dataset, GnssData, ImuData, Origin
    from fgins.geodesy import enu_to_lla

    origin = Origin(45.0, 10.0, 100.0)
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 12.0, 0.01)
    imu = ImuData(t=t, gyro=rng.normal(0, 1e-3, (len(t), 3)),
                  accel=np.array([0, 0, 9.806]) + rng.normal(0, 0.02, (len(t), 3)))  # fmt: skip
    fix_t = np.arange(1.0, 10.0)
    pdop = np.full(len(fix_t), 23.0)
    pdop[4] = 1.8
    gnss = GnssData(t=fix_t, lla=enu_to_lla(np.zeros((len(fix_t), 3)), origin),
                    std=np.tile([2.0, 2.0, 3.0], (len(fix_t), 1)), pdop=pdop)  # fmt: skip
    dataset = Dataset(imu=imu, gnss=gnss, origin=origin, name="mitac")
    with pytest.raises(fgins.InputError) as error:
        fgins.smooth(dataset, method, progress=False)
    message = str(error.value)
    assert "only 1 usable GNSS epoch(s) of 9 (a run needs 2)" in message, message
    assert "8 gated by PDOP > 5" in message, message


def test_inspect_of_a_text_with_dollar_signs_is_no_nmea_log(tmp_path: Path, capsys) -> None:
    """A README (shell prompts, prices: '$' but no sentence) was summarised as an NMEA log
    "not usable" at exit 0, while an empty file is an error: now both are errors. A log of
    corrupt sentences (a talker and type after the '$') stays a log to inspect."""
    text = tmp_path / "notes.txt"
    text.write_text("Run it:\n\n    $ fgins demo\n\nIt costs $0.\n" * 20)
    message = cli_error(capsys, ["inspect", str(text)])
    assert "not a log fgins reads: no NMEA sentence" in message, message
    corrupt = tmp_path / "corrupt.nmea"
    corrupt.write_text("$GPGGA,120000.00,4807.0,N,01131.0,E,1,08,0.9,545.4,M,46.9,M,,*00\n" * 5)
    assert main(["inspect", str(corrupt)]) == 0
    assert "checksum failures: 5" in capsys.readouterr().out
