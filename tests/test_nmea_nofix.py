"""Epochs the receiver marks "no fix" are no fix (outside tester s47/h1, finding 1).

MyGuide 3100 sends its no-fix epochs as a GGA with an empty quality field (a position, 2-3
satellites), an RMC with status V and a GSA with mode 1; gpsd ends each such epoch with a TPV
of mode 1. They were read as quality-1 fixes and the smoother used them (gating the real 3-D
fixes by their PDOP). Checked here against gpsd's per-epoch verdict in all 50 shared logs:
gpsd reports after every sentence, so its verdict on an epoch is the *last* TPV of that time
of day (MyGuide: mode 2 right after the GGA, mode 1 after the RMC V and the GSA 1).

The ``.chk`` parsing is :mod:`fgins.tests.test_nmea_gpsd`'s.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fgins.config import GnssConfig
from fgins.datatypes import InputError
from fgins.factors.gnss import NOT_MEASURED_QUALITIES
from fgins.io.nmea import read_nmea, summarize_nmea
from fgins.tests.test_nmea_gpsd import (
    _TIME_FIELD,
    GPSD_DIR,
    LOGS,
    GpsdFix,
    _gpsd_only_fix,
    _iso_tod,
    _nmea_reports,
    _row_at,
    _sentence_tod,
)

MYGUIDE = GPSD_DIR / "myguide-3100.log"
_TIMED = re.compile(rf"\$..({'|'.join(_TIME_FIELD)}),")

# Epochs gpsd sends no TPV for at all, though the receiver had a fix (every sentence valid):
# its reporting cycle, not a verdict. Log -> time of day (s) -> why.
_GPSD_UNREPORTED = {
    # gpsd's cycle detection restarted on the GGA after the first RMC: no report for it
    "rst39.log": {74492.1: "first GGA after a cycle restart"},
    # RMC A, GGA 1, GSA 3; gpsd's report of the cycle was lost in the log's overflow
    "gp-320fw-2019-04-06-overflow.log": {86246.02: "report lost in the buffer overflow"},
}
# Epochs that gpsd's last report calls no fix only for a sentence of the *next* cycle.
_GPSD_NEXT_CYCLE = {
    # the last fix (GGA 1, RMC A, GSA 2) is followed by the receiver's no-fix cycle, which
    # starts with an untimed GSA mode 1 before its GGA/RMC with empty time: gpsd reports that
    # GSA's mode 1 under the fix's time
    "quectel.log": {8438.0: "no-fix cycle's GSA 1 reported at the last fix's time"},
}
# Logs whose sentences gpsd (as run for its regression tests) ignores: no checksums.
_GPSD_IGNORES = {"hp58534a.log"}


def _gpsd_epoch_verdicts(chk: Path) -> dict[int, dict]:
    """Time of day (ms) -> gpsd's last TPV report for that epoch (its final verdict)."""
    verdicts: dict[int, dict] = {}
    tod: float | None = None
    for sentence, report in _nmea_reports(chk):
        if not report:
            sentence_tod = _sentence_tod(sentence)
            if sentence_tod is not None or _TIMED.match(sentence):
                # a GGA/RMC... with an empty time field (a receiver that lost its fix sends
                # such cycles) starts no epoch: its reports are nobody's verdict
                tod = sentence_tod
            continue
        if tod is None and "time" not in report:
            continue
        if report.get("class") != "TPV":
            continue
        # a no-fix report carries the time of the last fix, if any: it is the sentence's epoch
        fixed = report.get("mode", 0) >= 2 and "time" in report
        report_tod = _iso_tod(report["time"]) if fixed else tod
        if report_tod is not None:
            verdicts[round(report_tod * 1000)] = {**report, "after": sentence}
    return verdicts


def _used(quality: float) -> bool:
    """Whether the smoother's fix-quality gate lets a fix of this quality through."""
    return quality >= GnssConfig().min_fix_quality and int(quality) not in NOT_MEASURED_QUALITIES


@pytest.mark.skipif(not LOGS, reason=f"gpsd logs not found under {GPSD_DIR}")
@pytest.mark.parametrize("log", LOGS, ids=[log.name for log in LOGS])
def test_epoch_fix_status_matches_gpsd(log: Path) -> None:
    verdicts = _gpsd_epoch_verdicts(log.with_suffix(".log.chk"))
    fixes = {ms: v for ms, v in verdicts.items() if v.get("mode", 0) >= 2 and "lat" in v}
    try:
        gnss = read_nmea(log).gnss
    except InputError:
        assert not fixes, f"{log.name}: no fix read, gpsd's final verdict is a fix at {fixes}"
        return
    tod_ms = np.round(np.mod(gnss.t, 86400.0) * 1000).astype(np.int64)
    row_of = {int(ms): i for i, ms in enumerate(tod_ms)}
    # Every epoch gpsd ends with a fix (mode >= 2) is a fix here.
    for ms, report in fixes.items():
        if _row_at(row_of, ms) is None:
            fix = GpsdFix(ms / 1000, report["lat"], report["lon"], None, report["after"])
            assert _gpsd_only_fix(log.name, fix, "missing"), f"{log.name}: no fix at {report}"
    # Every epoch used here is one gpsd ends with a fix.
    unreported = _GPSD_UNREPORTED.get(log.name, {})
    next_cycle = _GPSD_NEXT_CYCLE.get(log.name, {})
    for i, ms in enumerate(tod_ms):
        if not _used(gnss.fix_quality[i]):
            continue
        verdict = _row_at(verdicts, int(ms))
        if verdict is None and (
            log.name in _GPSD_IGNORES or ms / 1000 in unreported or i == len(tod_ms) - 1
        ):
            continue  # gpsd sent no report for it (the last: the log ends before its report)
        if ms / 1000 in next_cycle:
            continue
        assert verdict is not None and verdict.get("mode", 0) >= 2, (
            f"{log.name}: fix used at {ms / 1000:.3f} s of day, gpsd says {verdict}"
        )


@pytest.mark.skipif(not MYGUIDE.is_file(), reason="myguide-3100.log absent")
def test_myguide_no_fix_epochs_are_counted_not_read() -> None:
    result = read_nmea(MYGUIDE)
    assert len(result.gnss) == 9  # the 3-D fixes 10:50:29.8 .. 10:50:37.8
    assert np.all(result.gnss.fix_quality == 1)
    assert np.mod(result.gnss.t[0], 86400.0) == pytest.approx(39029.8)
    assert result.epochs_without_fix == 4
    assert result.epoch_quality_histogram == {0: 4, 1: 9}
    (note,) = [w for w in result.warnings if "without a usable position" in w]
    assert "4 epochs" in note and "RMC status V" in note
    assert "fix quality histogram (GGA codes): 0: 4, 1: 9" in summarize_nmea(MYGUIDE)


def _line(body: str) -> str:
    checksum = 0
    for char in body:
        checksum ^= ord(char)
    return f"${body}*{checksum:02X}"


def _gga(tod: str, quality: str) -> str:
    return _line(f"GPGGA,{tod},4807.038,N,01131.000,E,{quality},08,0.9,545.4,M,46.9,M,,")


def _rmc(tod: str, status: str) -> str:
    return _line(f"GPRMC,{tod},{status},4807.038,N,01131.000,E,0.0,0.0,230394,,,A")


def _gsa(mode: str) -> str:
    return _line(f"GPGSA,A,{mode},04,05,09,12,,,,,,,,,2.5,1.3,2.1")


@pytest.mark.parametrize(
    ("sentences", "fix"),
    [
        ([_gga("120000", "")], False),  # an empty quality field is no fix
        ([_gga("120000", "1"), _gsa("1")], True),  # the GGA claims a fix: gpsd says fix
        ([_rmc("120000", "V"), _gga("120000", "8"), _gsa("3")], True),  # Garmin simulator
        ([_rmc("120000", "A"), _gsa("1")], True),  # RMC A claims it
        ([_rmc("120000", "V"), _gsa("1")], False),
        ([_line("GPGLL,4807.038,N,01131.000,E,120000,A,A"), _gsa("1")], True),
    ],
)
def test_receiver_no_fix_rules(tmp_path: Path, sentences: list[str], fix: bool) -> None:
    good = [_gga(f"1200{s:02d}", "1") for s in (10, 11)]
    path = tmp_path / "log.nmea"
    path.write_text("\n".join([*sentences, *good]) + "\n")
    result = read_nmea(path)
    has_first = bool(np.any(np.isclose(np.mod(result.gnss.t, 86400.0), 43200.0)))
    assert has_first == fix
    assert result.epochs_without_fix == (0 if fix else 1)
    assert math.isfinite(result.gnss.lla[0, 0])


def test_myguide_log_shape() -> None:
    """The pattern the test above relies on is in the log as the tester described."""
    if not MYGUIDE.is_file():
        pytest.skip("myguide-3100.log absent")
    text = MYGUIDE.read_text(encoding="latin-1")
    assert len(re.findall(r"\$GPGGA,[^,]*,[^,]+,N,[^,]+,W,,", text)) == 4
