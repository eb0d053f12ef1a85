"""What ``fgins bench`` scores when no window is given, and its 3-sigma column against fixes.

``fgins sim aircraft-ekf`` (the aircraft study: a 60 s outage) writes a folder whose GNSS
already lacks that minute. ``fgins bench`` on it stopped with "window 510:540 s withholds no
GNSS epoch": its default windows (30 s every 90 s) ran into the data's own outage. The
outage the scenario is about is now the default, scored against the folder's truth.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins import cli

DURATION_S = 240.0


@pytest.fixture(scope="module", params=[90.0, 150.0], ids=["outage-at-90s", "outage-at-150s"])
def aircraft(request, tmp_path_factory) -> tuple[Path, float]:
    folder = tmp_path_factory.mktemp("aircraft") / "flight"
    start = request.param
    assert cli.main(["sim", "aircraft-ekf", "-o", str(folder), "--duration", str(DURATION_S),
                     "--set", f"outage_start_s={start:g}"]) == 0  # fmt: skip
    return folder, start


def _outage_rms_against_truth(
    track: pd.DataFrame, truth: pd.DataFrame, window: tuple[float, float]
) -> float:
    """Horizontal RMS of the written track against truth.csv inside ``window`` (seconds from
    the first sample), by hand: both files carry east/north at the same IMU times."""
    merged = track.merge(truth, on="time", suffixes=("", "_truth"))
    inside = (merged["time"] - truth["time"].iloc[0] >= window[0]) & (
        merged["time"] - truth["time"].iloc[0] < window[1]
    )
    east = merged["east"] - merged["east_truth"]
    north = merged["north"] - merged["north_truth"]
    return float(np.sqrt(np.mean((east**2 + north**2)[inside])))


def test_a_sim_folders_own_outage_is_the_default_benchmark(aircraft, tmp_path, capsys):
    folder, start = aircraft
    code = cli.main(["bench", str(folder), "--methods", "ekf,ekf-rts", "--no-progress",
                     "-o", str(tmp_path / "bench")])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert f"outages [({start:g}, {start + 60:g})] (the data's own" in out.replace(
        ".0,", ","
    ).replace(".0)", ")"), out
    assert "reference: simulator truth" in out

    dataset = fgins.load(folder, progress=False)
    table = fgins.bench(dataset, ["ekf"])
    assert table.attrs["outages"] == [(start, start + 60.0)]
    assert table.attrs["outages_from"] == "data"
    # The table's number is the error inside that minute, against the truth, as computed by
    # hand from the written track.
    track = fgins.smooth(dataset, "ekf", progress=False)
    track.write(tmp_path / "ekf.csv")
    by_hand = _outage_rms_against_truth(
        pd.read_csv(tmp_path / "ekf.csv"), pd.read_csv(folder / "truth.csv"), (start, start + 60.0)
    )
    assert table.loc[0, "h_rms_outage_m"] == pytest.approx(by_hand, rel=0.02)
    assert by_hand > 0.3  # an outage was bridged (the forward EKF drifts metres in a minute)


def test_default_windows_where_the_data_have_no_gnss_are_left_out_and_said(aircraft, tmp_path):
    folder, start = aircraft
    bare = tmp_path / "no_truth"
    shutil.copytree(folder, bare)
    (bare / "truth.csv").unlink()  # withheld fixes are the reference: the own outage has none
    dataset = fgins.load(bare, progress=False)
    with pytest.warns(
        fgins.FginsWarning,
        match=r"1 of the \d+ default outage windows fall where the data have no GNSS",
    ):
        # The protocol's first window, 20 s from 10 s into the data's own outage, is empty.
        table = fgins.bench(
            dataset, ["ekf"], outage_start=start + 10.0, outage_duration=20.0, outage_period=50.0
        )
    windows = table.attrs["outages"]
    assert windows and table.attrs["outages_from"] == "protocol"
    assert all(end <= start or begin >= start + 60.0 for begin, end in windows), windows
    # A window the user gives there stays an error: it would measure nothing.
    with pytest.raises(fgins.ConfigError, match="withholds no GNSS epoch"):
        fgins.bench(dataset, ["ekf"], outages=[(start + 10.0, start + 40.0)])


def test_the_3_sigma_column_against_withheld_fixes_counts_their_own_sigma(aircraft, tmp_path):
    """The aircraft's fixes scatter 5 m (8 m up): an error against them is mostly theirs. The
    column counted the trajectory's sigma alone and called an honest EKF "10 % within 3
    sigma"; with the fixes' sigma added it is the fraction a consistent pair gives."""
    folder, _ = aircraft
    bare = tmp_path / "no_truth"
    shutil.copytree(folder, bare)
    (bare / "truth.csv").unlink()
    dataset = fgins.load(bare, progress=False)
    table = fgins.bench(dataset, ["ekf", "batch"], outages=[(30.0, 60.0), (200.0, 230.0)])
    for row in table.itertuples():
        assert row.within_3sigma_outage >= 0.9, (row.method, row.within_3sigma_outage)
    # By hand: each withheld fix's horizontal error against the EKF, inside the sum of both
    # sigmas (the fixes' 5 m per axis from config.toml, the track's from its std columns).
    track = fgins.smooth(dataset, "ekf", gnss_outage=[(30.0, 60.0), (200.0, 230.0)], progress=False)
    fixes = dataset.gnss_enu()
    relative = dataset.gnss.t - dataset.t0
    inside = ((relative >= 30) & (relative < 60)) | ((relative >= 200) & (relative < 230))
    at = track.at(dataset.gnss.t[inside])
    std = np.column_stack(
        [np.interp(dataset.gnss.t[inside], track.t, track.position_std[:, i]) for i in range(2)]
    )
    # Inside the 3-sigma ellipse of the two sigmas together (2-D chi-square 11.83: 99.73 %).
    z2 = np.sum(((at[:, :2] - fixes[inside, :2]) / np.hypot(std, 5.0)) ** 2, axis=1)
    assert table.set_index("method").loc["ekf", "within_3sigma_outage"] == pytest.approx(
        float(np.mean(z2 <= 11.829)), abs=1e-9
    )


def test_another_simulators_truth_without_sigmas_or_attitude_scores_alike(tmp_path):
    """An independent simulator's truth.csv need not carry fgins's sigma or attitude columns,
    nor east/north/up about the same origin: `fgins bench` stopped with "missing trajectory
    column(s) std_east, ..." on one. Positions from lat/lon/alt score alike; the attitude
    metrics it cannot give are null in outages.json, which stays strict JSON."""
    import json

    folder = tmp_path / "drive"
    assert cli.main(["sim", "car-urban", "-o", str(folder), "--duration", "70", "--seed", "5"]) == 0
    full = fgins.bench(
        fgins.load(folder, progress=False),
        ["ekf"],
        outages=[(30.0, 50.0)],
        output_dir=tmp_path / "full",
    )
    full_metrics = json.loads((tmp_path / "full" / "outages.json").read_text())["drive"]["methods"][
        "ekf"
    ]
    truth = pd.read_csv(folder / "truth.csv")
    for name, columns in {
        "lla_only": ["time", "lat", "lon", "alt"],
        "lla_velocity": ["time", "lat", "lon", "alt", "vel_east", "vel_north", "vel_up"],
        "shifted_enu": [
            "time",
            "lat",
            "lon",
            "alt",
            "east",
            "north",
            "up",
            "roll_deg",
            "pitch_deg",
            "heading_deg",
        ],
    }.items():
        other = tmp_path / name
        shutil.copytree(folder, other)
        table = truth[columns].copy()
        if name == "shifted_enu":  # its own frame 1 km away: not the dataset's
            table["east"] += 1000.0
            table["north"] -= 500.0
        table.to_csv(other / "truth.csv", index=False)
        out = tmp_path / f"bench_{name}"
        scored = fgins.bench(
            fgins.load(other, progress=False), ["ekf"], outages=[(30.0, 50.0)], output_dir=out
        )
        assert scored.loc[0, "h_rms_outage_m"] == pytest.approx(
            full.loc[0, "h_rms_outage_m"], abs=1e-3
        ), name
        payload = json.loads(
            (out / "outages.json").read_text(),
            parse_constant=lambda c: pytest.fail(f"{c} in outages.json"),
        )
        metrics = payload[other.name]["methods"]["ekf"]
        if "roll_deg" not in columns:
            assert metrics["heading_rms_deg"] is None
        else:
            assert metrics["heading_rms_deg"] == pytest.approx(
                full_metrics["heading_rms_deg"], abs=1e-6
            )


def test_a_truth_in_east_north_up_alone_needs_a_stated_origin(tmp_path):
    """East/north/up without lat/lon/alt are about some origin: the folder's stated [origin]
    (as `fgins sim` writes both), else unknown. An independent car simulator's truth, about
    its own origin 2.6 m from the first fix (the default origin), scored every epoch 2 m off
    (0 % within 3 sigma) when taken about the first fix: an error now, naming the cause."""
    import re

    folder = tmp_path / "drive"
    assert cli.main(["sim", "car-urban", "-o", str(folder), "--duration", "70", "--seed", "6"]) == 0
    full = fgins.bench(fgins.load(folder, progress=False), ["ekf"], outages=[(30.0, 50.0)])
    truth = pd.read_csv(folder / "truth.csv")
    truth[["time", "east", "north", "up", "vel_east", "vel_north", "vel_up"]].to_csv(
        folder / "truth.csv", index=False
    )
    stated = fgins.bench(fgins.load(folder, progress=False), ["ekf"], outages=[(30.0, 50.0)])
    assert stated.loc[0, "h_rms_outage_m"] == pytest.approx(full.loc[0, "h_rms_outage_m"], abs=1e-3)

    config = (folder / "config.toml").read_text()
    (folder / "config.toml").write_text(
        re.sub(r"\[origin\]\nlat = \S+\nlon = \S+\nalt = \S+\n", "", config)
    )
    assert "[origin]" not in (folder / "config.toml").read_text()
    with pytest.raises(
        fgins.InputError, match=r"truth\.csv: .*needs the columns time and lat, lon, alt \(its east"
    ):
        fgins.bench(fgins.load(folder, progress=False), ["ekf"], outages=[(30.0, 50.0)])


def test_a_protocol_number_given_asks_for_the_protocol_over_the_datas_own_outages(
    aircraft, tmp_path, capsys
):
    """`--outage-duration 40` on a folder with its own outage: the user asked for the
    protocol's windows (the own outage had taken over silently); the one that falls in the
    data's own gap is left out and said."""
    folder, start = aircraft
    code = cli.main(["bench", str(folder), "--methods", "ekf", "--outage-duration", "40",
                     "--no-progress", "-o", str(tmp_path / "bench")])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "(40 s every 90 s from 60 s)" in captured.out
    assert "the data's own" not in captured.out
    dataset = fgins.load(folder, progress=False)
    with pytest.warns(
        fgins.FginsWarning, match="default outage windows fall where the data have no GNSS"
    ):
        table = fgins.bench(
            dataset, ["ekf"], outage_start=start + 10.0, outage_duration=20.0, outage_period=50.0
        )
    assert table.attrs["outages_from"] == "protocol"
    assert table.attrs["protocol"] == (20.0, 50.0, start + 10.0)


def test_protocol_windows_that_would_touch_are_refused_as_the_protocols_mistake():
    """duration == period passed "0 < duration <= period" and was then refused as explicit
    windows that "touch", which the user never gave (outside tester)."""
    from fgins.datatypes import ConfigError
    from fgins.outages import periodic_windows

    with pytest.raises(ConfigError, match=r"need 0 < duration < period .*touch are one outage"):
        periodic_windows(30.0, 30.0, 0.0, 300.0)
    assert periodic_windows(30.0, 30.5, 0.0, 90.0) == [(0.0, 30.0), (30.5, 60.5)]


@pytest.mark.parametrize("t0", [0.0, 1000.0, 1_700_000_000.0])
def test_a_fix_stamped_at_a_windows_end_is_not_withheld(t0):
    """5 Hz fixes at POSIX times: 1.4 s after t0 read 1.39999999999998 and was withheld by
    a window ending at 1.4 (outside tester): [start, end) to the microsecond."""
    from fgins.outages import in_windows

    t = t0 + np.round(np.arange(0, 3, 0.2), 1)
    inside = in_windows(t, t0, [(0.6, 1.4)])
    assert np.flatnonzero(inside).tolist() == [3, 4, 5, 6]  # 0.6, 0.8, 1.0, 1.2


def test_a_window_past_the_data_is_scored_over_its_part_and_said(aircraft):
    """An explicit 280:400 on a 300 s drive was scored as 280:300 without a word (outside
    tester): the window's row is the part the data have, and that is said."""
    folder, _ = aircraft
    dataset = fgins.load(folder)
    last = float(dataset.gnss.t[-1] - dataset.t0)
    with pytest.warns(fgins.FginsWarning, match=r"runs past the last GNSS epoch"):
        table = fgins.bench(dataset, methods=["ekf"], outages=[(last - 20.0, last + 100.0)])
    assert table.attrs["warnings"] and any("runs past" in w for w in table.attrs["warnings"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        inside = fgins.bench(dataset, methods=["ekf"], outages=[(last - 20.0, last - 5.0)])
    assert not [w for w in caught if "runs past" in str(w.message)]
    assert not any("runs past" in w for w in inside.attrs["warnings"])
