"""The UBX reader against gpsd's reference decodings of 14 real u-blox logs.

Each ``X.log.chk`` holds gpsd's JSON reports for ``X.log`` (and the NMEA it generated). Every fix
gpsd reports (TPV, mode >= 2) must be found by :func:`read_ubx` with the same time (1 ms),
latitude/longitude (1e-7 deg) and ellipsoidal height (1 mm); every IMU sample gpsd decodes
from UBX-ESF-RAW must be found with the same values (1e-4 m/s^2, 1e-4 deg/s, 0.01 deg C), in
order; ESF-MEAS too. The gpsd-specific exceptions are listed in ``_gpsd_specific`` with the
reason; nothing is loosened globally.
"""

from __future__ import annotations

import calendar
import functools
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

from fgins.datatypes import InputError
from fgins.io.nmea import read_nmea
from fgins.io.ubx import ESF_RAW_TICK_S, read_ubx, require_fix


def _shared_dir() -> Path:
    env = os.environ.get("FGINS_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared"


GPSD_DIR = _shared_dir() / "data" / "ubx" / "gpsd"
LOGS = sorted(GPSD_DIR.glob("*.log")) if GPSD_DIR.is_dir() else []
pytestmark = pytest.mark.skipif(not LOGS, reason="../shared/data/ubx/gpsd not present")

TIME_TOL_S = 1e-3
LATLON_TOL_DEG = 1e-7
HEIGHT_TOL_M = 1e-3
ACC_TOL = 1e-4
GYRO_TOL = 1e-4
NO_FIX_LOG = "ublox-zoe-m8b-logbatch.log"
# 2007: GPS - UTC = 14 s (gpsd's compiled-in value today is 18).
AEK_LEAP_DIFFERENCE_S = 18 - 14


def _iso(text: str) -> float:
    match = re.fullmatch(r"(\d+)-(\d+)-(\d+)T(\d+):(\d+):(\d+(?:\.\d*)?)Z", text)
    assert match, text
    y, mo, d, h, mi = (int(match.group(i)) for i in range(1, 6))
    return calendar.timegm((y, mo, d, h, mi, 0)) + float(match.group(6))


def _reports(path: Path, cls: str) -> list[dict]:
    out = []
    for line in path.with_name(path.name + ".chk").read_text(errors="replace").splitlines():
        if line.startswith("{") and f'"class":"{cls}"' in line:
            out.append(json.loads(line))
    return out


def _gpsd_fixes(path: Path) -> list[dict]:
    return [r for r in _reports(path, "TPV") if r.get("mode", 0) >= 2 and "lat" in r]


def _match(gnss, t: float, lat: float, lon: float, alt: float | None) -> bool:
    close = np.flatnonzero(np.abs(gnss.t - t) <= TIME_TOL_S)
    for i in close:
        ok = abs(gnss.lla[i, 0] - lat) <= LATLON_TOL_DEG + 1e-12
        ok &= abs(gnss.lla[i, 1] - lon) <= LATLON_TOL_DEG + 1e-12
        if alt is not None:
            ok &= abs(gnss.lla[i, 2] - alt) <= HEIGHT_TOL_M + 1e-9
        if ok:
            return True
    return False


def _gpsd_specific(path: Path, fix: dict, result) -> str | None:
    """Why gpsd's fix legitimately differs from the UBX decoding, or None."""
    t = _iso(fix["time"])
    if path.name == "ublox-aek-4t.log":
        # ANTARIS 4, December 2007: gpsd's first TPV comes before any NAV-TIMEGPS, so gpsd used
        # its compiled-in leap seconds (18) instead of 2007's 14. That epoch's own NAV-TIMEUTC
        # (validUTC) puts it 4 s later, where the reader has it with the same position.
        if _match(result.gnss, t + AEK_LEAP_DIFFERENCE_S, fix["lat"], fix["lon"], fix.get("altHAE")):
            return "gpsd used 18 leap seconds in 2007 (UTC 4 s early)"
    if path.name == "ublox-zed-f9r.log":
        # gpsd reported the receiver's NMEA GGA of that instant (lat/lon to 1e-5 arc-minute,
        # height to 0.1 m) rather than its NAV-PVT. The reader prefers NAV-PVT (full precision,
        # with hAcc/vAcc); it must agree with the NMEA values within their rounding.
        nmea = _nmea_of(path)
        tod = t % 86400.0
        in_nmea = _match_tod(nmea, tod, fix)
        close = np.flatnonzero(np.abs(result.gnss.t - t) <= TIME_TOL_S)
        if in_nmea and close.size:
            i = close[0]
            rounding_deg = 0.5e-5 / 60.0
            if (
                abs(result.gnss.lla[i, 0] - fix["lat"]) <= rounding_deg + LATLON_TOL_DEG
                and abs(result.gnss.lla[i, 1] - fix["lon"]) <= rounding_deg + LATLON_TOL_DEG
                and abs(result.gnss.lla[i, 2] - fix["altHAE"]) <= 0.05 + 0.05 + HEIGHT_TOL_M
            ):
                return "gpsd reported the NMEA GGA fix (rounded) of a NAV-PVT epoch"
    return None


@functools.lru_cache(maxsize=4)
def _nmea_of(path: Path):
    return read_nmea(path).gnss


def _match_tod(nmea, tod: float, fix: dict) -> bool:
    near = np.flatnonzero(np.abs((nmea.t % 86400.0) - tod) <= TIME_TOL_S)
    return any(
        abs(nmea.lla[i, 0] - fix["lat"]) <= LATLON_TOL_DEG + 1e-12
        and abs(nmea.lla[i, 1] - fix["lon"]) <= LATLON_TOL_DEG + 1e-12
        and abs(nmea.lla[i, 2] - fix["altHAE"]) <= HEIGHT_TOL_M
        for i in near
    )


EXPECTED_EXCEPTIONS = {"ublox-aek-4t.log": 1, "ublox-zed-f9r.log": 54}


@pytest.mark.parametrize("path", LOGS, ids=[p.name for p in LOGS])
def test_every_gpsd_fix_is_found(path: Path):
    result = read_ubx(path)  # never raises on these logs
    fixes = _gpsd_fixes(path)
    if path.name == NO_FIX_LOG:
        assert not fixes and result.gnss is None
        with pytest.raises(InputError, match="no fix"):
            require_fix(result)
        return
    assert fixes, "every other log has gpsd fixes"
    missing, explained = [], []
    for fix in fixes:
        if _match(result.gnss, _iso(fix["time"]), fix["lat"], fix["lon"], fix.get("altHAE")):
            continue
        reason = _gpsd_specific(path, fix, result)
        (explained if reason else missing).append((fix["time"], reason))
    assert not missing, f"{len(missing)} of {len(fixes)} gpsd fixes not found: {missing[:5]}"
    assert len(explained) == EXPECTED_EXCEPTIONS.get(path.name, 0), explained[:3]
    # Sigmas come from the receiver: finite on every UBX-derived fix.
    assert np.all(np.isfinite(result.gnss.std[:, 0]))


def test_esf_raw_samples_match_gpsd():
    path = GPSD_DIR / "ublox-neo-m8u.log"
    result = read_ubx(path)
    reports = [r for r in _reports(path, "IMU") if r["msg"] == "UBX-ESF-RAW"]
    # gpsd-specific: gpsd re-reports samples from its IMU queue (830 reports of 290 distinct
    # time tags). Every report is checked; the distinct ones, in first-report order, must be
    # exactly the reader's samples in its order.
    first: dict[int, int] = {}
    for k, ref in enumerate(reports):
        first.setdefault(ref["timeTag"], k)
    reference = [reports[k] for k in sorted(first.values())]
    assert result.imu_source == "ESF-RAW"
    assert len(reports) == 830 and len(reference) == len(result.imu_tags) == 290
    tags = result.imu_tags.astype(np.int64) % (1 << 24)
    index = {int(tag): k for k, tag in enumerate(tags)}
    for ref in reports:  # repeats carry the same values as the sample they repeat
        k = index[ref["timeTag"]]
        assert abs(result.imu_raw_accel[k, 0] - ref["acc_x"]) <= ACC_TOL
        assert abs(result.imu_raw_gyro_deg_s[k, 2] - ref["gyro_z"]) <= GYRO_TOL
    for k, ref in enumerate(reference):  # same samples, same order
        assert tags[k] == ref["timeTag"]
        for axis, name in enumerate("xyz"):
            assert abs(result.imu_raw_accel[k, axis] - ref[f"acc_{name}"]) <= ACC_TOL
            assert abs(result.imu_raw_gyro_deg_s[k, axis] - ref[f"gyro_{name}"]) <= GYRO_TOL
        assert abs(result.imu_temp[k] - ref["gyro_temp"]) <= 0.005 + 1e-9
    # SI units in the ImuData: rad/s, m/s^2.
    np.testing.assert_allclose(result.imu.gyro, np.radians(result.imu_raw_gyro_deg_s))
    np.testing.assert_allclose(result.imu.accel, result.imu_raw_accel)
    # At rest: |specific force| ~ g, z up out of the module (the documented axis convention).
    assert 9.7 < np.linalg.norm(result.imu.accel.mean(axis=0)) < 10.2
    assert result.imu.accel[:, 2].mean() > 9.5


def test_esf_raw_time_mapping_against_the_fixes():
    """The receiver emits the IMU samples up to an epoch before that epoch's NAV-PVT: the
    samples at the anchors line up with the fixes to within a fraction of a sample period."""
    result = read_ubx(GPSD_DIR / "ublox-neo-m8u.log")
    (mapping,) = result.time_maps
    assert mapping.anchors == 3
    assert mapping.scale == pytest.approx(ESF_RAW_TICK_S)
    assert mapping.spread_s < 1e-3  # 3 fixes, one second apart, each on a sample to < 1 ms
    imu_t, gnss_t = result.imu.t, result.gnss.t
    assert imu_t[0] < gnss_t[0] and gnss_t[-1] <= imu_t[-1] + 1e-3
    # Each fix time has an IMU sample within one sample period (10 ms).
    nearest = np.min(np.abs(imu_t[None, :] - gnss_t[:, None]), axis=1)
    assert np.all(nearest < 0.0102)
    assert 99.0 < result.imu.rate_hz < 101.0


def test_esf_meas_messages_match_gpsd_and_pair():
    path = GPSD_DIR / "ublox-neo-m8u.log"
    result = read_ubx(path)
    reports = [r for r in _reports(path, "IMU") if r["msg"] == "UBX-ESF-MEAS"]
    # gpsd re-reports two of them (60 reports of 58 messages): compare the distinct ones.
    seen, reference = set(), []
    for r in reports:
        key = (r["timeTag"], "acc_x" in r)
        if key not in seen:
            seen.add(key)
            reference.append(r)
    assert len(reports) == 60
    imu_msgs = [
        (tag, v) for tag, v in result.esf_meas_messages if any(k in v for k in (16, 14))
    ]
    assert len(imu_msgs) == len(reference) == 58
    names = {16: "acc_x", 17: "acc_y", 18: "acc_z", 14: "gyro_x", 13: "gyro_y", 5: "gyro_z",
             12: "gyro_temp"}  # fmt: skip
    for (tag, values), ref in zip(imu_msgs, reference, strict=True):
        assert tag == ref["timeTag"]
        for kind, value in values.items():
            if kind in names:
                assert abs(value - ref[names[kind]]) <= (0.005 if kind == 12 else 1e-4) + 1e-9


def test_esf_meas_only_log_pairs_accel_and_gyro(tmp_path):
    """The NEO-M8U log without its ESF-RAW frames: the IMU comes from ESF-MEAS, whose
    accelerometer and gyro messages have different time tags (5 ms apart) and are paired."""
    from pyubx2 import UBXReader

    kept = bytearray()
    with (GPSD_DIR / "ublox-neo-m8u.log").open("rb") as stream:
        for raw, msg in UBXReader(stream, protfilter=2, quitonerror=0):
            if msg is not None and msg.identity != "ESF-RAW":
                kept += raw
    path = tmp_path / "meas_only.bin"
    path.write_bytes(bytes(kept))
    result = read_ubx(path)
    assert result.imu_source == "ESF-MEAS"
    accel_msgs = [(t, v) for t, v in result.esf_meas_messages if 16 in v]
    gyro_msgs = [(t, v) for t, v in result.esf_meas_messages if 14 in v]
    assert len(result.imu_tags) == len(accel_msgs) == len(gyro_msgs) == 29  # none invented
    for k, ((ta, a), (tg, g)) in enumerate(zip(accel_msgs, gyro_msgs, strict=True)):
        assert result.imu_tags[k] == (ta + tg) // 2
        np.testing.assert_allclose(result.imu_raw_accel[k], [a[16], a[17], a[18]])
        np.testing.assert_allclose(result.imu_raw_gyro_deg_s[k], [g[14], g[13], g[5]])
    assert any("paired by nearest time tag" in w for w in result.warnings)
    assert 9.0 < result.imu.rate_hz < 11.0


def test_no_fix_log_gives_a_clear_error_from_load_and_smooth():
    from fgins.cli import main
    from fgins.io.inputs import load_dataset

    path = GPSD_DIR / NO_FIX_LOG
    with pytest.raises(InputError, match="no fix"):
        load_dataset([str(path)], progress=False)
    assert main(["smooth", str(path), "-o", os.devnull + ".csv"]) == 2


def test_log_without_imu_says_what_to_give():
    from fgins.io.inputs import load_dataset

    with pytest.raises(InputError, match=r"no IMU in .*ublox-glo.log; give an imu.csv beside it"):
        load_dataset([str(GPSD_DIR / "ublox-glo.log")], progress=False)


def test_real_one_file_log_smooths_on_its_fixes(tmp_path):
    """fgins smooth ublox-neo-m8u.log: IMU and GNSS from the one file (3 fixes, 2.9 s at rest)."""
    from fgins.config import config_for_dataset
    from fgins.io.inputs import load_dataset
    from fgins.pipeline import run_method

    dataset = load_dataset([str(GPSD_DIR / "ublox-neo-m8u.log")], progress=False)
    trajectory = run_method(dataset, config_for_dataset(dataset), "batch", progress=False)
    assert trajectory.t[0] == dataset.imu.t[0] and trajectory.t[-1] == dataset.imu.t[-1]
    fixes = dataset.gnss_enu()
    for k, t in enumerate(dataset.gnss.t):
        i = int(np.argmin(np.abs(trajectory.t - t)))
        error = np.abs(trajectory.position[i] - fixes[k])
        # within the receiver's own 1-sigma accuracy (hAcc ~2.1 m, vAcc ~2.8 m)
        assert np.all(error <= dataset.gnss.std[k]), (error, dataset.gnss.std[k])
    assert np.all(np.isfinite(trajectory.position))
    speed = np.linalg.norm(trajectory.velocity, axis=1)
    assert speed.max() < 0.5  # the receiver was at rest (gSpeed 3 cm/s)


def test_every_log_inspects(capsys):
    from fgins.cli import main

    for path in LOGS:
        assert main(["inspect", str(path)]) == 0
        out = capsys.readouterr().out
        assert "u-blox UBX log" in out and "corrupt frames" in out
        if path.name == NO_FIX_LOG:
            assert "no fix" in out


def test_a_real_log_concatenated_with_itself_counts_its_repeated_epochs(tmp_path):
    """Outside tester F15: `cat ublox-zed-f9p-rtk.log ublox-zed-f9p-rtk.log` gave the same 10
    fixes without the count the README promises for repeated iTOWs."""
    path = GPSD_DIR / "ublox-zed-f9p-rtk.log"
    single = read_ubx(path)
    twice = tmp_path / "twice.ubx"
    twice.write_bytes(path.read_bytes() * 2)
    result = read_ubx(twice)
    assert len(result.gnss) == len(single.gnss) == 10
    np.testing.assert_array_equal(result.gnss.t, single.gnss.t)
    (message,) = [w for w in result.warnings if "identical to earlier ones" in w]
    assert message.startswith(f"{single.epochs} repeated navigation epoch(s) identical")
    assert not any("identical to earlier ones" in w for w in single.warnings)


def test_no_real_log_reports_identical_repeats():
    """The count is about copies: none of the 14 real logs (gpsd's) has one."""
    for path in LOGS:
        assert not any("identical to earlier ones" in w for w in read_ubx(path).warnings), path
