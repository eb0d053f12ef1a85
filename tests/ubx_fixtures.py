"""Small UBX logs for the tests, built with pyubx2's own message builder (UBXMessage).

pyubx2 lays out and scales the named NAV fields and frames every message (header, length,
checksum); ESF-RAW/ESF-MEAS have repeated 32-bit groups, which are packed here per the u-blox
layout and framed by UBXMessage(payload=...). Nothing here is written by fgins's reader.
Imported as ``fgins.tests.ubx_fixtures`` (the package maps onto the repository root).
"""

from __future__ import annotations

import calendar
import math
import struct
from collections.abc import Iterable

import numpy as np
from pyubx2 import GET, UBXMessage

GPS_EPOCH_POSIX = calendar.timegm((1980, 1, 6, 0, 0, 0))
LEAP_S = 18
RAW_TICK_S = 1.0 / 25600.0


def gps_week_itow(t_posix: float, leap: int = LEAP_S) -> tuple[int, int, int]:
    """(week, iTOW ms, fTOW ns) of a POSIX UTC time."""
    gps = t_posix - GPS_EPOCH_POSIX + leap
    week = int(gps // 604800)
    tow = gps - week * 604800
    itow = round(tow * 1000)
    ftow = round((tow * 1000 - itow) * 1e6)
    return week, itow, ftow


def _utc_fields(t_posix: float) -> dict[str, int]:
    second = math.floor(t_posix)
    nano = round((t_posix - second) * 1e9)
    if nano >= 500_000_000:  # u-blox keeps nano in [-5e8, 5e8]
        second, nano = second + 1, nano - 1_000_000_000
    tm = __import__("time").gmtime(second)
    return dict(year=tm.tm_year, month=tm.tm_mon, day=tm.tm_mday, hour=tm.tm_hour,
                min=tm.tm_min, nano=nano, _sec=tm.tm_sec)  # fmt: skip


def nav_pvt(
    t: float, lat: float, lon: float, height_m: float, vel_enu=(0.0, 0.0, 0.0), *,
    h_acc_m: float = 1.5, v_acc_m: float = 2.5, s_acc_m_s: float = 0.2, fix_type: int = 3,
    fix_ok: int = 1, carr_soln: int = 0, diff_soln: int = 0, num_sv: int = 12,
    pdop: float = 1.5, valid_date: int = 1, valid_time: int = 1, itow_t: float | None = None,
    fully_resolved: int = 1, gps_posix: float | None = None, leap: int = LEAP_S,
    inserted_second: bool = False,
) -> bytes:  # fmt: skip
    """``t`` POSIX UTC; with ``gps_posix`` (GPS time as POSIX seconds, no leap seconds) the
    iTOW is that time's and the UTC fields ``gps_posix - leap`` (``t`` unused), shown as
    23:59:60.x with ``inserted_second`` (``leap`` then the count after it), as a receiver
    shows the second a leap second inserts."""
    if gps_posix is None:
        utc = _utc_fields(t)
        _, itow, _ = gps_week_itow(t if itow_t is None else itow_t)
    else:
        itow = round(((gps_posix - GPS_EPOCH_POSIX) % 604800) * 1000)
        if inserted_second:
            whole = math.floor(gps_posix - leap)
            utc = _utc_fields(whole)  # 23:59:59, shown as its 60th second
            utc.update(_sec=60, nano=round((gps_posix - leap - whole) * 1e9))
        else:
            utc = _utc_fields(gps_posix - leap)
    second = utc.pop("_sec")
    ve, vn, vu = vel_enu
    return UBXMessage(
        "NAV", "NAV-PVT", GET, iTOW=itow, second=second, validDate=valid_date,
        validTime=valid_time, fullyResolved=fully_resolved, tAcc=20, fixType=fix_type, gnssFixOk=fix_ok,
        diffSoln=diff_soln, carrSoln=carr_soln, numSV=num_sv, lat=round(lat, 7),
        lon=round(lon, 7), height=round(height_m * 1000),
        hMSL=round(height_m * 1000) - 47000, hAcc=round(h_acc_m * 1000),
        vAcc=round(v_acc_m * 1000), velN=round(vn * 1000),
        velE=round(ve * 1000), velD=round(-vu * 1000),
        gSpeed=round(math.hypot(ve, vn) * 1000),
        headMot=round(math.degrees(math.atan2(ve, vn)) % 360.0, 5),
        sAcc=round(s_acc_m_s * 1000), pDOP=round(pdop, 2), **utc,
    ).serialize()  # fmt: skip


def nav_hpposllh(t: float, lat: float, lon: float, height_m: float, h_acc_m: float,
                 v_acc_m: float) -> bytes:  # fmt: skip
    _, itow, _ = gps_week_itow(t)

    def split(value: int, unit: int) -> tuple[int, int]:
        main = int(value / unit)  # toward zero; the high-precision part keeps the sign
        return main, value - main * unit

    lat_main, lat_hp = split(round(lat * 1e9), 100)
    lon_main, lon_hp = split(round(lon * 1e9), 100)
    h_main, h_hp = split(round(height_m * 1e4), 10)
    def nudge(count: int, unit: float) -> float:
        # pyubx2 truncates value / scale: move a quarter unit away from zero so that it lands
        # on the intended integer whatever the float rounding.
        return (count + math.copysign(0.25, count)) * unit if count else 0.0

    return UBXMessage(
        "NAV", "NAV-HPPOSLLH", GET, iTOW=itow, lat=nudge(lat_main, 1e-7),
        lon=nudge(lon_main, 1e-7), _HPlat=nudge(lat_hp, 1e-9), _HPlon=nudge(lon_hp, 1e-9),
        height=h_main, _HPheight=nudge(h_hp, 0.1), hMSL=h_main - 47000,
        hAcc=nudge(round(h_acc_m * 1e4), 0.1), vAcc=nudge(round(v_acc_m * 1e4), 0.1),
    ).serialize()  # fmt: skip


def nav_sol(t: float, ecef_m, vel_ecef_m_s=(0.0, 0.0, 0.0), *, gps_fix: int = 3, fix_ok: int = 1,
            p_acc_m: float = 3.0, s_acc_m_s: float = 0.3, num_sv: int = 8,
            leap: int = LEAP_S) -> bytes:  # fmt: skip
    week, itow, ftow = gps_week_itow(t, leap)
    x, y, z = (round(v * 100) for v in ecef_m)
    vx, vy, vz = (round(v * 100) for v in vel_ecef_m_s)
    return UBXMessage(
        "NAV", "NAV-SOL", GET, iTOW=itow, fTOW=ftow, week=week, gpsFix=gps_fix,
        gpsfixOK=fix_ok, wknSet=1, towSet=1, ecefX=x, ecefY=y, ecefZ=z,
        pAcc=round(p_acc_m * 100), ecefVX=vx, ecefVY=vy, ecefVZ=vz,
        sAcc=round(s_acc_m_s * 100), pDOP=2.0, numSV=num_sv,
    ).serialize()  # fmt: skip


def nav_timegps(t: float, leap: int = LEAP_S, leap_valid: int = 1) -> bytes:
    week, itow, ftow = gps_week_itow(t, leap)
    return UBXMessage(
        "NAV", "NAV-TIMEGPS", GET, iTOW=itow, fTOW=ftow, week=week, leapS=leap, towValid=1,
        weekValid=1, leapSValid=leap_valid, tAcc=20,
    ).serialize()  # fmt: skip


def nav_dop(t: float, hdop: float, vdop: float, pdop: float) -> bytes:
    _, itow, _ = gps_week_itow(t)
    return UBXMessage("NAV", "NAV-DOP", GET, iTOW=itow, gDOP=pdop + 0.5, pDOP=pdop,
                      tDOP=1.0, vDOP=vdop, hDOP=hdop, nDOP=hdop, eDOP=hdop).serialize()  # fmt: skip


def _group(kind: int, value: int) -> int:
    return (int(value) & 0xFFFFFF) | (kind << 24)


def esf_raw(samples: Iterable[tuple[int, dict[int, int]]]) -> bytes:
    """ESF-RAW from (sTag, {data type: raw integer value}) samples."""
    payload = struct.pack("<I", 0)
    for tag, values in samples:
        for kind, value in values.items():
            payload += struct.pack("<II", _group(kind, value), int(tag) & 0xFFFFFFFF)
    return UBXMessage("ESF", "ESF-RAW", GET, payload=payload).serialize()


def esf_meas(time_tag_ms: int, values: dict[int, int]) -> bytes:
    """ESF-MEAS with one time tag and {data type: raw integer value}."""
    flags = len(values) << 11
    payload = struct.pack("<IHH", int(time_tag_ms) & 0xFFFFFFFF, flags, 0)
    for kind, value in values.items():
        payload += struct.pack("<I", _group(kind, value))
    return UBXMessage("ESF", "ESF-MEAS", GET, payload=payload).serialize()


def imu_raw_values(gyro_rad_s: np.ndarray, accel: np.ndarray, temp_c: float = 25.0) -> dict:
    """ESF data types -> raw integers (gyro 2^-12 deg/s, accel 2^-10 m/s^2, temp 0.01 C)."""
    g = np.round(np.degrees(gyro_rad_s) / 2.0**-12).astype(int)
    a = np.round(np.asarray(accel) / 2.0**-10).astype(int)
    return {14: g[0], 13: g[1], 5: g[2], 16: a[0], 17: a[1], 18: a[2],
            12: round(temp_c * 100)}  # fmt: skip


def quantised_imu(gyro_rad_s: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What ESF-RAW carries of these samples, back in rad/s and m/s^2."""
    g = np.round(np.degrees(gyro_rad_s) / 2.0**-12) * 2.0**-12
    a = np.round(np.asarray(accel) / 2.0**-10) * 2.0**-10
    return np.radians(g), a
