"""Readers against outside testers' input cases (h3 B1, B2, B3, B6, B8d; h1 B8).

MCAP recordings are written by the ``mcap`` + ``mcap_ros2`` writers (tests/ros2_mcap_writer),
CSV files by pandas: neither shares code with fgins's readers.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("rosbags", reason="test extra: pip install rosbags")
pytest.importorskip("mcap_ros2", reason="test extra: pip install mcap-ros2-support")

import fgins
from fgins.datatypes import InputError
from fgins.io.csv_pair import _parse_table, _parse_table_python, _read_columns
from fgins.io.inputs import load_dataset
from fgins.io.mcap import read_mcap
from fgins.outages import outage_mask
from fgins.tests.mcap_fixtures import make_drive
from fgins.tests.ros2_mcap_writer import drive_messages, write_ros2_mcap

# --------------------------------------------------------------------------------------------
# MCAP
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def events():
    return drive_messages(make_drive(duration_s=20.0))


@pytest.fixture(scope="module")
def mcap_dir(events, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("mcap")
    write_ros2_mcap(folder / "good.mcap", events)
    drive = make_drive(duration_s=20.0)
    # The same drive as CSVs (pandas), to give beside the MCAP.
    t = drive.imu_ns / 1e9
    pd.DataFrame({"time": t, **{f"gyro_{a}": drive.gyro[:, i] for i, a in enumerate("xyz")},
                  **{f"accel_{a}": drive.accel[:, i] for i, a in enumerate("xyz")}}
                 ).to_csv(folder / "imu.csv", index=False)  # fmt: skip
    pd.DataFrame({"time": drive.gnss_ns / 1e9, "lat": drive.lla[:, 0], "lon": drive.lla[:, 1],
                  "alt": drive.lla[:, 2]}).to_csv(folder / "gnss.csv", index=False)  # fmt: skip
    return folder


def _same_data(a, b) -> None:
    np.testing.assert_array_equal(a.imu.t, b.imu.t)
    np.testing.assert_array_equal(a.imu.gyro, b.imu.gyro)
    np.testing.assert_array_equal(a.imu.accel, b.imu.accel)
    np.testing.assert_array_equal(a.gnss.t, b.gnss.t)
    np.testing.assert_array_equal(a.gnss.lla, b.gnss.lla)
    np.testing.assert_array_equal(a.gnss.std, b.gnss.std)


@pytest.mark.parametrize("name", ["drive.bin", "drive", "drive.csv"])
def test_an_mcap_under_another_name_is_read_as_mcap(mcap_dir: Path, tmp_path: Path, name) -> None:
    """h3 B1: an MCAP named drive.bin was "binary content that is none of the formats"."""
    renamed = tmp_path / name
    shutil.copy(mcap_dir / "good.mcap", renamed)
    expected = load_dataset([str(mcap_dir / "good.mcap")], progress=False)
    _same_data(load_dataset([str(renamed)], progress=False), expected)


@pytest.mark.parametrize(
    "others, says",
    [
        (["imu.csv"], "read alone, not with {d}/imu.csv; to use that IMU with the recording's "
                      "fixes, write them out with `fgins convert"),
        (["gnss.csv"], "read alone, not with {d}/gnss.csv: fgins takes an MCAP's IMU only"),
        (["good.mcap"], "given twice"),
        (["copy.bin"], "2 MCAP recordings given"),
        (["imu.csv", "gnss.csv"], "give it alone, not with {d}/imu.csv, {d}/gnss.csv"),
    ],
)  # fmt: skip
def test_an_mcap_with_another_input_is_refused_saying_why(mcap_dir: Path, others, says) -> None:
    """h3 B1: with any other input the MCAP was called none of the formats fgins reads."""
    shutil.copy(mcap_dir / "good.mcap", mcap_dir / "copy.bin")
    inputs = [str(mcap_dir / "good.mcap"), *(str(mcap_dir / o) for o in others)]
    with pytest.raises(InputError) as caught:
        load_dataset(inputs, progress=False)
    message = str(caught.value)
    assert "none of the formats" not in message
    assert "\n" not in message
    assert says.format(d=mcap_dir) in message


def test_an_mcap_read_as_a_csv_is_named_an_mcap(mcap_dir: Path) -> None:
    """What a CSV reader says of an MCAP handed to it is true (not "none of the formats")."""
    from fgins.io.csv_pair import csv_kind

    with pytest.raises(InputError, match="an MCAP recording"):
        csv_kind(mcap_dir / "good.mcap")


@pytest.mark.parametrize("order", ["swap-halves", "shuffled", "reversed"])
def test_messages_stored_out_of_log_time_order_read_as_the_sorted_file(
    events, mcap_dir: Path, tmp_path: Path, order
) -> None:
    """h3 B2: a valid MCAP whose messages are stored out of log-time order was refused:
    "IMU time goes backwards ... mixes clocks or files". Read in log-time order, it is the
    same drive as the file stored in order."""
    if order == "swap-halves":
        half = len(events) // 2
        stored = events[half:] + events[:half]
    elif order == "shuffled":
        stored = [events[k] for k in np.random.default_rng(3).permutation(len(events))]
    else:
        stored = events[::-1]
    path = write_ros2_mcap(tmp_path / f"{order}.mcap", stored)
    # The mcap library itself reads the file in log-time order when asked.
    from mcap.reader import make_reader

    with open(path, "rb") as stream:
        times = [m.log_time for _, _, m in make_reader(stream).iter_messages(log_time_order=True)]
    assert times == sorted(times)
    result = read_mcap(path, progress=False)
    reference = read_mcap(mcap_dir / "good.mcap", progress=False)
    _same_data(result.dataset, reference.dataset)
    assert result.warnings == reference.warnings
    assert any("read in log-time order" in line for line in result.report)
    _same_data(load_dataset([str(path)], progress=False),
               load_dataset([str(mcap_dir / "good.mcap")], progress=False))  # fmt: skip


def test_a_cut_shuffled_recording_reads_its_complete_messages(events, tmp_path: Path) -> None:
    """Message-level reading of a truncated file still works when the file is out of order:
    what is read is a subset of the drive, in time order, with each sample's own values."""
    stored = [events[k] for k in np.random.default_rng(5).permutation(len(events))]
    full_path = write_ros2_mcap(tmp_path / "full.mcap", stored, chunk_size=4096)
    full = read_mcap(full_path, progress=False).dataset
    data = full_path.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(data[: int(0.6 * len(data))])
    result = read_mcap(cut_path, progress=False)
    cut = result.dataset
    assert any("truncated" in w for w in result.warnings)
    assert 0.3 * len(full.imu) < len(cut.imu) < 0.8 * len(full.imu)
    assert np.all(np.diff(cut.imu.t) > 0)
    k = np.searchsorted(full.imu.t, cut.imu.t)
    np.testing.assert_array_equal(full.imu.t[k], cut.imu.t)
    np.testing.assert_array_equal(full.imu.gyro[k], cut.imu.gyro)


@pytest.mark.parametrize("size", [113, 40, 8, 5])
def test_a_recording_cut_before_any_message_says_it_is_truncated(
    mcap_dir: Path, tmp_path: Path, size
) -> None:
    """h3 B8d: cut at 113 bytes it said "no IMU channel found; record the IMU topic"."""
    path = tmp_path / "cut.mcap"
    path.write_bytes((mcap_dir / "good.mcap").read_bytes()[:size])
    with pytest.raises(InputError, match=rf"file truncated at byte {size}\b") as caught:
        load_dataset([str(path)], progress=False)
    assert "no IMU channel" not in str(caught.value)


# --------------------------------------------------------------------------------------------
# CSV
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory) -> Path:
    return fgins.simulate("car-urban", tmp_path_factory.mktemp("sim") / "drive", duration=60,
                          seed=1)  # fmt: skip


def test_rows_without_a_position_at_the_start_do_not_move_t0(sim_folder: Path, tmp_path) -> None:
    """h3 B3: 20 leading gnss.csv rows with a time but no lat/lon/alt moved t0 to the first
    row with a position, so --gnss-outage windows shifted silently. t0 is the first epoch's
    time, usable or not (DESIGN.md), as an MCAP NavSatFix with status -1 keeps it."""
    gnss = pd.read_csv(sim_folder / "gnss.csv")
    gnss.loc[:19, ["lat", "lon", "alt"]] = np.nan
    gnss.to_csv(tmp_path / "gnss.csv", index=False)
    imu = str(sim_folder / "imu.csv")
    full = fgins.load(imu, str(sim_folder / "gnss.csv"))
    cut = fgins.load(imu, str(tmp_path / "gnss.csv"))
    assert len(cut.gnss) == len(full.gnss) - 20
    assert cut.t0 == full.t0 == float(gnss["time"].iloc[0])
    for windows in ([(15.0, 25.0)], [(0.0, 10.0)], [(30.0, 40.0), (50.0, 55.0)]):
        withheld_full = full.gnss.t[~outage_mask(full, windows)]
        withheld_cut = cut.gnss.t[~outage_mask(cut, windows)]
        np.testing.assert_array_equal(withheld_cut, withheld_full[withheld_full >= cut.gnss.t[0]])
    with pytest.warns(UserWarning, match="withholds no GNSS epoch"):
        track = fgins.smooth(cut, "ekf", gnss_outage=[(0.0, 10.0)])
    assert track.summary()["gnss_withheld"] == 0


def test_t0_follows_a_time_offset_for_a_csv(sim_folder: Path, tmp_path) -> None:
    gnss = pd.read_csv(sim_folder / "gnss.csv")
    gnss.loc[:4, ["lat", "lon", "alt"]] = np.nan
    gnss.to_csv(tmp_path / "gnss.csv", index=False)
    data = load_dataset([str(sim_folder / "imu.csv"), str(tmp_path / "gnss.csv")],
                        time_offset_s=0.25, progress=False)  # fmt: skip
    assert data.t0 == float(gnss["time"].iloc[0]) + 0.25


def test_unknown_and_misspelt_columns_are_named_with_a_guess(sim_folder: Path, tmp_path) -> None:
    """h3 B6: std_est and hdp were ignored without a word and the result changed."""
    gnss = pd.read_csv(sim_folder / "gnss.csv").rename(columns={"std_east": "std_est",
                                                               "hdop": "hdp"})  # fmt: skip
    gnss.to_csv(tmp_path / "gnss.csv", index=False)
    imu = pd.read_csv(sim_folder / "imu.csv")
    imu["temprature"] = 25.0
    imu["gyro_w"] = 0.0
    imu.to_csv(tmp_path / "imu.csv", index=False)
    data = load_dataset([str(tmp_path / "imu.csv"), str(tmp_path / "gnss.csv")], progress=False)
    unknown = [w for w in data.warnings if "unknown column" in w]
    assert len(unknown) == 2, data.warnings
    gnss_line = next(w for w in unknown if w.startswith("gnss.csv"))
    assert "2 unknown column(s) ignored: std_est (did you mean std_east?), hdp (did you mean " \
           "hdop?)" in gnss_line  # fmt: skip
    imu_line = next(w for w in unknown if w.startswith("imu.csv"))
    assert "temprature" in imu_line and "gyro_w (did you mean gyro_" in imu_line
    partial = [w for w in data.warnings if "std_east missing beside std_north, std_up" in w]
    assert len(partial) == 1 and "east from [gnss] default_sigma_m (no hdop column)" in partial[0]
    # The folder fgins sim wrote has only known columns: no such warning.
    assert not any("unknown column" in w or "missing beside" in w
                   for w in fgins.load(str(sim_folder)).warnings)  # fmt: skip


def _with_comments(source: Path, target: Path, header_as_comment: bool = False) -> None:
    lines = source.read_text().splitlines()
    head = [f"# {lines[0]}"] if header_as_comment else ["# logged by rx", "#", lines[0]]
    body = [*lines[1:6], "# receiver restarted", "#" + lines[6], *lines[7:]]
    target.write_text("\n".join(head + body) + "\n")


@pytest.mark.parametrize("header_as_comment", [False, True])
def test_hash_comment_lines_are_skipped_and_counted(sim_folder: Path, tmp_path, header_as_comment):
    """h1 B8: a '#' first line was an "unrecognised CSV header", a '#' line after the header
    "1 malformed row". Comments are skipped and counted in one note; a header written as a
    comment (numpy.savetxt's default) is the header."""
    for name in ("imu.csv", "gnss.csv"):
        _with_comments(sim_folder / name, tmp_path / name, header_as_comment)
    plain = pd.read_csv(sim_folder / "gnss.csv")
    commented = load_dataset([str(tmp_path / "imu.csv"), str(tmp_path / "gnss.csv")],
                             progress=False)  # fmt: skip
    reference = fgins.load(str(sim_folder / "imu.csv"), str(sim_folder / "gnss.csv"))
    # the commented-out row (the 6th) is not read; everything else is
    keep = np.ones(len(plain), dtype=bool)
    keep[5] = False
    np.testing.assert_array_equal(commented.gnss.t, reference.gnss.t[keep])
    assert len(commented.imu) == len(reference.imu) - 1
    assert not any("malformed" in w for w in commented.warnings)
    count = 2 if header_as_comment else 4
    for name in ("imu.csv", "gnss.csv"):
        notes = [w for w in commented.warnings if w.startswith(f"{name}: skipped")]
        assert notes == [f"{name}: skipped {count} '#' comment line(s)"]


def test_a_file_of_only_comments_says_so(sim_folder: Path, tmp_path) -> None:
    (tmp_path / "gnss.csv").write_text("# logged by rx\n# nothing else\n")
    with pytest.raises(InputError, match="holds only 2 '#' comment line"):
        load_dataset([str(sim_folder / "imu.csv"), str(tmp_path / "gnss.csv")], progress=False)


def test_comment_rows_on_both_parsers_and_the_accel_array_reader(tmp_path) -> None:
    """The pyarrow path (fast and string), the Python fallback and the accelerometer-array
    reader treat '#' lines alike."""
    from fgins.io.accel_array_csv import read_accel_array_csv

    rows = [f"{k * 0.01:.2f},{k},{2 * k}" for k in range(10)]
    text = "\n".join(["# a", "time,a1,a2", *rows[:3], "# short", "#9,9,9", *rows[3:]]) + "\n"
    path = tmp_path / "accel_array.csv"
    path.write_text(text)
    fast = _parse_table(path, 3, skip=2)
    slow = _parse_table_python(path, 3, skip=2)
    np.testing.assert_array_equal(fast[0], slow[0])
    assert fast[1:] == slow[1:] == (0, [], [], 2)
    assert fast[0].shape == (10, 3)
    warnings: list[str] = []
    t, readings = read_accel_array_csv(path, warnings)
    np.testing.assert_array_equal(np.column_stack([t, readings]), fast[0])
    assert warnings == ["accel_array.csv: skipped 3 '#' comment line(s)"]
    # the numeric fast path, with a comment of another width only
    path.write_text("\n".join(["time,a1,a2", *rows[:3], "# note", *rows[3:]]) + "\n")
    found: list[str] = []
    columns = _read_columns(path, found)
    assert columns["time"].size == 10 and found == ["accel_array.csv: skipped 1 '#' comment line(s)"]


@pytest.mark.parametrize("damage", ["nul_tail", "nul_line", "open_quote", "open_quote_late"])
def test_a_damaged_csv_loses_only_the_damaged_row(sim_folder: Path, tmp_path, damage) -> None:
    """A logger that died with a pre-allocated file leaves NUL padding; a hand edit leaves
    one '"' that never closes. Both crashed every command ("internal error: field larger
    than field limit"), or one open quote swallowed every row after it into one cell (a
    gnss.csv's last 70 rows, counted as "1 malformed row", 38 m off at exit 0; outside
    tester). Now exactly the damaged line is dropped and counted, on both parsers."""
    lines = (sim_folder / "imu.csv").read_bytes().split(b"\n")
    n_rows = sum(1 for line in lines[1:] if line)
    at = {"nul_tail": None, "nul_line": 600, "open_quote": 300, "open_quote_late": n_rows - 20}[damage]
    if damage == "nul_tail":
        data = b"\n".join(lines) + b"\x00" * 300_000
        n_rows += 1  # the padding is one more, damaged line
    elif damage == "nul_line":
        data = b"\n".join([*lines[:at], b"\x00" * 200_000, *lines[at:]])
        n_rows += 1  # the NUL line is the extra, damaged row
    else:
        lines[at] = lines[at].replace(b",", b',"', 1)
        data = b"\n".join(lines)
    path = tmp_path / "imu.csv"
    path.write_bytes(data)
    warnings: list[str] = []
    columns = _read_columns(path, warnings)
    assert columns["time"].size == n_rows - 1
    assert warnings == ["imu.csv: dropped 1 malformed row(s)"]
    header_lines = 1
    fast = _parse_table(path, 7, skip=header_lines)
    slow = _parse_table_python(path, 7, skip=header_lines) if "quote" in damage else fast
    np.testing.assert_array_equal(fast[0], slow[0])
    assert fast[1] == slow[1] == 1
    dataset = fgins.load(path, sim_folder / "gnss.csv")  # through the API: no csv.Error
    assert len(dataset.imu) == n_rows - 1


def test_quoted_numbers_still_read_as_numbers(sim_folder: Path, tmp_path) -> None:
    """Every cell quoted (a spreadsheet's export): quotes that close on their line are CSV."""
    frame = pd.read_csv(sim_folder / "gnss.csv")
    path = tmp_path / "gnss.csv"
    frame.to_csv(path, index=False, quoting=1)  # csv.QUOTE_ALL
    warnings: list[str] = []
    columns = _read_columns(path, warnings)
    assert not warnings
    np.testing.assert_allclose(columns["lat"], frame["lat"].to_numpy())
