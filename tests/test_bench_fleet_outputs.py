"""Outside tester h4: what `fgins fleet` and `fgins bench` report and leave in their folders,
and `fgins sim` under a file.

B1: the fleet's aided RMS is over the fixes the run used, not over gated or faulty ones.
B2: a bench window whose fixes are all gated already is said and left out of the scores.
B3: a method that cannot run is refused up front (ekf18 on an ordinary IMU), or, failing
    during the run, a row and a warning, never silently absent (nor `nan` ratios).
B4: `fgins sim -o FILE/sub` is the output check's one line and exit 2.
B5: the README's shortest simulation is the code's.
B7: re-running into a folder of an earlier bench/fleet leaves none of its files behind.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins import cli
from fgins.datatypes import FginsError

PDOP_MAX = 5.0  # the simulated folders' [gnss] pdop_max
EARTH_A = 6378137.0
EARTH_E2 = 6.69437999014e-3


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    """car-urban 120 s: PDOP > 5 at 60-94 s (35 fixes gated); car-urban 60 s: 4 of its fixes
    left out as faults by the batch smoother."""
    root = tmp_path_factory.mktemp("h4")
    folders = {"pdop": root / "pdop", "faults": root / "faults"}
    assert cli.main(["sim", "car-urban", "-o", str(folders["pdop"]), "--duration", "120"]) == 0
    assert cli.main(["sim", "car-urban", "-o", str(folders["faults"]), "--duration", "60"]) == 0
    return folders


def _horizontal_errors(track_csv: Path, gnss_csv: Path) -> tuple[np.ndarray, pd.DataFrame]:
    """Horizontal distance (m) of the written track at each fix's time from the fix, by
    hand: the simulated fixes fall on IMU samples, so the track row of the same time; the
    distance from lat/lon on the ellipsoid's local radii (metres apart: exact enough)."""
    track = pd.read_csv(track_csv)
    fixes = pd.read_csv(gnss_csv)
    rows = np.searchsorted(track["time"].to_numpy(), fixes["time"].to_numpy())
    assert np.allclose(track["time"].to_numpy()[rows], fixes["time"].to_numpy(), atol=1e-6)
    lat = np.radians(fixes["lat"].to_numpy())
    sin2 = np.sin(lat) ** 2
    north_radius = EARTH_A * (1 - EARTH_E2) / (1 - EARTH_E2 * sin2) ** 1.5
    east_radius = EARTH_A / np.sqrt(1 - EARTH_E2 * sin2) * np.cos(lat)
    d_north = np.radians(track["lat"].to_numpy()[rows] - fixes["lat"].to_numpy()) * north_radius
    d_east = np.radians(track["lon"].to_numpy()[rows] - fixes["lon"].to_numpy()) * east_radius
    return np.hypot(d_east, d_north), fixes


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


# ---------------------------------------------------------------------------------------------
# B1 and B7 (fleet)


def test_fleet_aided_rms_is_over_the_fixes_used_and_a_rerun_leaves_no_old_drive(
    drives, tmp_path, capsys
):
    out = tmp_path / "fleet"
    argv = ["fleet", str(drives["pdop"]), str(drives["faults"]), "-o", str(out), "--workers", "1",
            "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    report = {d["drive"]: d for d in json.loads((out / "fleet.json").read_text())["drives"]}
    capsys.readouterr()

    # pdop: the fixes used are those with PDOP <= 5 (none left out as a fault).
    errors, fixes = _horizontal_errors(out / "pdop.csv", drives["pdop"] / "gnss.csv")
    used = fixes["pdop"].to_numpy() <= PDOP_MAX
    assert used.sum() == 85  # 35 gated
    track = fgins.smooth(fgins.load(drives["pdop"]), "batch")
    assert not track.info.get("gnss_excluded_times")
    assert report["pdop"]["h_rms_aided_m"] == pytest.approx(_rms(errors[used]), rel=1e-3)
    assert _rms(errors) > 1.5 * _rms(errors[used])  # what it was: over every fix

    # faults: every fix passes PDOP; the batch smoother leaves 4 out as faults.
    errors, fixes = _horizontal_errors(out / "faults.csv", drives["faults"] / "gnss.csv")
    assert np.all(fixes["pdop"].to_numpy() <= PDOP_MAX)
    excluded = fgins.smooth(fgins.load(drives["faults"]), "batch").info["gnss_excluded_times"]
    assert len(excluded) == 4
    used = ~np.isin(fixes["time"].to_numpy(), excluded)
    assert used.sum() == 56
    assert report["faults"]["h_rms_aided_m"] == pytest.approx(_rms(errors[used]), rel=1e-3)
    assert _rms(errors) > 1.2 * _rms(errors[used])

    # B7: the same folder, one drive: the other drive's file does not stay beside it.
    assert cli.main(["fleet", str(drives["faults"]), "-o", str(out), "--workers", "1",
                     "--no-progress"]) == 0  # fmt: skip
    assert sorted(p.name for p in out.iterdir()) == ["faults.csv", "fleet.json"]
    # A file that is not the fleet's: refused before any work, nothing touched.
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    assert cli.main(["fleet", str(drives["pdop"]), "-o", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.txt" in err[0] and "fgins fleet" in err[0], err
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before


def test_fleet_refuses_a_folder_of_other_data(drives, tmp_path, capsys):
    assert cli.main(["fleet", str(drives["pdop"]), "-o", str(drives["faults"]),
                     "--workers", "1"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not written by fgins fleet" in err[0], err
    assert not (drives["faults"] / "fleet.json").exists()


# ---------------------------------------------------------------------------------------------
# B2 (a window over gated fixes)


def test_a_window_over_gated_fixes_is_said_and_left_out_of_the_scores(drives, tmp_path, capsys):
    dataset = fgins.load(drives["pdop"])
    with pytest.warns(fgins.FginsWarning, match=r"window 62:92 s withholds no usable GNSS fix"):
        table = fgins.bench(dataset, ["ekf"], outages=[(20.0, 40.0), (62.0, 92.0)])
    assert table.attrs["outages"] == [(20.0, 40.0)]
    assert table.attrs["outages_left_out"] == [(62.0, 92.0)]
    alone = fgins.bench(dataset, ["ekf"], outages=[(20.0, 40.0)])
    for column in ("h_rms_outage_m", "h_max_outage_m", "h_end_outage_m", "h_rms_aided_m"):
        assert table.loc[0, column] == alone.loc[0, column], column

    # The CLI: a warning naming the window and why; table and JSON agree.
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf", "--gnss-outage", "20:40",
                     "--gnss-outage", "62:92", "-o", str(out), "--no-progress"]) == 0  # fmt: skip
    captured = capsys.readouterr()
    warned = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert len(warned) == 1 and "62:92" in warned[0] and "PDOP > 5" in warned[0], warned
    assert "left out (no usable fix withheld): 62:92" in captured.out
    stored = json.loads((out / "outages.json").read_text())["pdop"]
    assert stored["windows"] == [[20.0, 40.0]]
    assert [w["window"] for w in stored["windows_left_out"]] == [[62.0, 92.0]]
    assert "PDOP > 5" in stored["windows_left_out"][0]["why"]
    assert stored["methods"]["ekf"]["h_rms_outage"] == pytest.approx(alone.loc[0, "h_rms_outage_m"])
    assert "window 62:92 s left out of the scores" in (out / "outages.md").read_text()

    # Only such windows: nothing to score, one line, exit 2 (the default protocol's 60:90
    # on this drive lies inside the PDOP stretch).
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf", "-o",
                     str(tmp_path / "none"), "--no-progress"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "60:90" in err[0] and "no usable GNSS fix" in err[0], err


# ---------------------------------------------------------------------------------------------
# B3 (a method that cannot run)


def test_ekf18_on_an_ordinary_imu_is_refused_before_any_work(drives, tmp_path, capsys):
    out = tmp_path / "bench"
    for extra in ([], ["--baseline", "ekf18"]):
        code = cli.main(["bench", str(drives["pdop"]), "--methods", "batch,ekf18", *extra,
                         "--gnss-outage", "20:40", "-o", str(out), "--no-progress"])  # fmt: skip
        captured = capsys.readouterr()
        assert code == 2
        err = captured.err.strip().splitlines()
        assert len(err) == 1 and "ekf18" in err[0] and "accelerometer-array" in err[0], err
        assert "|" not in captured.out  # no table: no method ran
        assert not out.exists()


def test_a_method_failing_during_the_run_is_a_row_and_a_warning(
    drives, tmp_path, capsys, monkeypatch
):
    import fgins.bench.outages as bench_outages

    real = bench_outages.run_method

    def failing(dataset, config, method, **kwargs):
        if method == "ekf-rts":
            raise FginsError("ekf-rts: the smoother pass broke | here")
        return real(dataset, config, method, **kwargs)

    monkeypatch.setattr(bench_outages, "run_method", failing)
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf,ekf-rts", "--baseline",
                     "ekf-rts", "--gnss-outage", "20:40", "-o", str(out),
                     "--no-progress"]) == 0  # fmt: skip
    captured = capsys.readouterr()
    warned = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert any("ekf-rts produced no result" in w and "smoother pass broke" in w for w in warned)
    assert any("baseline ekf-rts produced no result" in w for w in warned), warned
    stored = json.loads((out / "outages.json").read_text())["pdop"]["methods"]
    assert stored["ekf-rts"] == {"error": "ekf-rts: the smoother pass broke | here"}
    assert "h_rms_outage" in stored["ekf"]
    for text in (captured.out, (out / "outages.md").read_text()):
        rows = [line for line in text.splitlines() if line.startswith("| pdop |")]
        assert len(rows) == 2
        assert all(row.count("|") - row.count("\\|") == 12 for row in rows), rows
        failed = next(row for row in rows if "| ekf-rts |" in row)
        assert "failed: ekf-rts: the smoother pass broke" in failed
        assert "nan" not in text
        assert rows[0].endswith("| n/a |")  # ekf's ratio: no baseline result


def test_an_internal_error_in_one_method_leaves_the_others_rows(drives, tmp_path, capsys, monkeypatch):
    """A method that ends in an internal error (not an fgins error) is a failed row; the
    benchmark ended at it, no table, no folder, the other methods' results lost (outside
    tester: an SVD error of the EKF on a flight aligned to NaN)."""
    import fgins.bench.outages as bench_outages

    real = bench_outages.run_method

    def broken(dataset, config, method, **kwargs):
        if method == "ekf":
            raise np.linalg.LinAlgError("SVD did not converge")
        return real(dataset, config, method, **kwargs)

    monkeypatch.setattr(bench_outages, "run_method", broken)
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf,ekf-rts", "--gnss-outage",
                     "20:40", "-o", str(out), "--no-progress"]) == 0  # fmt: skip
    captured = capsys.readouterr()
    assert "internal error" not in captured.err.split("warning:")[0]
    stored = json.loads((out / "outages.json").read_text())["pdop"]["methods"]
    assert stored["ekf"]["error"].startswith("internal error: LinAlgError: SVD did not converge")
    assert np.isfinite(stored["ekf-rts"]["h_rms_outage"])
    assert "| pdop | ekf | failed: internal error: LinAlgError" in captured.out


def test_what_a_method_says_of_its_result_is_in_the_benchmark(drives, tmp_path, capsys, monkeypatch):
    """A method's own warnings (here one put on EKF+RTS's result) are the benchmark's
    warnings and in outages.json: a row at "100 % in 3 sigma" whose smooth run said "not to
    be trusted" was shown clean (outside tester)."""
    import fgins.bench.outages as bench_outages

    real = bench_outages.run_method
    note = "EKF+RTS: the smoother turns the filter's attitude by up to 10 deg: not to be trusted"

    def noted(dataset, config, method, **kwargs):
        trajectory = real(dataset, config, method, **kwargs)
        if method == "ekf-rts":
            trajectory.info.setdefault("fit_warnings", []).append(note)
        return trajectory

    monkeypatch.setattr(bench_outages, "run_method", noted)
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf,ekf-rts", "--gnss-outage",
                     "20:40", "-o", str(out), "--no-progress"]) == 0  # fmt: skip
    assert f"warning: ekf-rts: {note}" in capsys.readouterr().err.splitlines()
    stored = json.loads((out / "outages.json").read_text())["pdop"]["methods"]
    assert stored["ekf-rts"]["warnings"] == [note]
    assert note not in stored["ekf"]["warnings"]
    table = fgins.bench(fgins.load(drives["pdop"]), ["ekf", "ekf-rts"], [(20.0, 40.0)])
    assert f"bench: ekf-rts: {note}" in table.attrs["warnings"]


def test_windows_and_a_protocol_number_together_are_refused(drives, tmp_path, capsys):
    """--gnss-outage 60:90 beside --outage-duration 20 ran the window and dropped the
    duration without a word: two answers to one question are an error, before any solve."""
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf", "--gnss-outage", "20:40",
                     "--outage-duration", "20", "-o", str(out), "--no-progress"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "given together with outage_duration" in err and "give one or the other" in err
    assert not out.exists()


def test_fleet_says_its_warnings_once_and_a_drive_given_twice(drives, tmp_path, capfd):
    """The solve's warnings (an outage window beyond a drive) came on stderr as raw Python
    warnings with fleet's source line, beside the summary's own line; a drive given twice
    ran once without a word."""
    out = tmp_path / "fleet"
    code = cli.main(["fleet", str(drives["faults"]), str(drives["faults"]) + "/", "-o", str(out),
                     "--workers", "1", "--method", "ekf", "--gnss-outage", "100:130",
                     "--no-progress"])  # fmt: skip
    assert code == 0
    captured = capfd.readouterr()
    assert "FginsWarning" not in captured.err and "fleet.py" not in captured.err
    assert "1 drive(s) given more than once run once" in captured.err
    said = [line for line in captured.out.splitlines() if "withholds no GNSS epoch" in line]
    assert len(said) == 1 and said[0].startswith("warning: faults:")
    summary = json.loads((out / "fleet.json").read_text())
    drives_run = summary["drives"] if isinstance(summary, dict) else summary
    assert len(drives_run) == 1


def test_the_3_sigma_share_is_the_2d_ellipse_and_each_window_is_scored(drives, tmp_path, capsys):
    """'in 3σ' counted |e| <= 3 sqrt(sE^2 + sN^2): 4.24 sigmas of an isotropic error, so
    sigmas 2x too small still scored 89 %; and only pooled windows were reported, a window at
    0 % inside showing as 90 % (outside tester). Now the 2-D 3-sigma ellipse (99.73 %) and
    each window's own numbers in the JSON and a table."""
    from fgins.bench.metrics import Errors

    rng = np.random.default_rng(0)
    error = rng.normal(0.0, 1.0, (20000, 2))
    rows = np.ones(len(error), dtype=bool)

    def share(reported: float) -> float:
        std = np.full_like(error, reported)
        errors = Errors(t=np.arange(len(error)), horizontal=np.linalg.norm(error, axis=1),
                        vertical=np.zeros(len(error)), inside=rows,
                        horizontal_std=np.linalg.norm(std, axis=1), east_north=error,
                        east_north_std=std)  # fmt: skip
        return errors.inside_3_sigma(rows)

    assert 0.995 < share(1.0) < 0.999  # 99.73 %
    assert share(0.5) < 0.80  # 77 %: the norm test gave 89 %
    out = tmp_path / "bench"
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf,ekf-rts", "--gnss-outage",
                     "10:30", "--gnss-outage", "100:115", "-o", str(out), "--no-progress"]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    stored = json.loads((out / "outages.json").read_text())["pdop"]["methods"]
    for method in ("ekf", "ekf-rts"):
        windows = stored[method]["windows"]
        assert [w["window"] for w in windows] == [[10.0, 30.0], [100.0, 115.0]]
        assert all(w["h_rms"] <= w["h_max"] and 0.0 <= w["within_3sigma"] <= 1.0 for w in windows)
        assert all(np.isfinite(w["nees_h"]) for w in windows)
    assert "| 10:30 |" in printed and "| 100:115 |" in printed
    assert "| 10:30 |" in (out / "outages.md").read_text()
    # The first window's numbers by hand, from smooth's output and the simulator's truth.
    dataset = fgins.load(drives["pdop"])
    track = fgins.smooth(dataset, "ekf", gnss_outage=[(10.0, 30.0), (100.0, 115.0)])
    truth = pd.read_csv(drives["pdop"] / "truth.csv")
    t = track.t - dataset.t0
    inside = (t >= 10.0) & (t < 30.0)
    rows = np.searchsorted(truth["time"].to_numpy(), t[inside] - 1e-9)
    difference = track.position[inside, :2] - truth[["east", "north"]].to_numpy()[rows]
    z2 = np.sum((difference / track.position_std[inside, :2]) ** 2, axis=1)
    first = stored["ekf"]["windows"][0]
    # (truth.csv holds positions to 0.1 mm)
    assert first["h_rms"] == pytest.approx(np.sqrt(np.mean(np.sum(difference**2, axis=1))), abs=2e-4)
    assert first["within_3sigma"] == pytest.approx(np.mean(z2 <= 11.829), abs=1e-9)
    assert first["nees_h"] == pytest.approx(np.mean(z2) / 2, rel=1e-3)


# ---------------------------------------------------------------------------------------------
# B4 (sim under a file), B5 (README's shortest simulation)


def test_sim_under_a_file_is_the_output_checks_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    smooth_line = None
    assert cli.main(["smooth", str(tmp_path / "d"), "-o", str(afile / "sub.csv")]) == 2
    smooth_line = capsys.readouterr().err.strip()
    assert smooth_line.endswith(f"cannot write under {afile}: it is a file, not a folder")
    for target in (afile / "sub", afile / "sub" / "deeper"):
        code = cli.main(["sim", "car-urban", "--duration", "10", "-o", str(target)])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2
        assert len(err) == 1 and err[0].startswith(f"fgins: error: {target}"), err
        assert err[0].endswith(f"cannot write under {afile}: it is a file, not a folder"), err
    assert afile.read_text() == "x" and not list(tmp_path.glob(".*"))


def test_the_readme_states_the_simulators_shortest_duration(tmp_path, capsys):
    from fgins.sim.scenarios import MIN_DURATION_S

    readme = (Path(fgins.__file__).parent / "README.md").read_text()
    stated = re.search(r"durations run from (\S+) s( \([^)]*\))? to 24 h", readme)
    assert stated, "the README's sentence on durations"
    assert float(stated.group(1)) == MIN_DURATION_S and stated.group(2) is None
    for scenario in ("car-urban", "highway", "aircraft-ekf"):
        below = f"{MIN_DURATION_S - 1:g}"
        assert cli.main(["sim", scenario, "--duration", below, "-o", str(tmp_path / scenario)]) == 2
        assert f"outside [{MIN_DURATION_S:g}" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# B7 (bench)


def test_a_rerun_of_bench_leaves_no_earlier_case_and_refuses_other_files(
    drives, tmp_path, capsys
):
    out = tmp_path / "bench"
    for name in ("pdop", "faults"):
        assert cli.main(["bench", str(drives[name]), "--methods", "ekf", "--gnss-outage",
                         "20:40", "-o", str(out), "--no-progress"]) == 0  # fmt: skip
    assert sorted(p.name for p in out.iterdir()) == ["faults.png", "outages.json", "outages.md"]
    assert list(json.loads((out / "outages.json").read_text())) == ["faults"]
    capsys.readouterr()
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf", "--gnss-outage", "20:40",
                     "-o", str(out)]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.txt" in err[0] and "fgins bench" in err[0], err
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    # Into a folder of other data (the input itself): refused, nothing written there.
    assert cli.main(["bench", str(drives["pdop"]), "--methods", "ekf", "--gnss-outage", "20:40",
                     "-o", str(drives["faults"])]) == 2  # fmt: skip
    assert "not written by fgins bench" in capsys.readouterr().err
    assert not (drives["faults"] / "outages.json").exists()
