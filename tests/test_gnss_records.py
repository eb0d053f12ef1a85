"""GNSS records that are not what they look like (outside tester F7, F16): DOP "not available"
placeholders (u-blox 99.99, NMEA 0.00 / 99.0) and fixes whose quality says they are no
measurement (6 dead reckoning, 7 manual input, 8 simulator).

Checked on the shared real logs (gpsd's corpus; gpsd's reference DOPs for these logs are
computed from the satellites, never 99.99) through ``fgins convert``, and end to end through
``fgins smooth`` on a simulator drive written as a CSV pair.
"""

from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fgins.cli import main
from fgins.config import GnssConfig
from fgins.factors.gnss import gate_epochs, position_sigmas, velocity_sigmas
from fgins.io.csv_pair import read_gnss_csv, write_gnss_csv, write_imu_csv
from fgins.sim.scenarios import SCENARIOS


def _shared_dir() -> Path:
    env = os.environ.get("FGINS_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared"


DATA = _shared_dir() / "data"
needs_logs = pytest.mark.skipif(
    not (DATA / "ubx" / "gpsd").is_dir() or not (DATA / "nmea" / "gpsd").is_dir(),
    reason="shared gpsd logs absent",
)

# log -> (fixes, DOP values that are placeholders, fixes holding one): the tester's counts.
PLACEHOLDER_LOGS = {
    "ubx/gpsd/ublox-glo.log": (291, 325, 171),
    "ubx/gpsd/ublox-neo-m8t-s.log": (29, 87, 29),
    "ubx/gpsd/ublox-lea-m8f.log": (28, 74, 28),
    "nmea/gpsd/jl-micro-jlt.log": (8, 24, 8),
}


def _convert(tmp_path: Path, log: str, capsys) -> tuple[object, str]:
    out = tmp_path / (Path(log).stem + ".csv")
    assert main(["convert", str(DATA / log), "-o", str(out)]) == 0
    return read_gnss_csv(out), capsys.readouterr().err


@needs_logs
@pytest.mark.parametrize("log", list(PLACEHOLDER_LOGS))
def test_dop_placeholders_are_written_as_missing(tmp_path, capsys, log):
    """ublox-glo: pDOP 99.99 in 171 of 291 fixes; neo-m8t-s, lea-m8f: in every fix (a
    pdop_max = 5 gate took all 29 / 28 as outages); jl-micro-jlt: GSA 0.00 and GGA HDOP
    99.0. None is left in the converted gnss.csv, the count is said, and the sigmas the
    smoother uses are finite and positive."""
    fixes, placeholders, rows = PLACEHOLDER_LOGS[log]
    gnss, err = _convert(tmp_path, log, capsys)
    assert len(gnss) == fixes
    for name in ("hdop", "vdop", "pdop"):
        value = getattr(gnss, name)
        finite = value[np.isfinite(value)]
        assert np.all((finite > 0) & (finite < 99)), (name, np.unique(finite)[-3:])
    assert (
        f"{placeholders} DOP value(s) in {rows} fix(es) are the receiver's 'not available'"
        in err
    )
    config = GnssConfig()
    sigma = position_sigmas(gnss, config)
    assert np.all(np.isfinite(sigma) & (sigma > 0))
    velocity = velocity_sigmas(gnss, config)
    has = np.isfinite(velocity)
    assert np.all(velocity[has] > 0)
    # Where a fix has no sigma of its own, it falls back exactly as a log without any DOP.
    no_dops = replace(gnss, hdop=np.full(len(gnss), np.nan), vdop=np.full(len(gnss), np.nan),
                      pdop=np.full(len(gnss), np.nan))  # fmt: skip
    dops_gone = ~np.isfinite(gnss.hdop) & ~np.isfinite(gnss.vdop) & ~np.isfinite(gnss.pdop)
    np.testing.assert_array_equal(sigma[dops_gone], position_sigmas(no_dops, config)[dops_gone])
    # The PDOP gate judges only real PDOPs: no placeholder is an "outage".
    gate = gate_epochs(gnss, GnssConfig(pdop_max=5.0))
    real_high = int(np.sum(np.isfinite(gnss.pdop) & (gnss.pdop > 5.0) & (gnss.fix_quality >= 1)))
    assert gate.rejected_pdop == real_high
    if "glo" not in log:
        assert gate.rejected_pdop == 0 and gate.n_used == fixes


@needs_logs
@pytest.mark.parametrize(("log", "fixes"), [("GPSmap-76S.log", 12), ("garmin-geko201.log", 18)])
def test_a_simulator_mode_log_is_converted_with_its_quality_and_said(tmp_path, capsys, log, fixes):
    """Garmin receivers in demo mode send GGA quality 8: `fgins convert` writes the fixes
    (fix_quality 8 kept, so a reader can tell) and says the log is simulated."""
    gnss, err = _convert(tmp_path, f"nmea/gpsd/{log}", capsys)
    assert len(gnss) == fixes and np.all(gnss.fix_quality == 8)
    assert (
        f"warning: gnss: every fix ({fixes}) has fix quality 8: the receiver was in simulator "
        "mode, its positions are not GNSS measurements" in err
    )
    assert gate_epochs(gnss, GnssConfig()).rejected_quality == fixes


# --- end to end: fgins smooth on a simulator drive ------------------------------------------


@pytest.fixture(scope="module")
def drive():
    return SCENARIOS["car-urban"](seed=3, duration_s=60).dataset


def _smooth(tmp_path: Path, dataset, gnss, capsys) -> tuple[int, str]:
    write_imu_csv(dataset.imu, tmp_path / "imu.csv")
    write_gnss_csv(gnss, tmp_path / "gnss.csv")
    rc = main(["smooth", str(tmp_path / "imu.csv"), str(tmp_path / "gnss.csv"),
               "--method", "ekf", "-o", str(tmp_path / "out.csv")])  # fmt: skip
    return rc, capsys.readouterr().err


def _gnss_line(err: str) -> str:
    (line,) = [x for x in err.splitlines() if x.startswith("GNSS: ")]
    return line


def test_a_pdop_of_99_99_is_not_an_outage(tmp_path, capsys, drive):
    """Every PDOP 99.99 and every HDOP 0.00 (the placeholders): the old reading gated all 60
    epochs by PDOP > 5 ("no usable GNSS epoch") and would have floored a 0-HDOP sigma."""
    gnss = drive.gnss
    n = len(gnss)
    rc, err = _smooth(tmp_path, drive, replace(gnss, pdop=np.full(n, 99.99),
                                               hdop=np.zeros(n)), capsys)  # fmt: skip
    assert rc == 0, err
    assert f"{2 * n} DOP value(s) in {n} fix(es) are the receiver's 'not available'" in err
    assert re.search(r"\b0 gated by PDOP > 5\b", _gnss_line(err)), err


def test_simulator_and_manual_fixes_are_gated_and_counted(tmp_path, capsys, drive):
    """Fix quality 7 (manual input) and 8 (simulator) went in as real fixes ("0 by fix
    quality"); 9 (SBAS) is a measurement and stays."""
    quality = np.ones(len(drive.gnss), dtype=int)
    quality[10:20] = 8
    quality[30:35] = 7
    quality[40:45] = 9
    rc, err = _smooth(tmp_path, drive, replace(drive.gnss, fix_quality=quality), capsys)
    assert rc == 0, err
    assert re.search(r"\b15 by fix quality\b", _gnss_line(err)), err
    assert (
        f"gnss: 15 of {len(quality)} fix(es) are not GNSS measurements by their fix quality "
        "(5 with 7 (manual input), 10 with 8 (simulator))" in err
    )


def test_a_whole_simulator_log_is_refused_naming_the_quality(tmp_path, capsys, drive):
    n = len(drive.gnss)
    rc, err = _smooth(tmp_path, drive, replace(drive.gnss, fix_quality=np.full(n, 8)), capsys)
    lines = err.splitlines()  # the input checks' warnings, then the one error line
    assert rc == 2 and lines[-1].startswith("fgins: error: "), lines
    assert all(line.startswith("warning: ") for line in lines[:-1]), lines
    assert f"no usable GNSS epoch of {n}: {n} by fix quality" in lines[-1]
    assert f"simulator: not measurements: {n} with 8 (simulator))" in err


def test_sigmas_a_fix_quality_cannot_have_are_raised_to_it():
    """An RTK receiver's std columns kept claiming 1.5 cm through float, DGPS and single-point
    stretches (GGA quality 5, 2, 1): weighted so, the scatter check scaled every fix, RTK ones
    too, and the drive came out 0.15 m off at z 3.7 (outside tester). Sigmas below what the
    fix's own quality allows are raised to it and counted; RTK fixed ones stay."""
    from fgins.datatypes import GnssData
    from fgins.io.gnss_checks import QUALITY_MIN_SIGMA_M, check_gnss_records

    quality = np.array([4, 4, 5, 2, 9, 1, 1])  # 1: also the quality of a fix without one
    std = np.tile([0.015, 0.015, 0.025], (len(quality), 1))
    std[-1] = [1.2, 1.2, 2.0]  # an honest single-point fix
    gnss = GnssData(t=np.arange(len(quality), dtype=float), lla=np.tile([45.0, 10.0, 100.0], (len(quality), 1)),
                    std=std, fix_quality=quality)  # fmt: skip
    checks: list[str] = []
    out = check_gnss_records(gnss, checks)
    assert np.allclose(out.std[:2], std[:2])  # RTK fixed: as stated
    for i in range(2, 5):
        floor = QUALITY_MIN_SIGMA_M[int(quality[i])]
        assert np.allclose(out.std[i, :2], floor) and out.std[i, 2] >= 1.5 * floor - 1e-12
    assert np.allclose(out.std[5:], std[5:])
    assert len(checks) == 1 and checks[0].startswith("gnss: 3 fix(es) state sigmas below"), checks
    assert np.allclose(gnss.std, std)  # the input is not changed
