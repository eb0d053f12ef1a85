"""The public Python API (issue 11): only documented names, checked against the CLI.

The CLI is run in-process (``fgins.cli.main``) on the same inputs; what it writes and prints
is the independent side of each comparison.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.cli import main
from fgins.tests.cli_checks import cli_error

README = Path(__file__).resolve().parents[1] / "README.md"
CONTRACT = (
    "time,lat,lon,alt,east,north,up,vel_east,vel_north,vel_up,roll_deg,pitch_deg,heading_deg,"
    "std_east,std_north,std_up"
).split(",")


@pytest.fixture(scope="module")
def sim_drive(tmp_path_factory) -> Path:
    return fgins.simulate(
        "car-urban", tmp_path_factory.mktemp("api") / "drive", duration=60, seed=4
    )


@pytest.fixture(scope="module")
def kitti():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        return fgins.load("demo:kitti")


def test_api_reproduces_cli_smooth_on_kitti_bit_identical(tmp_path, kitti):
    """Acceptance: `fgins smooth demo:kitti --method batch --gnss-outage 60:90 -o x.csv`."""
    assert main(["smooth", "demo:kitti", "--method", "batch", "--gnss-outage", "60:90",
                 "-o", str(tmp_path / "cli.csv"), "--no-progress"]) == 0  # fmt: skip
    track = fgins.smooth(kitti, "batch", gnss_outage=[(60, 90)])
    track.write(tmp_path / "api.csv")
    assert (tmp_path / "api.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
    # The DataFrame carries the CSV's columns in order, at full precision.
    frame = track.to_dataframe()
    assert list(frame.columns[: len(CONTRACT)]) == CONTRACT
    written = np.loadtxt(tmp_path / "cli.csv", delimiter=",", skiprows=1)
    header = (tmp_path / "cli.csv").read_text().splitlines()[0].split(",")
    assert list(frame.columns) == header
    assert frame.shape == written.shape == (len(kitti.imu), len(header))
    np.testing.assert_allclose(frame["time"], written[:, 0], atol=5e-7, rtol=0)
    np.testing.assert_allclose(frame[["east", "north", "up"]], written[:, 4:7], atol=5e-5, rtol=0)
    np.testing.assert_allclose(frame[["lat", "lon"]], written[:, 1:3], atol=6e-10, rtol=0)  # 9 decimals


def test_smooth_summary_counts_add_up(sim_drive):
    dataset = fgins.load(sim_drive)
    track = fgins.smooth(dataset, "ekf", gnss_outage=[(20, 35), (45, 50)])
    summary = track.summary()
    json.dumps(summary)  # plain data only
    relative = dataset.gnss.t - dataset.gnss.t[0]
    withheld = int(
        (((relative >= 20) & (relative < 35)) | ((relative >= 45) & (relative < 50))).sum()
    )
    assert summary["gnss_withheld"] == withheld == 20
    assert summary["gnss_outage"] == [(20.0, 35.0), (45.0, 50.0)]
    assert summary["method"] == "ekf" and summary["states"] == len(dataset.imu) == len(track)
    assert summary["imu_samples"] == len(dataset.imu) and summary["gnss_epochs"] == len(
        dataset.gnss
    )
    assert math.isclose(summary["duration_s"], dataset.imu.t[-1] - dataset.imu.t[0])
    assert "gnss_gating" in summary and summary["wall_s"] > 0


def test_an_outage_window_in_the_logs_own_times_is_named_relative_to_t0(tmp_path):
    """Windows count from the first GNSS epoch; given as the log's POSIX times, the warning
    printed both bounds as 1.71456e+09, and not what was meant."""
    t0 = 1_714_564_800.0
    dataset = fgins.load(fgins.simulate("car-urban", tmp_path / "posix", duration=60, start_time_s=t0))
    with pytest.warns(fgins.FginsWarning, match=r"window 1714564820:1714564835 s withholds no GNSS epoch.*"
                      r"as the log's own times, it is 20\.0:35\.0"):  # fmt: skip
        fgins.smooth(dataset, "ekf", gnss_outage=[(t0 + 20, t0 + 35)])


def test_an_outage_window_that_withholds_nothing_is_said(sim_drive):
    """A window past the drive (a typo, another drive's windows) makes no outage test."""
    dataset = fgins.load(sim_drive)
    with pytest.warns(fgins.FginsWarning, match=r"window 500:600 s withholds no GNSS epoch"):
        track = fgins.smooth(dataset, "ekf", gnss_outage=[(20, 35), (500, 600)])
    warned = [w for w in track.summary().get("fit_warnings", []) if "withholds no" in w]
    assert len(warned) == 1 and "20:35" not in warned[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", fgins.FginsWarning)
        fgins.smooth(dataset, "ekf", gnss_outage=[(20, 35)])


def test_api_bench_reproduces_cli_table(sim_drive, tmp_path, capsys):
    capsys.readouterr()
    assert main(["bench", str(sim_drive), "--methods", "ekf,ekf-rts", "--gnss-outage", "20:35",
                 "-o", str(tmp_path / "bench"), "--no-progress"]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    table = fgins.bench(fgins.load(sim_drive), methods=["ekf", "ekf-rts"], outages=[(20, 35)])
    assert list(table["method"]) == ["ekf", "ekf-rts"]
    assert table.attrs["reference"] == "truth"  # the simulator folder's truth.csv
    stored = json.loads((tmp_path / "bench" / "outages.json").read_text())[table["case"][0]]
    for row in table.itertuples(index=False):
        metrics = stored["methods"][row.method]
        for column, key in (
            ("h_rms_outage_m", "h_rms_outage"), ("h_max_outage_m", "h_max_outage"),
            ("h_end_outage_m", "h_end_outage_mean"), ("h_rms_aided_m", "h_rms_aided"),
            ("rpe_100m_m", "rpe_100m"), ("within_3sigma_outage", "within_3sigma_outage"),
        ):  # fmt: skip
            assert getattr(row, column) == metrics[key], (row.method, column)
        # The printed row, all but the timing columns.
        line = next(li for li in printed.splitlines() if f"| {row.method} |" in li)
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2:7] == [f"{getattr(row, c):.2f}" for c in (
            "h_rms_outage_m", "h_max_outage_m", "h_end_outage_m", "h_rms_aided_m", "rpe_100m_m")]  # fmt: skip
        assert cells[-1] == f"{row.rms_ratio:.2f}"
    assert table["rms_ratio"][0] == 1.0  # ekf against itself
    assert "RPE/100 m" in printed


def test_errors_are_fgins_errors_with_the_cli_message(tmp_path, capsys, sim_drive):
    missing = str(tmp_path / "missing.csv")
    with pytest.raises(fgins.InputError) as caught:
        fgins.load(missing)
    assert str(caught.value) == cli_error(
        capsys, ["smooth", missing, "-o", str(tmp_path / "o.csv")]
    )

    bad = tmp_path / "bad.toml"
    bad.write_text("[imu]\nno_such_key = 1\n")
    with pytest.raises(fgins.ConfigError) as caught:
        fgins.load(sim_drive, config=bad)
    assert isinstance(caught.value, fgins.FginsError)
    assert str(caught.value) == cli_error(
        capsys, ["smooth", str(sim_drive), "--config", str(bad), "-o", str(tmp_path / "o.csv")]
    )

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    track = fgins.smooth(fgins.load(sim_drive), "ekf")
    with pytest.raises(fgins.OutputError) as caught:
        track.write(blocker / "out.csv")
    assert str(caught.value) == cli_error(
        capsys, ["smooth", str(sim_drive), "-o", str(blocker / "out.csv")]
    )
    assert (
        str(caught.value)
        == f"{blocker / 'out.csv'}: cannot write under {blocker}: it is a file, not a folder"
    )

    with pytest.raises(fgins.ConfigError, match="unknown method 'kalman'"):
        fgins.smooth(fgins.load(sim_drive), "kalman")
    with pytest.raises(fgins.ConfigError, match="start < end"):
        fgins.smooth(fgins.load(sim_drive), "ekf", gnss_outage=[(30, 20)])
    with pytest.raises(fgins.ConfigError, match="needs method isam2"):
        fgins.smooth(fgins.load(sim_drive), "ekf", online=True)
    with pytest.raises(fgins.ConfigError) as caught:
        fgins.bench(fgins.load(sim_drive), methods=["ekf", "magic"])
    assert str(caught.value) == cli_error(
        capsys, ["bench", str(sim_drive), "--methods", "ekf,magic"]
    )


def test_reader_findings_arrive_as_fgins_warnings(kitti):
    with pytest.warns(fgins.FginsWarning) as record:
        dataset = fgins.load("demo:kitti")
    messages = [str(w.message) for w in record if issubclass(w.category, fgins.FginsWarning)]
    assert messages == dataset.warnings and len(messages) == 2
    assert "IMU gap" in messages[0] and "interpolated" in messages[1]
    # A clean simulated drive warns nothing.
    assert kitti.warnings == dataset.warnings


def test_clean_input_gives_no_warning(sim_drive):
    with warnings.catch_warnings():
        warnings.simplefilter("error", fgins.FginsWarning)
        assert fgins.load(sim_drive).warnings == []


def test_every_output_format_and_plots(sim_drive, tmp_path):
    import matplotlib
    from matplotlib.figure import Figure

    backend = matplotlib.get_backend()
    dataset = fgins.load(sim_drive)
    batch = fgins.smooth(dataset, "batch", gnss_outage=[(20, 35)])
    ekf = fgins.smooth(dataset, "ekf", gnss_outage=[(20, 35)])
    for suffix in (".csv", ".geojson", ".kml", ".mcap", ".tum"):
        batch.write(tmp_path / f"track{suffix}")
        assert (tmp_path / f"track{suffix}").stat().st_size > 0
    assert not list(tmp_path.glob("*.part"))
    fig = fgins.plot([batch, ekf], dataset, path=tmp_path / "both.png")
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    labels = [line.get_label() for line in fig.axes[1].get_lines()]
    assert "batch" in labels and "ekf" in labels
    assert (tmp_path / "both.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The outage windows of the run are shaded without being given again.
    assert len(fig.axes[1].patches) == 1
    assert matplotlib.get_backend() == backend  # no global backend switch


def test_import_is_lazy_and_help_shows_units_and_an_example():
    import subprocess
    import sys

    code = (
        "import sys, fgins; import pydoc; text = pydoc.plain(pydoc.render_doc(fgins.smooth)); "
        "print('gtsam' in sys.modules, 'matplotlib' in sys.modules); print(text)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    first, text = out.stdout.split("\n", 1)
    assert first == "False False"
    words = " ".join(text.split()).lower()
    assert "example" in words and "seconds after t0" in words
    assert "(m)" in text and "m/s" in text


def _readme_python_example() -> str:
    text = README.read_text()
    section = text.split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "README: no python block under '## Python API'"
    return blocks[0]


def test_readme_python_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        exec(compile(_readme_python_example(), "README.md", "exec"), namespace)
    assert (tmp_path / "drive" / "truth.csv").exists()
    assert (tmp_path / "track.csv").exists() and (tmp_path / "track.tum").exists()


def test_api_docstring_examples_run(monkeypatch, tmp_path):
    import doctest

    import fgins.api

    monkeypatch.chdir(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        result = doctest.testmod(fgins.api, optionflags=doctest.ELLIPSIS)
    assert result.attempted >= 5 and result.failed == 0
