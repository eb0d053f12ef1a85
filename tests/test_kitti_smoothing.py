"""Acceptance on the real KITTI drive (demo:kitti), against its own GNSS positions."""

from __future__ import annotations

import numpy as np
import pytest

from fgins.bench.metrics import errors_against
from fgins.graph.smoother import smooth
from fgins.outages import outage_mask

WINDOWS_30 = [(60, 90), (150, 180), (240, 270), (330, 360), (420, 450)]
WINDOWS_60 = [(60, 120), (210, 270), (360, 420)]


def _run(kitti, config, windows, method="batch"):
    mask = outage_mask(kitti, windows)
    trajectory = smooth(kitti, config, method, gnss_mask=mask, progress=False)
    errors = errors_against(trajectory, kitti.gnss.t, kitti.gnss_enu(), kitti.t0, windows)
    return trajectory, errors.summary()


def test_reader_matches_file_exactly(kitti):
    # ENU of the GNSS fixes equals the file's X,Y,Z (east, north, up) after the lat/lon trip.
    np.testing.assert_allclose(kitti.gnss_enu(), kitti.metadata["gnss_enu_file"], atol=1e-6)
    assert len(kitti.imu) == 46968
    assert len(kitti.imu.suspect) == 9  # the start-up gap + eight linearly filled stretches


def test_no_outage_horizontal_rms_below_30cm(kitti, kitti_config):
    trajectory, summary = _run(kitti, kitti_config, [])
    assert summary["h_rms_all"] < 0.3
    # Output at IMU rate over the whole input span.
    np.testing.assert_array_equal(trajectory.t, kitti.imu.t)
    assert np.all(np.isfinite(trajectory.position_std))


def test_30s_outages_beat_reference_script(kitti, kitti_config):
    _, summary = _run(kitti, kitti_config, WINDOWS_30)
    assert summary["h_rms_outage"] <= 2.1
    assert summary["h_rms_aided"] < 0.3


def test_60s_outages_beat_reference_script(kitti, kitti_config):
    _, summary = _run(kitti, kitti_config, WINDOWS_60)
    assert summary["h_rms_outage"] <= 13.6


def test_isam2_final_within_10_percent_of_batch(kitti, kitti_config):
    _, batch = _run(kitti, kitti_config, WINDOWS_30)
    final, isam = _run(kitti, kitti_config, WINDOWS_30, "isam2")
    assert isam["h_rms_outage"] <= 1.1 * batch["h_rms_outage"]
    online = final.info["online"]
    assert online.method == "isam2-online"
    assert np.all(np.isfinite(online.position))


@pytest.mark.parametrize("heading_error_deg", [30.0, 90.0])
def test_isam2_survives_a_poorly_known_start(kitti, kitti_config, heading_error_deg):
    from dataclasses import replace

    from fgins.alignment import initial_alignment
    from fgins.geodesy import rotation_to_roll_pitch_heading

    heading = rotation_to_roll_pitch_heading(initial_alignment(kitti).rotation[None])[0, 2]
    config = replace(
        kitti_config,
        smoother=replace(kitti_config.smoother, initial_heading_deg=heading + heading_error_deg),
    )
    trajectory = smooth(kitti, config, "isam2-online", progress=False)
    assert np.all(np.isfinite(trajectory.position))


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_gnss_withheld_at_the_very_start(kitti, method):
    """The car starts moving with no GNSS for 30 s: the alignment is made at the first fix
    and carried back; the start is then bridged like any other (one-sided) outage."""
    from fgins.config import config_for_dataset

    _, summary = _run(kitti, config_for_dataset(kitti), [(0, 30)], method)
    assert summary["h_rms_outage"] < 3.0
    assert summary["h_rms_aided"] < 0.3
