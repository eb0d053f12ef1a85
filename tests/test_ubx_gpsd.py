"""The UBX reader against gpsd's reference decodings of real u-blox logs.

The 14 logs of ``../shared/data/ubx/gpsd`` and 10 more from the same corpus shipped in
``tests/data/gpsd_extra/ubx`` (gpsd's JSON reduced to the TPV and IMU fields used here; see its
README). Each ``X.log.chk`` holds gpsd's JSON reports for ``X.log``. Every fix gpsd reports
(TPV, mode >= 2) must be found by :func:`read_ubx` with the same time (1 ms),
latitude/longitude (1e-7 deg) and ellipsoidal height (1 mm); every IMU sample gpsd decodes
from UBX-ESF-RAW must be found with the same values (1e-4 m/s^2, 1e-4 deg/s, 0.01 deg C), in
order; ESF-MEAS too. A log gpsd finds no fix in must be a clear "no fix" error. The
gpsd-specific differences are classes listed in ``_gpsd_specific``, each with its reason and
its own check, and pinned per log in ``EXPECTED_EXCEPTIONS``; nothing is loosened globally.
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
SHARED_LOGS = sorted(GPSD_DIR.glob("*.log")) if GPSD_DIR.is_dir() else []
EXTRA_DIR = Path(__file__).resolve().parent / "data" / "gpsd_extra" / "ubx"
EXTRA_LOGS = sorted(EXTRA_DIR.glob("*.log"))
LOGS = SHARED_LOGS + EXTRA_LOGS if SHARED_LOGS else []
pytestmark = pytest.mark.skipif(not LOGS, reason="../shared/data/ubx/gpsd not present")

TIME_TOL_S = 1e-3
LATLON_TOL_DEG = 1e-7
HEIGHT_TOL_M = 1e-3
ACC_TOL = 1e-4
GYRO_TOL = 1e-4
NO_FIX_LOG = "ublox-zoe-m8b-logbatch.log"
# GPS - UTC in seconds from each date on (IERS Bulletin C); gpsd's compiled-in value is 18.
LEAP_SECONDS = ((2006, 1, 14), (2009, 1, 15), (2012, 7, 16), (2015, 7, 17), (2017, 1, 18))
GPSD_BUILT_IN_LEAP_S = 18
ECEF_ROUNDING_M = 0.03  # NAV-SOL's 1 cm ECEF against NAV-PVT's 1e-7 deg (1.1 cm) and 1 mm
HNR_TRACK_TOL_M = 5.0  # an HNR-PVT fix against the NAV fixes interpolated to its time


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


def _leap_at(t: float) -> int:
    leap = 0
    for year, month, value in LEAP_SECONDS:
        if t >= calendar.timegm((year, month, 1, 0, 0, 0)):
            leap = value
    return leap


def _gpsd_specific(path: Path, fix: dict, result) -> str | None:
    """Why gpsd's fix legitimately differs from the UBX decoding, or None. Each class is
    checked, not assumed: the fix must be found where the class says it is."""
    t = _iso(fix["time"])
    gnss = result.gnss
    early = GPSD_BUILT_IN_LEAP_S - _leap_at(t)
    if early and _match(gnss, t + early, fix["lat"], fix["lon"], fix.get("altHAE")):
        # gpsd's report came before any valid leap-second count in the log (ANTARIS 4,
        # 2007-2009), so gpsd used its compiled-in 18; the receiver's NAV-TIMEUTC (validUTC)
        # puts the epoch ``early`` seconds later, where the reader has it, same position.
        return f"gpsd used {GPSD_BUILT_IN_LEAP_S} leap seconds where {_leap_at(t)} applied"
    close = np.flatnonzero(np.abs(gnss.t - t) <= TIME_TOL_S)
    nmea = _nmea_of(path)
    if nmea is not None and close.size and _match_tod(nmea, t % 86400.0, fix):
        # gpsd reported the receiver's NMEA GGA of that instant (lat/lon to 1e-5 arc-minute,
        # height to 0.1 m) rather than its NAV-PVT. The reader prefers NAV-PVT (full precision,
        # with hAcc/vAcc); it must agree with the NMEA values within their rounding.
        i = close[0]
        rounding_deg = 0.5e-5 / 60.0
        if (
            abs(gnss.lla[i, 0] - fix["lat"]) <= rounding_deg + LATLON_TOL_DEG
            and abs(gnss.lla[i, 1] - fix["lon"]) <= rounding_deg + LATLON_TOL_DEG
            and abs(gnss.lla[i, 2] - fix["altHAE"]) <= 0.05 + 0.05 + HEIGHT_TOL_M
        ):
            return "gpsd reported the NMEA GGA fix (rounded) of a NAV-PVT epoch"
    if result.counts.get("NAV-SOL") and close.size:
        # gpsd reported NAV-SOL's ECEF position (1 cm) of an epoch whose NAV-PVT the reader
        # prefers (lat/lon 1e-7 deg, height 1 mm, hAcc/vAcc): the two agree to their rounding.
        i = close[0]
        north = np.radians(gnss.lla[i, 0] - fix["lat"]) * 6.371e6
        east = np.radians(gnss.lla[i, 1] - fix["lon"]) * 6.371e6 * np.cos(np.radians(fix["lat"]))
        up = gnss.lla[i, 2] - fix.get("altHAE", gnss.lla[i, 2])
        if np.hypot(north, east) <= ECEF_ROUNDING_M and abs(up) <= ECEF_ROUNDING_M:
            return "gpsd reported NAV-SOL's ECEF position (1 cm) of a NAV-PVT epoch"
    if result.counts.get("HNR-PVT") and gnss.t[0] - 1 <= t <= gnss.t[-1] + 1:
        # gpsd reported the receiver's high-rate fused HNR-PVT (also at the NAV epochs, with
        # its own position), which the reader does not use as fixes by design (see
        # fgins.io.ubx): it must lie on the NAV fixes' track.
        lat = np.interp(t, gnss.t, gnss.lla[:, 0])
        lon = np.interp(t, gnss.t, gnss.lla[:, 1])
        north = np.radians(lat - fix["lat"]) * 6.371e6
        east = np.radians(lon - fix["lon"]) * 6.371e6 * np.cos(np.radians(fix["lat"]))
        if np.hypot(north, east) <= HNR_TRACK_TOL_M:
            return "gpsd reported an HNR-PVT fix (not used as a fix by design)"
    return None


@functools.lru_cache(maxsize=4)
def _nmea_of(path: Path):
    """The NMEA fixes of a mixed UBX + NMEA stream (None when it has none)."""
    try:
        return read_nmea(path).gnss
    except InputError:
        return None


def _match_tod(nmea, tod: float, fix: dict) -> bool:
    near = np.flatnonzero(np.abs((nmea.t % 86400.0) - tod) <= TIME_TOL_S)
    return any(
        abs(nmea.lla[i, 0] - fix["lat"]) <= LATLON_TOL_DEG + 1e-12
        and abs(nmea.lla[i, 1] - fix["lon"]) <= LATLON_TOL_DEG + 1e-12
        and abs(nmea.lla[i, 2] - fix["altHAE"]) <= HEIGHT_TOL_M
        for i in near
    )


EXPECTED_EXCEPTIONS = {
    "ublox-aek-4t.log": 1, "ublox-zed-f9r.log": 54, "ublox-lea-4t.log": 1,
    "ublox-zed-f9t-ubx_nmea_l5.log": 18, "ublox8-uniqid-monhw.log": 7, "ublox-neo-m8l.log": 190,
    "ublox-neo-m8u-hnr.log": 12,
}  # fmt: skip


@pytest.mark.parametrize("path", LOGS, ids=[p.name for p in LOGS])
def test_every_gpsd_fix_is_found(path: Path):
    result = read_ubx(path)  # never raises on these logs
    fixes = _gpsd_fixes(path)
    if not fixes:  # gpsd found none: a clear error, not an empty or made-up track
        assert result.gnss is None
        with pytest.raises(InputError, match="no fix"):
            require_fix(result)
        return
    missing, explained = [], []
    for fix in fixes:
        if _match(result.gnss, _iso(fix["time"]), fix["lat"], fix["lon"], fix.get("altHAE")):
            continue
        reason = _gpsd_specific(path, fix, result)
        (explained if reason else missing).append((fix["time"], reason))
    assert not missing, f"{len(missing)} of {len(fixes)} gpsd fixes not found: {missing[:5]}"
    assert len(explained) == EXPECTED_EXCEPTIONS.get(path.name, 0), explained[:3]
    # Sigmas come from the receiver: finite on every UBX-derived fix (an epoch only an NMEA
    # sentence gives has none: it is weighted by its HDOP like any NMEA fix).
    assert np.sum(~np.isfinite(result.gnss.std[:, 0])) <= result.nmea_fixes_added


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


IMU_NAMES = {16: "acc_x", 17: "acc_y", 18: "acc_z", 14: "gyro_x", 13: "gyro_y", 5: "gyro_z",
             12: "gyro_temp"}  # fmt: skip
IMU_LOGS = [p for p in LOGS if _reports(p, "IMU")]


@pytest.mark.parametrize("path", IMU_LOGS, ids=[p.name for p in IMU_LOGS])
def test_every_gpsd_esf_meas_sample_is_decoded_alike(path: Path):
    """Every ESF-MEAS message gpsd decodes (also the NEO-M8L's ~11 Hz stream, accelerometer
    and gyro in separate messages) is in the reader's messages with the same values; the
    real logs' IMU time maps raise no clock warning."""
    result = read_ubx(path)
    ours: dict[int, list[dict[int, float]]] = {}
    for tag, values in result.esf_meas_messages:
        ours.setdefault(tag, []).append(values)
    reports = [r for r in _reports(path, "IMU") if r["msg"] == "UBX-ESF-MEAS"]
    assert reports
    for ref in reports:
        kinds = {kind: name for kind, name in IMU_NAMES.items() if name in ref}
        assert any(
            all(
                kind in values
                and abs(values[kind] - ref[name]) <= (0.005 if kind == 12 else 1e-4) + 1e-9
                for kind, name in kinds.items()
            )
            for values in ours.get(ref["timeTag"], [])
        ), ref
    assert result.imu is not None and len(result.imu) >= 2
    assert not any("clock may have jumped" in w for w in result.warnings), result.warnings


def test_a_log_without_a_navigation_solution_says_what_it_holds():
    """Raw subframes only (a timing receiver's RXM-SFRBX), or the positions of a flash-log
    retrieval: a "no fix" error that names what the log holds instead and what to log."""
    for name, holds in (
        ("ublox-ned-m8t-sbfrx3.log", "RXM-SFRBX x165 (raw navigation data subframes)"),
        ("ublox-zoe-m8b-logretrieve.log", "LOG-RETRIEVEPOS x34 (positions retrieved"),
    ):
        with pytest.raises(InputError, match="no fix: none of its") as error:
            require_fix(read_ubx(EXTRA_DIR / name))
        assert holds in str(error.value) and "log NAV-PVT" in str(error.value)


def test_hnr_pvt_is_counted_and_said_not_used():
    result = read_ubx(EXTRA_DIR / "ublox-neo-m8l.log")
    assert result.counts["HNR-PVT"] == 189 and len(result.gnss) == result.counts["NAV-PVT"]
    assert any(w.startswith("189 HNR-PVT message(s) not used as fixes") for w in result.warnings)


def test_a_dop_beside_a_position_dop_not_available_is_none_either():
    """ublox-glo's NAV-DOP: pDOP, hDOP (and g/t) 99.99, the receiver's "not available", and
    vDOP 1.00 beside them (pyubx2 reads the same). The 99.99s were dropped and the 1.00 kept:
    a median VDOP of 1.0 on a fix without geometry (outside tester). Where PDOP is not
    available no DOP of that fix is kept; where all are given they stay."""
    from fgins.io.gnss_checks import check_gnss_records

    gnss = read_ubx(GPSD_DIR / "ublox-glo.log").gnss
    raw_pdop, raw_vdop = gnss.pdop.copy(), gnss.vdop.copy()
    placeholder = np.isfinite(raw_pdop) & (raw_pdop >= 99.0)
    assert placeholder.any() and np.isfinite(raw_vdop[placeholder]).any()
    checked = check_gnss_records(gnss, [])
    assert not np.isfinite(checked.vdop[placeholder]).any()
    assert not np.isfinite(checked.hdop[placeholder]).any()
    given = np.isfinite(raw_pdop) & ~placeholder & np.isfinite(raw_vdop) & (raw_vdop > 0) & (raw_vdop < 99)
    assert given.any()
    np.testing.assert_array_equal(checked.vdop[given], raw_vdop[given])
