"""`fgins fleet`: drives smoothed on Dask give exactly what `fgins smooth` gives on each alone."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from fgins.cli import main
from fgins.datatypes import FginsError
from fgins.fleet import FleetOptions, expand_drives, run_fleet
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import write_sim_dir

# Three different short drives: a car in town, a highway run, a UAV loop with a barometer.
DRIVE_SPECS = {
    "urban": ("car-urban", 11, 40.0),
    "motorway": ("highway", 12, 30.0),
    "loop": ("uav-loop-baro", 13, 30.0),
}


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("fleet_drives")
    folders = []
    for name, (scenario, seed, duration) in DRIVE_SPECS.items():
        folder = root / name
        write_sim_dir(SCENARIOS[scenario](seed=seed, duration_s=duration), folder)
        folders.append(folder)
    return folders


@pytest.fixture(scope="module")
def smoothed_alone(drives, tmp_path_factory) -> dict[str, np.ndarray]:
    """Each drive through `fgins smooth` on its own, in this process: the reference."""
    out = tmp_path_factory.mktemp("alone")
    reference = {}
    for folder in drives:
        target = out / f"{folder.name}.csv"
        assert main(["smooth", str(folder), "-o", str(target), "--no-progress"]) == 0
        reference[folder.name] = _read_csv(target)
    return reference


@pytest.fixture(scope="module")
def scheduler_address():
    """An existing cluster, as a user's own scheduler would be."""
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=40
    ) as cluster:
        yield cluster.scheduler_address


def _read_csv(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1)


def _assert_same_outputs(out_dir: Path, reference: dict[str, np.ndarray]) -> None:
    for name, expected in reference.items():
        got = _read_csv(out_dir / f"{name}.csv")
        assert got.shape == expected.shape
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9, equal_nan=True)


def _children() -> set[int]:
    """Child processes, except multiprocessing's resource tracker: one per interpreter, started
    on first use and ending with the interpreter itself."""
    pids = set()
    for child in psutil.Process().children(recursive=True):
        try:
            if "resource_tracker" not in " ".join(child.cmdline()):
                pids.add(child.pid)
        except psutil.NoSuchProcess:
            pass
    return pids


def test_local_cluster_outputs_equal_smooth_alone_and_leave_no_processes(
    drives, smoothed_alone, tmp_path, capsys
):
    out = tmp_path / "fleet"
    before = _children()
    argv = ["fleet", *map(str, drives), "-o", str(out), "--workers", "2", "--no-progress"]
    assert main(argv) == 0
    _assert_same_outputs(out, smoothed_alone)

    report = json.loads((out / "fleet.json").read_text())
    assert report["workers"] == 2 and report["drives_failed"] == 0
    assert [d["drive"] for d in report["drives"]] == [f.name for f in drives]
    for summary in report["drives"]:
        rows = len(smoothed_alone[summary["drive"]])
        assert summary["states"] == rows and summary["error"] is None
        assert summary["output"] == str(out / f"{summary['drive']}.csv")
        assert 0 < summary["h_rms_aided_m"] < 20  # metres, against the drive's own GNSS fixes
    table = capsys.readouterr().out
    assert all(f"| {f.name} | batch |" in table for f in drives)
    assert "speed-up" in table
    # The local cluster is gone: no worker or nanny process survives the command.
    deadline = time.monotonic() + 10
    while _children() - before and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _children() - before


def test_broken_drive_fails_alone_with_one_line_on_a_given_scheduler(
    drives, smoothed_alone, scheduler_address, tmp_path, capsys
):
    broken = tmp_path / "broken"
    broken.mkdir()
    shutil.copy(drives[0] / "imu.csv", broken / "imu.csv")  # no gnss.csv beside it
    out = tmp_path / "fleet"
    argv = ["fleet", *map(str, drives), str(broken), "-o", str(out)]
    assert main([*argv, "--scheduler", scheduler_address, "--no-progress"]) == 1

    _assert_same_outputs(out, smoothed_alone)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{f.name}.csv" for f in drives] + ["fleet.json"]
    )  # nothing at all for the broken drive, not even a temporary file
    report = json.loads((out / "fleet.json").read_text())
    assert report["scheduler"] == scheduler_address
    # What the drives were smoothed with, so its numbers can be tied to the run.
    assert report["options"]["method"] == "batch" and report["options"]["gnss_outage"] is None
    by_name = {d["drive"]: d for d in report["drives"]}
    assert set(by_name) == {f.name for f in drives} | {"broken"}
    error = by_name["broken"]["error"]
    assert "GNSS" in error and "\n" not in error
    assert by_name["broken"]["output"] is None
    assert f"FAILED: {error}" in capsys.readouterr().out


def test_list_file_and_geojson_format(drives, scheduler_address, tmp_path):
    listing = tmp_path / "drives.txt"
    # Relative to the list file's folder, with a comment and a blank line.
    relative = os.path.relpath(drives[1], tmp_path)
    listing.write_text(f"# the fleet\n{drives[0]}\n\n{relative}  # second\n")
    out = tmp_path / "geo"
    argv = ["fleet", f"@{listing}", "-o", str(out), "--format", "geojson"]
    assert main([*argv, "--scheduler", scheduler_address, "--no-progress"]) == 0
    for folder in drives[:2]:
        features = json.loads((out / f"{folder.name}.geojson").read_text())
        assert features["type"] == "FeatureCollection"
    report = json.loads((out / "fleet.json").read_text())
    assert [d["drive"] for d in report["drives"]] == [drives[0].name, drives[1].name]


def test_colliding_drive_names_get_their_folder(tmp_path):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "log.mcap").write_bytes(b"")
    names = [
        d.name for d in expand_drives([str(tmp_path / "a/log.mcap"), str(tmp_path / "b/log.mcap")])
    ]
    assert names == ["a_log", "b_log"]


def test_unusable_fleet_arguments_are_one_line_errors(tmp_path, capsys):
    assert main(["fleet", f"@{tmp_path / 'missing.txt'}", "-o", str(tmp_path / "o")]) == 2
    assert main(["fleet", str(tmp_path), "-o", str(tmp_path / "o"), "--workers", "0"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and all(line.startswith("fgins: error:") for line in errors)
    assert "missing.txt" in errors[0] and "--workers" in errors[1]
    drive = expand_drives([str(tmp_path)])
    with pytest.raises(FginsError, match="cannot connect to the Dask scheduler"):
        run_fleet(
            drive, FleetOptions(), tmp_path / "o", scheduler="tcp://127.0.0.1:9",
            connect_timeout_s=0.5, progress=False,
        )  # fmt: skip


@pytest.mark.slow
def test_ctrl_c_stops_the_fleet_and_its_workers(tmp_path):
    """SIGINT to the whole process group (what a terminal's Ctrl-C does) ends everything."""
    folders = []
    # A fraction of a second of smoothing each: with 8 drives a loaded machine once saw the
    # whole fleet end between the first output and the interrupt (exit 0), and once with 24
    # (two test suites beside it on two cores); the last ones are long enough (10 min
    # drives, several seconds each) that the fleet is still at work when the signal comes.
    for seed in range(16):
        folder = tmp_path / f"drive{seed}"
        minutes = 10 if seed >= 12 else 2
        write_sim_dir(SCENARIOS["highway"](seed=seed, duration_s=60 * minutes), folder)
        folders.append(str(folder))
    out = tmp_path / "out"
    command = [sys.executable, "-m", "fgins", "fleet", *folders, "-o", str(out), "--workers", "2"]
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
    )
    deadline = time.monotonic() + 30
    while not list(out.glob("*.csv")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(out.glob("*.csv")), "no drive finished within 30 s"
    group = os.getpgid(process.pid)
    os.killpg(group, signal.SIGINT)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 130, stderr.decode()[-2000:]
    assert stderr.decode().strip().splitlines()[-1] == "fgins: interrupted"
    assert "Traceback" not in stderr.decode()
    assert not (out / "fleet.json").exists()  # the fleet did not finish
    deadline = time.monotonic() + 10
    while [p for p in psutil.process_iter() if _in_group(p, group)]:
        assert time.monotonic() < deadline, "worker processes survived Ctrl-C"
        time.sleep(0.2)
    assert not list(out.glob(".*.part"))


def _in_group(process: psutil.Process, group: int) -> bool:
    """A live process of ``group`` (zombies are dead: an init that never reaps keeps them)."""
    try:
        return os.getpgid(process.pid) == group and process.status() != psutil.STATUS_ZOMBIE
    except (ProcessLookupError, PermissionError, psutil.NoSuchProcess):
        return False


def test_a_drive_whose_fit_is_doubtful_says_so_in_the_fleet(
    drives, scheduler_address, tmp_path, capsys
):
    """The fleet counted the input checks' warnings only: a drive whose solve found its fit
    doubtful (here its GNSS sigmas configured 3x too small: the scatter is said and the
    sigmas scaled) looked as clean as the rest. Every warning `fgins smooth` prints for a
    drive is now in its fleet.json entry, counted in the table and printed as one line under
    it, and the table has the fit's chi2/dof."""
    doubtful = tmp_path / "doubtful"
    shutil.copytree(drives[0], doubtful)
    config = (doubtful / "config.toml").read_text()
    (doubtful / "config.toml").write_text(
        config.replace("[gnss]\n", "[gnss]\nsigma_m = [1.1, 1.1, 1.8]\n", 1)
    )
    assert main(["smooth", str(doubtful), "-o", str(tmp_path / "alone.csv"), "--no-progress"]) == 0
    said = [
        line[len("warning: ") :]
        for line in capsys.readouterr().err.splitlines()
        if line.startswith("warning: ")
    ]
    assert any("scatter" in line for line in said), said

    out = tmp_path / "fleet"
    argv = ["fleet", str(drives[0]), str(doubtful), "-o", str(out), "--no-progress"]
    assert main([*argv, "--scheduler", scheduler_address]) == 0
    printed = capsys.readouterr().out
    report = {d["drive"]: d for d in json.loads((out / "fleet.json").read_text())["drives"]}
    entry = report["doubtful"]
    assert entry["warning_lines"] == said and entry["warnings"] == len(said)
    assert report[drives[0].name]["warning_lines"] == [] and report[drives[0].name]["warnings"] == 0
    assert 0.2 < entry["chi2_per_dof"] < 3.0 and 0.2 < report[drives[0].name]["chi2_per_dof"] < 3.0
    for line in said:
        assert f"warning: doubtful: {line}" in printed
    assert "| chi2/dof |" in printed


def test_a_rerun_that_does_not_finish_leaves_a_fleet_json_saying_so(tmp_path):
    """A re-run into an earlier fleet's folder rewrites its drive files one by one; an
    interrupted one had left new drive files beside the old fleet.json, which described them
    wrongly (method, scores: outside tester). Until the new summary replaces it, fleet.json
    says the folder is incomplete, listing every drive file, so the next run may rewrite it."""
    from fgins.fleet import FLEET_JSON, check_fleet_dir

    drive = tmp_path / "drive"
    write_sim_dir(SCENARIOS["highway"](seed=1, duration_s=20), drive)
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.csv").write_text("time\n")
    (out / FLEET_JSON).write_text(json.dumps({"method": "batch", "drives": [{"output": str(out / "old.csv")}]}))
    drives = expand_drives([str(drive)])
    # A scheduler nobody runs: the run stops after the folder was taken, as an interrupt would.
    with pytest.raises(Exception):  # noqa: B017 (the connection's own error, whatever it is)
        run_fleet(drives, FleetOptions(method="ekf"), out, scheduler="tcp://127.0.0.1:9", progress=False,
                  connect_timeout_s=1.0)  # fmt: skip
    said = json.loads((out / FLEET_JSON).read_text())
    assert said["status"] == "incomplete" and "did not finish" in said["note"]
    assert {Path(d["output"]).name for d in said["drives"]} == {"old.csv", "drive.csv"}
    assert check_fleet_dir(out, {"drive.csv"}) == {"old.csv", "drive.csv"}
