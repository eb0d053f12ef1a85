"""u-blox UBX reader: one binary log -> GNSS fixes, the receiver's own IMU and wheel speed.

Framing
-------
The stream is split here, by content, into UBX frames (``0xB5 0x62``, class, id, length,
payload, 8-bit Fletcher checksum), NMEA sentences (``$``...LF), RTCM 3 frames (``0xD3``, CRC-24Q)
and noise. pyubx2's own stream reader is not used for the framing: on a corrupt length it reads
past the following good frames, and a non-ASCII byte after ``$`` escapes it as a
``UnicodeDecodeError``. Frames that fail their checksum or are cut by the end of the file are
counted (the scan resumes two bytes after their sync, so the next good frame is never lost);
only frames that pass are decoded, by :meth:`pyubx2.UBXReader.parse`. ``#`` comment lines at the
start (gpsd's log headers) are skipped; NMEA sentences go to :mod:`fgins.io.nmea` unchanged;
RTCM frames are skipped and counted.

GNSS epochs
-----------
Navigation messages are grouped by their GPS time of week ``iTOW`` (a new group when iTOW goes
back by more than half a week). Per epoch the position comes from, best first, NAV-HPPOSLLH,
NAV-PVT, NAV-PVAT, NAV-POSLLH, NAV-SOL (ECEF), NAV-POSECEF; velocity from NAV-PVT/PVAT,
NAV-VELNED, NAV-SOL, NAV-VELECEF (ENU = east, north, -down); DOPs from NAV-DOP; fix type,
carrier solution and satellites from NAV-PVT/PVAT, NAV-SOL or NAV-STATUS. HNR-PVT (the
high-rate output of a sensor-fusion receiver: its IMU is already in it, and its errors are
correlated from one message to the next) is counted, said, and not used as fixes.

Time is POSIX UTC seconds on one clock for the whole log: GPS time (week + iTOW (+fTOW) from
NAV-SOL/NAV-TIMEGPS, or iTOW with the week of the epoch's UTC) less one leap count, that of the
first epoch whose UTC the receiver had fully resolved (else the first valid NAV-TIMEGPS leap
count, else the built-in table, counted); where NAV-PVT/PVAT (or NAV-TIMEUTC) date and time are
flagged valid their sub-second is kept. A leap second inside the log, or UTC not yet resolved
after a cold start (1 s off), is a whole-second step of the receiver's UTC, not of the log:
said, not followed. Epochs without a valid time or without a position fix are counted, not
used.

Sigmas are the receiver's own: std east = std north = hAcc (the horizontal accuracy, used per
axis: conservative by up to sqrt(2), as the HDOP convention of :mod:`fgins.factors.gnss`),
std up = vAcc; NAV-SOL/NAV-POSECEF give one 3-D pAcc, used on all three axes. A 2-D fix holds the
height, so its vertical sigma is never below ``TWO_D_MIN_VERTICAL_SIGMA_M``. velocity_std = sAcc
on each axis. Fix quality in the NMEA GGA codes: no fix / gnssFixOK clear / time only -> not a
fix; dead reckoning only -> 6; carrier solution fixed -> 4, float -> 5; differential -> 2; else 1.

IMU (ESF-RAW, ESF-MEAS)
-----------------------
Data types (u-blox ESF): 14/13/5 gyro x/y/z (deg/s * 2^-12 -> rad/s), 16/17/18 accelerometer x/y/z
(m/s^2 * 2^-10), 12 gyro temperature (deg C * 0.01), 6-10 wheel ticks (23 bits + direction
bit), 11 speed (m/s * 1e-3). Axes are the receiver's IMU axes as it reports them (the module's
sensor frame, not rotated into the vehicle frame); fgins uses them as logged, like any IMU, and
the IMU-to-vehicle rotation comes from the configuration. On the gpsd NEO-M8U log the z
accelerometer reads +9.8 m/s^2 at rest: z points up out of the module.

One IMU sample is one sensor time tag carrying all six of gyro x/y/z and accel x/y/z; values
sharing a tag (in one message or several) are merged. ESF-RAW is preferred (the raw high-rate
stream) over ESF-MEAS. Either may send accelerometer and gyro with different time tags (ESF-MEAS
in separate messages, 5 ms apart on the NEO-M8U): each accelerometer-only tag is paired with the
gyro-only tag nearest to it, once their median offset is taken out, when both are each other's
nearest and at most half the median tag interval apart; the pair gets the mean of the two tags. Unpaired or partial tags are dropped and
counted; nothing is interpolated, so no sample is invented.

Sensor time tags (ESF-RAW sTag: 24-bit counter wrapping at 2^24, nominally 1/25600 s;
ESF-MEAS timeTag: 32-bit ms) are unwrapped and mapped linearly onto the GNSS time base with
*anchors*: for each navigation epoch, the last IMU tag the receiver sent before that epoch's
first navigation message is taken to be the epoch's own time (the receiver emits the IMU samples
up to an epoch before the solution of that epoch). With at least ``MIN_FIT_ANCHORS`` anchors
over ``MIN_FIT_SPAN_S`` the scale and offset are fitted by least squares, else the nominal
scale is kept and the offset is the median. The anchors' residuals are the check of the mapping
against the fixes: their spread is reported (one NAV output latency, tens of ms, is the
uncertainty of this mapping on real receivers; an anchor is quantised to one sample interval),
and a spread above ``ANCHOR_SPREAD_WARN_S`` and above two sample intervals (a NEO-M8L's ~11 Hz
ESF-MEAS: 155 ms is normal) or a fitted scale far from nominal is reported as a warning. Tags that go back by more than
``RESTART_BACKWARDS_S`` (a receiver restart, not a wrap) leave the IMU unused, with a warning:
sorting would interleave two runs of the sensor clock.
"""

from __future__ import annotations

import calendar
import math
import re
import struct
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from itertools import accumulate
from pathlib import Path

import numpy as np

from fgins.datatypes import (
    IMU_TIMES_FROM_FIXES_KEY,
    Dataset,
    GnssData,
    ImuData,
    InputError,
    OdometerData,
)

UBX_SYNC = b"\xb5\x62"
GPS_EPOCH_POSIX = 315964800  # 1980-01-06T00:00:00Z
WEEK_S = 604800
TWO_D_MIN_VERTICAL_SIGMA_M = 100.0
# A repeated epoch (same iTOW) whose position lies further than this from the kept one is
# reported with its distance (another session or receiver, not a copy of one solution).
REPEAT_SAME_POSITION_M = 1.0
ESF_RAW_TICK_S = 1.0 / 25600.0
ESF_MEAS_TICK_S = 1e-3
MIN_FIT_ANCHORS = 5
MIN_FIT_SPAN_S = 20.0
ANCHOR_SPREAD_WARN_S = 0.15
SCALE_WARN = 0.01  # fitted tick scale more than 1 % from nominal
RESTART_BACKWARDS_S = 1.0  # sensor tags going back more than this (not a wrap): a restart
# Consecutive anchors (IMU tag against GNSS epoch) whose residuals from the fitted time map
# step by more than this: the sensor clock jumped (back or forward) against GNSS time. One
# map over both sides is wrong everywhere (a 1 s jump back: the scale fitted 2.5 % off, the
# drive 1.3 m off at 4.6 sigma, heading 1.1 deg; 3 s forward: 7 % and 3 deg; outside tester).
CLOCK_JUMP_S = 0.5
HEAD_BYTES = 65536

# GPS - UTC leap seconds from these UTC dates on (IERS bulletins; none announced after 2017).
_LEAP_TABLE = (
    (1981, 7, 1, 1), (1982, 7, 1, 2), (1983, 7, 1, 3), (1985, 7, 1, 4), (1988, 1, 1, 5),
    (1990, 1, 1, 6), (1991, 1, 1, 7), (1992, 7, 1, 8), (1993, 7, 1, 9), (1994, 7, 1, 10),
    (1996, 1, 1, 11), (1997, 7, 1, 12), (1999, 1, 1, 13), (2006, 1, 1, 14), (2009, 1, 1, 15),
    (2012, 7, 1, 16), (2015, 7, 1, 17), (2017, 1, 1, 18),
)  # fmt: skip

GYRO_TYPES = (14, 13, 5)  # x, y, z
ACCEL_TYPES = (16, 17, 18)
TEMP_TYPE = 12
TICK_TYPES = (6, 7, 8, 9, 10)
SPEED_TYPE = 11
GYRO_SCALE = 2.0**-12  # deg/s per LSB
ACCEL_SCALE = 2.0**-10  # m/s^2 per LSB
_SCALE = {14: GYRO_SCALE, 13: GYRO_SCALE, 5: GYRO_SCALE, 16: ACCEL_SCALE, 17: ACCEL_SCALE,
          18: ACCEL_SCALE, TEMP_TYPE: 1e-2, SPEED_TYPE: 1e-3}  # fmt: skip

_NAV_CLASS = 0x01
_ESF_CLASS = 0x10
# Messages decoded by pyubx2 (the rest are only counted, by name).
_DECODED = {
    "NAV-PVT", "NAV-HPPOSLLH", "NAV-POSLLH", "NAV-SOL", "NAV-TIMEGPS", "NAV-TIMEUTC",
    "NAV-PVAT", "NAV-VELNED", "NAV-VELECEF", "NAV-DOP", "NAV-STATUS", "NAV-POSECEF",
    "ESF-RAW", "ESF-MEAS",
}  # fmt: skip
_NMEA_START = re.compile(rb"\$[A-Z][A-Z0-9]{2,11},")
_CANDIDATE = re.compile(rb"\xb5\x62|\$|\xd3")


def _leap_from_table(gps_seconds: float) -> int:
    leap = 0
    for year, month, day, value in _LEAP_TABLE:
        if gps_seconds - value >= calendar.timegm((year, month, day, 0, 0, 0)) - GPS_EPOCH_POSIX:
            leap = value
    return leap


def _fletcher_ok(frame: bytes) -> bool:
    """8-bit Fletcher checksum over class, id, length and payload (the last two bytes)."""
    body = frame[2:-2]
    # ck_a is the running sum, ck_b the sum of the running sums (both C loops here).
    return (sum(body) & 0xFF) == frame[-2] and (sum(accumulate(body)) & 0xFF) == frame[-1]


def _crc24q_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= 0x1864CFB
        table.append(crc & 0xFFFFFF)
    return table


_CRC24Q = _crc24q_table()


def _crc24q(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q[(crc >> 16) ^ byte]
    return crc


def _skip_comment_header(data: bytes) -> int:
    """Offset after the leading '#' comment lines."""
    pos = 0
    while pos < len(data) and data[pos : pos + 1] == b"#":
        end = data.find(b"\n", pos)
        if end < 0:
            return len(data)
        pos = end + 1
    return pos


def looks_like_ubx(path: str | Path) -> bool:
    """True when the file's first 64 KiB hold at least one UBX frame with a valid checksum."""
    try:
        with Path(path).open("rb") as handle:
            head = handle.read(HEAD_BYTES)
    except OSError:
        return False
    pos = head.find(UBX_SYNC)
    while 0 <= pos <= len(head) - 8:
        length = head[pos + 4] | (head[pos + 5] << 8)
        end = pos + 8 + length
        if end <= len(head) and _fletcher_ok(head[pos:end]):
            return True
        pos = head.find(UBX_SYNC, pos + 2)
    return False


# ----------------------------------------------------------------------------------------------
# Per-epoch collection


class _Epoch:
    """What the navigation messages of one iTOW said (units as the messages give them)."""

    def __init__(self, itow: int, order: int) -> None:
        self.itow = itow
        self.order = order  # stream index of its first navigation message
        self.msgs: dict[str, object] = {}
        # Messages of a type the epoch already had, with another payload: the same iTOW
        # again (a receiver restart, two logs concatenated, a second receiver). The first of
        # each type is used; these are counted (see _repeat_warning), never merged.
        self.repeats: dict[str, object] = {}
        # Byte-identical copies of messages the epoch already had (a log concatenated with
        # itself, a replayed stretch): nothing is lost by dropping them, but they are counted.
        self.identical_repeats = 0


@dataclass
class TimeMap:
    """Linear map of one sensor time-tag stream onto the GNSS time base: t = offset + scale*tag.

    ``residuals`` are the anchors' misfits (s); ``fitted`` says whether scale was estimated.
    """

    stream: str
    scale: float
    offset: float
    nominal_scale: float
    anchors: int
    fitted: bool
    residuals: np.ndarray
    # The anchors' GNSS time minus their tag at the nominal scale (s): steady but for the
    # sensor clock's drift; a step in it is the clock jumping.
    nominal_lag: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gnss_t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the anchors' GNSS times

    @property
    def spread_s(self) -> float:
        return float(np.ptp(self.residuals)) if self.residuals.size else math.nan

    def describe(self) -> str:
        how = "scale fitted" if self.fitted else "nominal scale"
        ratio = self.scale / self.nominal_scale
        spread = f"{1e3 * self.spread_s:.1f} ms" if self.residuals.size > 1 else "n/a"
        return (
            f"{self.stream} time tags -> GNSS time: {self.anchors} anchors, {how} "
            f"({ratio:.6f} x nominal), anchor residual spread {spread}"
        )


@dataclass
class UbxResult:
    """Everything :func:`read_ubx` found in one log.

    ``gnss`` is None when the log holds no usable fix; ``imu`` None without a complete IMU
    stream. ``counts`` maps message names (UBX "NAV-PVT", NMEA "NMEA-GGA", "RTCM3") to counts.
    ``imu_tags`` are the raw (unwrapped) sensor time tags of the IMU rows, ``imu_temp`` the gyro
    temperature per row (deg C, NaN when absent), ``imu_source`` "ESF-RAW" or "ESF-MEAS".
    """

    path: Path
    gnss: GnssData | None
    imu: ImuData | None
    odometer: OdometerData | None
    counts: dict[str, int]
    warnings: list[str]
    corrupt_frames: int = 0
    cut_frames: int = 0
    noise_bytes: int = 0
    undecodable: int = 0
    rtcm_frames: int = 0
    epochs: int = 0
    epochs_without_fix: int = 0
    epochs_without_time: int = 0
    fix_histogram: dict[int, int] = field(default_factory=dict)
    nmea_fixes_added: int = 0
    imu_source: str = ""
    imu_tags: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu_temp: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu_raw_gyro_deg_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    imu_raw_accel: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    time_maps: list[TimeMap] = field(default_factory=list)
    wheel_ticks: int = 0
    esf_meas_messages: list[tuple[int, dict[int, float]]] = field(default_factory=list)
    first_time: float = math.nan
    # The first timed navigation epoch, with a fix or not (the t0 of outage windows).
    first_epoch_time: float = math.nan
    last_time: float = math.nan


class _Scanner:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.counts: Counter[str] = Counter()
        self.corrupt = 0
        self.cut = 0
        self.noise = 0
        self.undecodable = 0
        self.rtcm = 0
        self.nmea_lines: list[str] = []
        self.epochs: list[_Epoch] = []
        self._by_key: dict[tuple[int, int], _Epoch] = {}
        self._week_wraps = 0
        self._last_itow: int | None = None
        self.index = 0  # running message index (all protocols)
        self.esf_raw: list[tuple[int, bytes]] = []  # (stream index, data/sTag groups)
        self.esf_meas: list[tuple[int, int, list[tuple[int, int]]]] = []
        self.valid_leaps: list[int] = []

    # -- framing ---------------------------------------------------------------------------
    def scan(self, data: bytes) -> None:
        pos = _skip_comment_header(data)
        size = len(data)
        while pos < size:
            match = _CANDIDATE.search(data, pos)
            if match is None:
                self._noise(data[pos:])
                break
            start = match.start()
            if start > pos:
                self._noise(data[pos:start])
            pos = start
            lead = data[pos]
            if lead == 0xB5:
                pos = self._ubx(data, pos)
            elif lead == 0x24:
                pos = self._nmea(data, pos)
            else:
                pos = self._rtcm(data, pos)

    def _noise(self, chunk: bytes) -> None:
        # Line ends and blanks between NMEA sentences are not noise.
        self.noise += len(chunk.strip(b"\r\n \t"))

    def _ubx(self, data: bytes, pos: int) -> int:
        if pos + 8 > len(data):
            self.cut += 1
            return len(data)
        length = data[pos + 4] | (data[pos + 5] << 8)
        end = pos + 8 + length
        if end > len(data):
            self.cut += 1
            return pos + 2
        frame = data[pos:end]
        if not _fletcher_ok(frame):
            self.corrupt += 1
            return pos + 2
        self._decode(frame)
        self.index += 1
        return end

    def _nmea(self, data: bytes, pos: int) -> int:
        if not _NMEA_START.match(data, pos):
            self.noise += 1
            return pos + 1
        end = data.find(b"\n", pos, pos + 200)
        stop = end if end >= 0 else min(len(data), pos + 200)
        # A sentence never holds a UBX sync or a second '$': stop there (a cut sentence).
        for marker in (UBX_SYNC, b"$"):
            cut = data.find(marker, pos + 1, stop)
            if cut >= 0:
                stop = cut
        self.nmea_lines.append(data[pos:stop].decode("latin-1"))
        self.index += 1
        return stop + 1 if (end >= 0 and stop == end) else stop

    def _rtcm(self, data: bytes, pos: int) -> int:
        if pos + 6 > len(data) or data[pos + 1] & 0xFC:
            self.noise += 1
            return pos + 1
        length = ((data[pos + 1] & 0x03) << 8) | data[pos + 2]
        end = pos + 6 + length
        if end > len(data) or _crc24q(data[pos : end - 3]) != int.from_bytes(
            data[end - 3 : end], "big"
        ):
            self.noise += 1
            return pos + 1
        self.rtcm += 1
        self.counts["RTCM3"] += 1
        self.index += 1
        return end

    # -- decoding --------------------------------------------------------------------------
    def _decode(self, frame: bytes) -> None:
        msgids, reader = _pyubx2()
        name = msgids.get(frame[2:4]) or f"UBX-{frame[2]:02X}-{frame[3]:02X}"
        self.counts[name] += 1
        if name == "ESF-RAW":
            self._esf_raw(frame)
            return
        if name == "ESF-MEAS":
            self._esf_meas(frame)
            return
        if name not in _DECODED:
            return
        try:
            msg = reader.parse(frame, validate=1, msgmode=0, parsebitfield=1)
        except Exception:  # pyubx2 raises several types for a payload it cannot lay out
            self.undecodable += 1
            return
        self._nav(name, msg)

    def _nav(self, name: str, msg: object) -> None:
        itow = getattr(msg, "iTOW", None)
        if not isinstance(itow, int):
            self.undecodable += 1
            return
        if name == "NAV-TIMEGPS" and getattr(msg, "leapSValid", 0):
            self.valid_leaps.append(int(msg.leapS))
        if self._last_itow is not None and itow < self._last_itow - WEEK_S * 500:
            self._week_wraps += 1
        self._last_itow = itow
        key = (self._week_wraps, itow)
        epoch = self._by_key.get(key)
        if epoch is None:
            epoch = self._by_key[key] = _Epoch(itow, self.index)
            self.epochs.append(epoch)
        first = epoch.msgs.setdefault(name, msg)
        if first is not msg:
            if getattr(first, "payload", None) != getattr(msg, "payload", 0):
                epoch.repeats.setdefault(name, msg)
            else:
                epoch.identical_repeats += 1  # an identical copy loses nothing: counted

    # The ESF messages are the high-rate stream (one a sample or ten samples a message): their
    # fixed u-blox layout is decoded here, vectorised later, because pyubx2 takes about 1 ms a
    # message (an hour at 100 Hz would take minutes). The gpsd test checks these decodings
    # against gpsd's, value by value, and the builder-made fixtures against pyubx2's layout.
    def _esf_raw(self, frame: bytes) -> None:
        # payload: reserved U4, then N x (data X4: bits 0-23 value, 24-29 type; sTag U4)
        length = len(frame) - 8
        if length < 4 or (length - 4) % 8:
            self.undecodable += 1
            return
        if length > 4:
            self.esf_raw.append((self.index, frame[10 : 6 + length]))

    def _esf_meas(self, frame: bytes) -> None:
        # payload: timeTag U4, flags X2 (bit 3 calibTtagValid, bits 11-15 numMeas), id U2,
        # numMeas x data X4, then calibTtag U4 when flagged
        length = len(frame) - 8
        if length < 8:
            self.undecodable += 1
            return
        tag, flags = struct.unpack_from("<IH", frame, 6)
        count = flags >> 11
        expected = 8 + 4 * count + (4 if flags & 0x08 else 0)
        if length not in (expected, 8 + 4 * count) or count == 0:
            self.undecodable += 1
            return
        words = np.frombuffer(frame, dtype="<u4", count=count, offset=14).astype(np.int64)
        kinds = (words >> 24) & 0x3F
        values = _signed24(words & 0xFFFFFF)
        values = np.where(np.isin(kinds, TICK_TYPES), words & 0xFFFFFF, values)
        self.esf_meas.append((self.index, int(tag), list(zip(kinds.tolist(), values.tolist(),
                                                             strict=True))))  # fmt: skip


def _signed24(raw: np.ndarray) -> np.ndarray:
    return ((raw & 0xFFFFFF) ^ 0x800000) - 0x800000


_PYUBX2: tuple | None = None


def _pyubx2() -> tuple:
    """pyubx2's message-id table and reader, imported once, on first use."""
    global _PYUBX2
    if _PYUBX2 is None:
        from pyubx2 import UBX_MSGIDS, UBXReader

        _PYUBX2 = (UBX_MSGIDS, UBXReader)
    return _PYUBX2


# ----------------------------------------------------------------------------------------------
# GNSS epochs -> GnssData


def _f(msg: object, name: str, scale: float = 1.0) -> float:
    value = getattr(msg, name, None)
    if value is None:
        return math.nan
    try:
        return float(value) * scale
    except (TypeError, ValueError):
        return math.nan


def _utc_from_fields(msg: object, second_name: str) -> float | None:
    try:
        year, month, day = int(msg.year), int(msg.month), int(msg.day)
        hour, minute = int(msg.hour), int(msg.min)
        second = int(getattr(msg, second_name))
        nano = int(msg.nano)
    except (AttributeError, TypeError, ValueError):
        return None
    if not (1980 <= year <= 2200 and 1 <= month <= 12 and 1 <= day <= 31):
        return None
    if hour > 23 or minute > 59 or second > 60:
        return None
    return calendar.timegm((year, month, day, hour, minute, 0)) + second + nano * 1e-9


def _ecef_to_enu_velocity(v: np.ndarray, lat_deg: float, lon_deg: float) -> np.ndarray:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    east = -sl * v[0] + cl * v[1]
    north = -sp * cl * v[0] - sp * sl * v[1] + cp * v[2]
    up = cp * cl * v[0] + cp * sl * v[1] + sp * v[2]
    return np.array([east, north, up])


class _EpochBuilder:
    def __init__(self, scanner: _Scanner) -> None:
        self.scanner = scanner
        self.leap: int | None = None  # GPS - UTC (s) all the log's times take (_time)
        self.table_leap = False  # ... taken from the built-in table
        self.table_leaps = 0
        # Leap counts other than self.leap in resolved UTC, with the UTC they first came at.
        self.leap_changes: dict[int, float] = {}
        self.unresolved = 0  # epochs whose unresolved UTC was off the log's clock
        self.without_time = 0
        self.without_fix = 0
        self.histogram: Counter[int] = Counter()
        self.last_week: int | None = None
        self.last_itow: int | None = None  # of the epoch that set or carried last_week
        self.last_time: float | None = None
        self.first_time = math.inf  # of any timed epoch, with a fix or not (t0 of outages)

    def _utc(self, e: _Epoch) -> tuple[float, bool] | None:
        """The epoch's UTC (POSIX) from its date and time fields where flagged valid, and
        whether the receiver had fully resolved it (knew the leap seconds)."""
        m = e.msgs
        for name, sec in (("NAV-PVT", "second"), ("NAV-PVAT", "sec")):
            msg = m.get(name)
            if msg is not None and getattr(msg, "validDate", 0) and getattr(msg, "validTime", 0):
                t = _utc_from_fields(msg, sec)
                if t is not None:
                    return t, bool(getattr(msg, "fullyResolved", 0))
        utc = m.get("NAV-TIMEUTC")
        if utc is not None and getattr(utc, "validUTC", 0):
            t = _utc_from_fields(utc, "sec")
            if t is not None:
                return t, True
        return None

    def _stated_week(self, e: _Epoch) -> tuple[int, float] | None:
        """(GPS week, fTOW ns) from NAV-SOL or NAV-TIMEGPS where flagged valid."""
        sol, tgps = e.msgs.get("NAV-SOL"), e.msgs.get("NAV-TIMEGPS")
        if sol is not None and getattr(sol, "wknSet", 0) and getattr(sol, "towSet", 0):
            return int(sol.week), _f(sol, "fTOW")
        if tgps is not None and getattr(tgps, "weekValid", 0) and getattr(tgps, "towValid", 0):
            return int(tgps.week), _f(tgps, "fTOW")
        return None

    @staticmethod
    def _gps_posix(week: int, itow_ms: int, ftow_ns: float) -> float:
        return GPS_EPOCH_POSIX + week * WEEK_S + itow_ms * 1e-3 + (ftow_ns if math.isfinite(ftow_ns) else 0.0) * 1e-9

    @staticmethod
    def _week_from_utc(e: _Epoch, utc: float) -> int:
        """The GPS week of the epoch's iTOW, from its UTC (a leap count off by a few seconds
        cannot change it)."""
        guess = utc - GPS_EPOCH_POSIX + _leap_from_table(utc - GPS_EPOCH_POSIX)
        return round((guess - e.itow * 1e-3) / WEEK_S)

    def reference_leap(self, epochs: list[_Epoch]) -> int | None:
        """GPS - UTC (s) of the log's first epoch whose UTC the receiver had resolved, else
        of its first valid NAV-TIMEGPS leap count: the one offset the whole log's times take
        (see :meth:`_time`). None where the log says neither."""
        for e in epochs:
            utc = self._utc(e)
            if utc is None or not utc[1]:
                continue
            stated = self._stated_week(e)
            week = stated[0] if stated else self._week_from_utc(e, utc[0])
            return round(self._gps_posix(week, e.itow, 0.0) - utc[0])
        return self.scanner.valid_leaps[0] if self.scanner.valid_leaps else None

    def _time(self, e: _Epoch) -> float | None:
        """The epoch's time on one clock for the whole log: GPS time less the log's one leap
        count (:meth:`reference_leap`), to the sub-millisecond of the UTC fields where
        valid. The receiver's own UTC steps by a whole second at a leap second, and when it
        learns the leap count after a cold start (an epoch's UTC valid but not fully
        resolved runs 1 s off): such a step read as the IMU's sensor tags jumping and the
        log refused (outside tester, a real 2016-12-31 leap second and an unresolved start).
        So the times stay UTC as at the log's start; each step is counted and said."""
        utc = self._utc(e)
        stated = self._stated_week(e)
        week: int | None = None
        ftow = 0.0
        if stated is not None:
            week, ftow = stated
        elif utc is not None:
            week = self._week_from_utc(e, utc[0])
        elif self.last_week is not None:
            week = self.last_week  # iTOW of a later epoch of the same week ...
            if self.last_itow is not None and e.itow < self.last_itow - WEEK_S * 500:
                # ... or of the next, where iTOW wrapped: a log with NAV-TIMEGPS once put
                # every fix after the rollover a week back (outside tester: "the IMU's time
                # tags jump", or half the fixes outside an imu.csv's span).
                week += 1
        if week is None or week <= 0:
            return None
        self.last_week, self.last_itow = week, e.itow
        gps = self._gps_posix(week, e.itow, ftow)
        if self.leap is None:
            self.leap = _leap_from_table(gps - GPS_EPOCH_POSIX)
            self.table_leap = True
        if self.table_leap:
            self.table_leaps += 1
        if utc is None:
            return gps - self.leap
        own = round(gps - utc[0])
        if own != self.leap:
            if utc[1]:
                self.leap_changes.setdefault(own, utc[0])
            else:
                self.unresolved += 1
        # The UTC fields' fraction of a second, moved by the whole seconds of leap count.
        return utc[0] + (own - self.leap)

    def _status(self, e: _Epoch) -> tuple[int, int] | None:
        """(NMEA fix quality, u-blox fix type) or None when the epoch has no position fix."""
        m = e.msgs
        pvt = m.get("NAV-PVT") or m.get("NAV-PVAT")
        if pvt is not None:
            fix_type = int(getattr(pvt, "fixType", 0))
            ok = getattr(pvt, "gnssFixOk", getattr(pvt, "gnssFixOK", 0))
            carr = int(getattr(pvt, "carrSoln", 0))
            diff = getattr(pvt, "diffSoln", 0)
        elif "NAV-SOL" in m:
            sol = m["NAV-SOL"]
            fix_type, ok = int(sol.gpsFix), sol.gpsfixOK
            diff, carr = sol.diffSoln, 0
            status = m.get("NAV-STATUS")
            if status is not None:
                carr = int(getattr(status, "carrSoln", 0))
        elif "NAV-STATUS" in m:
            st = m["NAV-STATUS"]
            fix_type, ok = int(st.gpsFix), st.gpsFixOk
            diff, carr = st.diffSoln, int(getattr(st, "carrSoln", 0))
        elif any(k in m for k in ("NAV-HPPOSLLH", "NAV-POSLLH")):
            return 1, 3  # a position without any status message: taken as autonomous
        else:
            return None
        if fix_type == 0:
            return None
        if fix_type == 1:
            return (6 if ok else 0), 1
        if not ok:
            # A solution outside the receiver's DOP/accuracy masks (gnssFixOK clear): kept, as
            # gpsd reports it, but flagged invalid (0) so the smoother's quality gate drops it.
            return 0, fix_type
        if fix_type == 5:
            return 1, 5  # time only: a timing receiver at its fixed (surveyed) position
        if carr == 2:
            return 4, fix_type
        if carr == 1:
            return 5, fix_type
        return (2 if diff else 1), fix_type

    def row(self, e: _Epoch) -> list[float] | None:
        t = self.last_time = self._time(e)
        if t is None:
            self.without_time += 1
            return None
        self.first_time = min(self.first_time, t)
        status = self._status(e)
        position = self._position(e) if status is not None else None
        if status is None or position is None:
            self.without_fix += 1
            return None
        quality, fix_type = status
        self.histogram[quality] += 1
        lat, lon, h, sh, sv = position
        if fix_type == 2:
            sv = max(sv, TWO_D_MIN_VERTICAL_SIGMA_M) if math.isfinite(sv) else math.nan
        vel, vsig, speed, course = self._velocity(e, lat, lon)
        m = e.msgs
        dop = m.get("NAV-DOP")
        hdop, vdop, pdop = (
            (_f(dop, "hDOP"), _f(dop, "vDOP"), _f(dop, "pDOP")) if dop else (math.nan,) * 3
        )
        sats = math.nan
        for name in ("NAV-PVT", "NAV-PVAT", "NAV-SOL"):
            msg = m.get(name)
            if msg is not None:
                if not math.isfinite(pdop):
                    pdop = _f(msg, "pDOP")
                sats = _f(msg, "numSV")
                break
        return [t, lat, lon, h, *vel, sh, sh, sv, vsig, vsig, vsig, hdop, vdop, pdop,
                quality, sats, speed, course]  # fmt: skip

    @staticmethod
    def _position(e: _Epoch) -> tuple[float, float, float, float, float] | None:
        m = e.msgs
        for name in ("NAV-HPPOSLLH", "NAV-PVT", "NAV-PVAT", "NAV-POSLLH"):
            msg = m.get(name)
            if msg is None or getattr(msg, "invalidLlh", 0):
                continue
            lat, lon, h = _f(msg, "lat"), _f(msg, "lon"), _f(msg, "height", 1e-3)
            if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90):
                continue
            return lat, lon, h, _f(msg, "hAcc", 1e-3), _f(msg, "vAcc", 1e-3)
        for name in ("NAV-SOL", "NAV-POSECEF"):
            msg = m.get(name)
            if msg is None:
                continue
            xyz = [_f(msg, k, 1e-2) for k in ("ecefX", "ecefY", "ecefZ")]
            if not all(math.isfinite(v) for v in xyz) or np.linalg.norm(xyz) < 6.0e6:
                continue
            import pymap3d

            lat, lon, h = pymap3d.ecef2geodetic(*xyz)
            pacc = _f(msg, "pAcc", 1e-2)
            return float(lat), float(lon), float(h), pacc, pacc
        return None

    @staticmethod
    def _velocity(
        e: _Epoch, lat: float, lon: float
    ) -> tuple[list[float], float, float, float]:
        m = e.msgs
        for name in ("NAV-PVT", "NAV-PVAT"):
            msg = m.get(name)
            if msg is not None:
                vel = [_f(msg, "velE", 1e-3), _f(msg, "velN", 1e-3), -_f(msg, "velD", 1e-3)]
                course = _f(msg, "headMot") if name == "NAV-PVT" else _f(msg, "motHeading")
                return vel, _f(msg, "sAcc", 1e-3), _f(msg, "gSpeed", 1e-3), course
        msg = m.get("NAV-VELNED")
        if msg is not None:
            vel = [_f(msg, "velE", 1e-2), _f(msg, "velN", 1e-2), -_f(msg, "velD", 1e-2)]
            return vel, _f(msg, "sAcc", 1e-2), _f(msg, "gSpeed", 1e-2), _f(msg, "heading")
        for name in ("NAV-SOL", "NAV-VELECEF"):
            msg = m.get(name)
            if msg is not None:
                v = np.array([_f(msg, k, 1e-2) for k in ("ecefVX", "ecefVY", "ecefVZ")])
                enu = _ecef_to_enu_velocity(v, lat, lon)
                speed = float(math.hypot(enu[0], enu[1]))
                course = math.degrees(math.atan2(enu[0], enu[1])) % 360.0
                return list(map(float, enu)), _f(msg, "sAcc", 1e-2), speed, course
        return [math.nan] * 3, math.nan, math.nan, math.nan


_ROW_COLUMNS = 20  # t, lat, lon, h, ve, vn, vu, sE, sN, sU, svE, svN, svU, hdop, vdop, pdop, q, n, speed, course


def _gnss_from_rows(rows: list[list[float]]) -> GnssData:
    table = np.array(rows, dtype=float).reshape(-1, _ROW_COLUMNS)
    return GnssData(
        t=table[:, 0],
        lla=table[:, 1:4],
        velocity=table[:, 4:7],
        std=table[:, 7:10],
        velocity_std=table[:, 10:13],
        hdop=table[:, 13],
        vdop=table[:, 14],
        pdop=table[:, 15],
        fix_quality=table[:, 16],
        num_sats=table[:, 17],
        speed=table[:, 18],
        course=table[:, 19],
    )


def _time_step(t: np.ndarray) -> float:
    """The coarsest of 1 ms, 10 ms, 0.1 s and 1 s that every time in ``t`` (s) is a whole
    multiple of: the resolution its sentences wrote them with."""
    step = 1e-3
    for coarser in (1e-2, 1e-1, 1.0):
        if t.size and np.all(np.abs(t / coarser - np.round(t / coarser)) < 1e-3):
            step = coarser
    return step


def _nmea_rows(
    scanner: _Scanner, ubx_times: np.ndarray, warnings: list[str]
) -> tuple[list[list[float]], dict[str, int]]:
    """Fixes of the NMEA sentences mixed into the stream, at times no UBX epoch covers."""
    from fgins.io.gnss_export import gnss_columns
    from fgins.io.nmea import _assemble, _Reader

    if not scanner.nmea_lines:
        return [], {}
    reader = _Reader()
    for line in scanner.nmea_lines:
        reader.feed_line(line)
    counts = {f"NMEA-{k}": v for k, v in reader.counts.items()}
    try:
        result = _assemble(scanner.path, reader, 0.0)
    except InputError as exc:
        # Sentences without a fix (GSV, GSA, TXT) are common beside UBX: nothing to say.
        # Anything else (two receivers on one time base, ...) is said, not swallowed.
        if "no usable GNSS fix" not in str(exc):
            warnings.append(f"NMEA sentences in the log not used: {exc}")
        return [], counts
    t = result.gnss.t.copy()
    if not result.has_date:
        if ubx_times.size == 0:
            warnings.append("NMEA sentences carry no date and no UBX epoch gives one: "
                            "their times are seconds of the UTC day")  # fmt: skip
        else:
            midnight = math.floor(ubx_times[0] / 86400.0) * 86400.0
            t = t + midnight
    warnings.extend(f"NMEA sentences: {w}" for w in result.warnings)
    columns = gnss_columns(result.gnss)
    # The UBX epoch of the same instant is better (sigmas, full precision): NMEA fixes only
    # where no UBX epoch lies within the NMEA times' own step (ubx_times is sorted). The
    # step, not 0.5 ms: a receiver's GGA at hhmmss.ss truncates an epoch at .399999857 s to
    # .39, and 398 such sentences became extra fixes beside their own epochs (outside tester).
    covered = np.zeros(len(t), dtype=bool)
    if ubx_times.size:
        k = np.clip(np.searchsorted(ubx_times, t), 1, max(len(ubx_times) - 1, 1))
        left = ubx_times[np.minimum(k - 1, len(ubx_times) - 1)]
        right = ubx_times[np.minimum(k, len(ubx_times) - 1)]
        covered = np.minimum(np.abs(t - left), np.abs(t - right)) < max(_time_step(t), 5e-4)
    rows = []
    for i, ti in enumerate(t):
        if covered[i]:
            continue
        rows.append(
            [ti] + [float(columns[k][i]) for k in (
                "lat", "lon", "alt", "vel_east", "vel_north", "vel_up",
                "std_east", "std_north", "std_up")]
            + [math.nan] * 3
            + [float(columns[k][i]) for k in (
                "hdop", "vdop", "pdop", "fix_quality", "num_sats", "speed", "course")]
        )  # fmt: skip
    return rows, counts


# ----------------------------------------------------------------------------------------------
# IMU


def _unwrap(tags: np.ndarray, modulus: int) -> np.ndarray:
    """Counter values unwrapped: each step taken as the shorter way round, so a counter that
    wraps goes on, and one that goes back past zero (a restart, a log concatenated with
    itself) goes back, not forward by most of the counter's period (a 200 s step back read
    as "forward by 0.0 s, 240 times", a log given twice as "forward by 655.4 s"; outside
    tester)."""
    tags = tags.astype(np.int64)
    if tags.size < 2:
        return tags
    steps = np.diff(tags)
    turns = (steps < -modulus // 2).astype(np.int64) - (steps > modulus // 2).astype(np.int64)
    wraps = np.concatenate([[0], np.cumsum(turns)])
    return tags + wraps * modulus


def _time_map(
    stream: str,
    msg_index: np.ndarray,
    msg_last_tag: np.ndarray,
    epochs: list[tuple[int, float]],
    nominal: float,
) -> TimeMap | None:
    """Anchor each GNSS epoch (stream index, time) to the last IMU tag sent before it."""
    anchors_tag, anchors_t = [], []
    for order, t in epochs:
        k = int(np.searchsorted(msg_index, order)) - 1
        if k >= 0:
            anchors_tag.append(float(msg_last_tag[k]))
            anchors_t.append(t)
    if not anchors_tag:
        return None
    tag = np.asarray(anchors_tag)
    t = np.asarray(anchors_t)
    # Keep one anchor per tag (several epochs between two IMU messages share one): the first.
    _, first = np.unique(tag, return_index=True)
    tag, t = tag[np.sort(first)], t[np.sort(first)]
    scale, fitted = nominal, False
    # The span in GNSS time, not in ticks at the nominal scale: tags in 1 ms ticks (25.6 x
    # ESF-RAW's nominal) spanned 9 s of a 240 s log "at nominal", were never fitted, and
    # were refused as "jumping back" 240 times (outside tester).
    if len(tag) >= MIN_FIT_ANCHORS and t.max() - t.min() >= MIN_FIT_SPAN_S:
        scale = float(np.polyfit(tag - tag[0], t - t[0], 1)[0])
        fitted = True
    offset = float(np.median(t - scale * tag))
    residuals = t - (offset + scale * tag)
    return TimeMap(stream, scale, offset, nominal, len(tag), fitted, residuals, t - nominal * tag, t)


@dataclass
class _ImuRows:
    tags: np.ndarray
    gyro: np.ndarray  # deg/s
    accel: np.ndarray  # m/s^2
    temp: np.ndarray
    speed_tags: np.ndarray
    speed: np.ndarray
    ticks: int
    dropped: int
    msg_index: np.ndarray
    msg_last_tag: np.ndarray
    max_pair_gap: float = 0.0
    repeated: int = 0  # IMU values at a tag and type already filled: dropped
    identical: int = 0  # ... of them equal to the value kept (the stream logged twice)
    tick_s: float = ESF_RAW_TICK_S  # one tag tick (s)

    def jumps_back(self) -> np.ndarray:
        """The messages after which the tags go back by more than RESTART_BACKWARDS_S (a
        receiver restart, not a wrap)."""
        return np.flatnonzero(np.diff(self.msg_last_tag) * self.tick_s < -RESTART_BACKWARDS_S)


def _table(tags: np.ndarray, kinds: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(unique tags, table of raw values by tag x ESF data type 0..63, NaN where absent, the
    number of IMU values that repeat a tag's type already filled: dropped, and how many of
    those equal the value kept)."""
    unique, inverse = np.unique(tags, return_inverse=True)
    table = np.full((len(unique), 64), np.nan)
    # The first value of a type at a tag counts (numpy leaves the winner of repeated indices
    # in one assignment unspecified: the first ones are picked explicitly).
    cells = inverse.astype(np.int64) * 64 + kinds
    _, first = np.unique(cells, return_index=True)
    table[inverse[first], kinds[first]] = values[first]
    imu = np.isin(kinds, [*GYRO_TYPES, *ACCEL_TYPES])
    repeated = int(imu.sum() - np.isin(kinds[first], [*GYRO_TYPES, *ACCEL_TYPES]).sum())
    again = np.ones(len(cells), dtype=bool)
    again[first] = False
    again &= imu
    identical = int(np.sum(table[inverse[again], kinds[again]] == values[again]))
    return unique.astype(float), table, repeated, identical


def _raw_rows(scanner: _Scanner) -> _ImuRows | None:
    if not scanner.esf_raw:
        return None
    counts = np.array([len(groups) // 8 for _, groups in scanner.esf_raw])
    words = np.frombuffer(b"".join(g for _, g in scanner.esf_raw), dtype="<u4").reshape(-1, 2)
    words = words.astype(np.int64)
    kinds = (words[:, 0] >> 24) & 0x3F
    values = _signed24(words[:, 0])
    modulus = 1 << 24 if int(words[:, 1].max()) < (1 << 24) else 1 << 32
    tags = _unwrap(words[:, 1], modulus)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    msg_last = np.maximum.reduceat(tags, starts)
    msg_index = np.array([index for index, _ in scanner.esf_raw])
    unique, table, repeated, identical = _table(tags, kinds, values)
    rows = _rows_from_table(unique, table, msg_index, msg_last, ESF_RAW_TICK_S)
    rows.repeated, rows.identical = repeated, identical
    return rows


def _meas_rows(scanner: _Scanner) -> _ImuRows | None:
    if not scanner.esf_meas:
        return None
    msg_tags = _unwrap(np.array([tag for _, tag, _ in scanner.esf_meas]), 1 << 32)
    msg_index = np.array([index for index, _, _ in scanner.esf_meas])
    sizes = [len(values) for _, _, values in scanner.esf_meas]
    pairs = np.array([kv for _, _, values in scanner.esf_meas for kv in values], dtype=np.int64)
    tags = np.repeat(msg_tags, sizes)
    unique, table, repeated, identical = _table(tags, pairs[:, 0], pairs[:, 1])
    rows = _rows_from_table(unique, table, msg_index, msg_tags.copy(), ESF_MEAS_TICK_S)
    rows.repeated, rows.identical = repeated, identical
    return rows


def _rows_from_table(
    tags: np.ndarray, table: np.ndarray, msg_index: np.ndarray, msg_last: np.ndarray, tick_s: float
) -> _ImuRows:
    """Rows of (time tag, ESF data type) raw values -> IMU samples.

    A tag with all six axes is a sample. Tags with only the gyro or only the accelerometer
    (sent in separate messages) are paired, mutually nearest and closer than half the median
    interval, at the mean tag; the rest are dropped and counted. Nothing is interpolated.
    """
    has_gyro = np.isfinite(table[:, list(GYRO_TYPES)]).all(axis=1)
    has_accel = np.isfinite(table[:, list(ACCEL_TYPES)]).all(axis=1)
    any_imu = np.isfinite(table[:, [*GYRO_TYPES, *ACCEL_TYPES]]).any(axis=1)
    complete = has_gyro & has_accel
    gyro_only = np.flatnonzero(has_gyro & ~has_accel)
    accel_only = np.flatnonzero(has_accel & ~has_gyro)
    ia, ig = _pair(tags[accel_only], tags[gyro_only])
    ia, ig = accel_only[ia], gyro_only[ig]
    merged = np.where(np.isfinite(table[ia]), table[ia], table[ig])
    merged_tags = np.floor((tags[ia] + tags[ig]) / 2.0)
    max_gap = float(np.max(np.abs(tags[ia] - tags[ig]))) * tick_s if len(ia) else 0.0
    dropped = int((any_imu & ~complete).sum()) - 2 * len(ia)
    imu_tags = np.concatenate([tags[complete], merged_tags])
    imu = np.concatenate([table[complete], merged])
    order = np.argsort(imu_tags, kind="stable")
    imu_tags, imu = imu_tags[order], imu[order]
    speed_rows = np.isfinite(table[:, SPEED_TYPE])
    return _ImuRows(
        tags=imu_tags,
        gyro=imu[:, list(GYRO_TYPES)] * GYRO_SCALE,
        accel=imu[:, list(ACCEL_TYPES)] * ACCEL_SCALE,
        temp=imu[:, TEMP_TYPE] * 1e-2,
        speed_tags=tags[speed_rows],
        speed=table[speed_rows, SPEED_TYPE] * 1e-3,
        ticks=int(np.isfinite(table[:, list(TICK_TYPES)]).sum()),
        dropped=dropped,
        msg_index=np.asarray(msg_index),
        msg_last_tag=np.asarray(msg_last),
        max_pair_gap=max_gap,
        tick_s=tick_s,
    )


def _pair(ta: np.ndarray, tg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of mutually nearest accel/gyro tags closer than half the median interval."""
    empty = np.zeros(0, dtype=int)
    if len(ta) == 0 or len(tg) == 0:
        return empty, empty
    steps = np.concatenate([np.diff(ta), np.diff(tg)])
    steps = steps[steps > 0]
    if steps.size == 0:
        return empty, empty  # one message each: no interval to judge "nearest" by
    limit = 0.5 * float(np.median(steps))

    def nearest(x: np.ndarray, ref: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(ref, x), 1, max(len(ref) - 1, 1))
        left = np.minimum(k - 1, len(ref) - 1)
        right = np.minimum(k, len(ref) - 1)
        return np.where(np.abs(ref[left] - x) <= np.abs(ref[right] - x), left, right)

    # The accelerometer's tags sit a fixed time from the gyro's: judged from there, so that
    # one exactly half an interval after (5 ms at 100 Hz, the NEO-M8U's offset) is not a tie
    # between two gyro tags, each then nobody's nearest (a 100 Hz log lost its whole IMU).
    # Exactly half an interval, 5 ms after one gyro tag is 5 ms before the next: only the
    # log's ends tell which, so both are tried and the one pairing more is kept.
    lag = float(np.median(ta - tg[nearest(ta, tg)]))
    lags = [lag, -lag] if abs(abs(lag) - limit) < 0.25 * limit else [lag]
    best: tuple[np.ndarray, np.ndarray] = (empty, empty)
    for candidate in lags:
        shifted = ta - candidate
        a_to_g = nearest(shifted, tg)
        g_to_a = nearest(tg, shifted)
        mutual = g_to_a[a_to_g] == np.arange(len(ta))
        close = (np.abs(shifted - tg[a_to_g]) < limit) & (np.abs(ta - tg[a_to_g]) <= limit)
        ia = np.flatnonzero(mutual & close)
        if len(ia) > len(best[0]):
            best = (ia, a_to_g[ia])
    return best


# ----------------------------------------------------------------------------------------------


def read_ubx(path: str | Path) -> UbxResult:
    """Read one u-blox UBX log (see the module docstring for every convention).

    Raises :class:`InputError` only when the file cannot be read or holds no UBX frame and no
    NMEA sentence at all; a log without a fix gives ``gnss=None`` (see :func:`require_fix`).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read UBX log ({exc.strerror}); check the path") from None
    scanner = _Scanner(path)
    scanner.scan(data)
    ubx_frames = sum(v for k, v in scanner.counts.items() if k != "RTCM3")
    if ubx_frames == 0 and not scanner.nmea_lines:
        raise InputError(
            f"{path}: no valid UBX frame or NMEA sentence ({scanner.corrupt} frames with a bad "
            f"checksum, {scanner.cut} cut); is this a u-blox log?"
        )
    warnings: list[str] = []
    builder = _EpochBuilder(scanner)
    builder.leap = builder.reference_leap(scanner.epochs)
    rows: list[tuple[float, list[float]]] = []
    epoch_times: list[tuple[int, float]] = []
    for epoch in scanner.epochs:
        row = builder.row(epoch)
        if row is not None:
            rows.append((epoch.order, row))
        if builder.last_time is not None:
            epoch_times.append((epoch.order, builder.last_time))
    rows.sort(key=lambda item: item[1][0])
    kept: list[list[float]] = []
    duplicates = 0
    for _, row in rows:
        if kept and row[0] - kept[-1][0] < 5e-4:
            duplicates += 1
            continue
        kept.append(row)
    if duplicates:
        warnings.append(f"{duplicates} navigation epochs repeat an earlier time: dropped")
    repeat_warning = _repeat_warning(scanner.epochs)  # also counts identical copies
    if repeat_warning:
        warnings.append(repeat_warning)
    ubx_times = np.array([r[0] for r in kept])
    nmea_rows, nmea_counts = _nmea_rows(scanner, ubx_times, warnings)
    counts = dict(scanner.counts)
    counts.update(nmea_counts)
    merged = sorted(kept + nmea_rows, key=lambda r: r[0])
    final: list[list[float]] = []
    for row in merged:
        if final and row[0] - final[-1][0] < 5e-4:
            continue
        final.append(row)
    gnss = _gnss_from_rows(final) if final else None

    if scanner.corrupt or scanner.cut:
        warnings.append(
            f"{scanner.corrupt} UBX frame(s) with a bad checksum and {scanner.cut} cut frame(s) "
            "skipped"
        )
    if scanner.noise:
        warnings.append(f"{scanner.noise} byte(s) outside any UBX/NMEA/RTCM frame skipped")
    if scanner.undecodable:
        warnings.append(f"{scanner.undecodable} UBX frame(s) with a valid checksum but an "
                        "undecodable payload skipped")  # fmt: skip
    if builder.without_time:
        warnings.append(f"{builder.without_time} navigation epoch(s) without a valid time skipped")
    if builder.without_fix:
        warnings.append(f"{builder.without_fix} navigation epoch(s) without a position fix skipped")
    if counts.get("HNR-PVT"):
        warnings.append(
            f"{counts['HNR-PVT']} HNR-PVT message(s) not used as fixes: the receiver's own "
            "high-rate sensor-fused output (it already holds the IMU and its errors run on "
            "from one message to the next); the fixes come from the NAV messages"
        )
    warnings.extend(_leap_warnings(builder))
    if builder.table_leaps:
        warnings.append(
            f"{builder.table_leaps} epoch(s) in GPS time without valid leap seconds in the log: "
            "used the built-in leap-second table"
        )

    # Only epochs with a fix anchor the IMU time map (their time is trusted).
    fix_anchor = [(order, row[0]) for order, row in rows]
    result = UbxResult(
        path=path, gnss=gnss, imu=None, odometer=None, counts=counts, warnings=warnings,
        corrupt_frames=scanner.corrupt, cut_frames=scanner.cut, noise_bytes=scanner.noise,
        undecodable=scanner.undecodable, rtcm_frames=scanner.rtcm, epochs=len(scanner.epochs),
        epochs_without_fix=builder.without_fix, epochs_without_time=builder.without_time,
        fix_histogram=dict(builder.histogram), nmea_fixes_added=len(nmea_rows),
    )  # fmt: skip
    if gnss is not None:
        result.first_time, result.last_time = float(gnss.t[0]), float(gnss.t[-1])
    result.first_epoch_time = float(builder.first_time)
    _attach_imu(result, scanner, fix_anchor or epoch_times)
    return result


def _leap_warnings(builder: _EpochBuilder) -> list[str]:
    """What the receiver's UTC did that the log's one clock does not follow (_time)."""
    out = []
    for leap, utc in sorted(builder.leap_changes.items(), key=lambda item: item[1]):
        when = datetime.fromtimestamp(utc, tz=UTC).strftime("%Y-%m-%d %H:%M:%S")
        out.append(
            f"the receiver's UTC steps by a leap second at {when} (GPS - UTC {builder.leap} -> "
            f"{leap} s): the times stay on one clock, UTC as at the log's start, so from there "
            f"on they run {abs(leap - builder.leap)} s {'ahead of' if leap > builder.leap else 'behind'} UTC"
        )
    if builder.unresolved:
        out.append(
            f"{builder.unresolved} epoch(s) whose UTC the receiver had not resolved yet (leap "
            f"seconds not known; 1 s or more off its later UTC): timed from GPS time less "
            f"{builder.leap} s as the rest"
        )
    return out


def _repeat_warning(epochs: list[_Epoch]) -> str:
    """A counted warning for the epochs whose iTOW came again with other messages (dropped:
    the first of each message type is used), and how far the dropped positions lie from the
    kept ones."""
    from fgins.datatypes import Origin
    from fgins.geodesy import lla_to_enu

    repeated = [e for e in epochs if e.repeats]
    # Epochs that came again only as identical copies (no differing message): dropped too.
    identical = sum(1 for e in epochs if e.identical_repeats and not e.repeats)
    copies = (
        f"{identical} repeated navigation epoch(s) identical to earlier ones dropped (the same "
        "iTOW with byte-identical messages: the log concatenated with itself, or a stretch "
        "logged twice)"
        if identical
        else ""
    )
    if not repeated:
        return copies
    distances = []
    for epoch in repeated:
        kept = _EpochBuilder._position(epoch)
        shadow = _Epoch(epoch.itow, epoch.order)
        shadow.msgs = epoch.repeats
        other = _EpochBuilder._position(shadow)
        if kept is None or other is None:
            continue
        origin = Origin(kept[0], kept[1], 0.0)
        east, north, _ = lla_to_enu(np.array([[other[0], other[1], 0.0]]), origin)[0]
        distances.append(math.hypot(east, north))
    kinds = "/".join(sorted({name for e in repeated for name in e.repeats}))
    message = (
        f"dropped {len(repeated)} navigation epoch(s) with repeated time: their iTOW (GPS time "
        f"of week) came again with different {kinds} messages (a receiver restart or two logs "
        "concatenated?); the first of each kept"
    )
    far = [d for d in distances if d > REPEAT_SAME_POSITION_M]
    if len(far) == 1:
        message += f"; 1 of them with a position {far[0]:.0f} m from the kept one"
    elif far:
        message += (
            f"; {len(far)} of them with positions {np.median(far):.0f} m (median, up to "
            f"{max(far):.0f} m) from the kept ones"
        )
    elif distances:
        message += f" (positions within {REPEAT_SAME_POSITION_M:g} m of the kept ones)"
    return f"{message}; {copies}" if copies else message


def _median_interval(tags: np.ndarray) -> float:
    """Median step between consecutive distinct time tags (in ticks); 0 if fewer than two."""
    steps = np.diff(np.unique(tags))
    return float(np.median(steps)) if steps.size else 0.0


def _anchor_steps(mapping: TimeMap) -> np.ndarray:
    """Per pair of consecutive anchors, the GNSS time elapsed less the tags' (s) at the
    median scale of such pairs: ~0 on one clock, the jump where the sensor clock jumped
    (positive: its tags went back)."""
    lag = mapping.nominal_lag  # t - nominal * tag
    if lag.size < 2:
        return np.zeros(0)
    gnss = np.diff(mapping.gnss_t)
    ticks = gnss - np.diff(lag)  # nominal * d(tag)
    forward = ticks > 0
    rate = float(np.median(gnss[forward] / ticks[forward])) if forward.any() else 1.0
    return gnss - rate * ticks


def _attach_imu(result: UbxResult, scanner: _Scanner, anchors: list[tuple[int, float]]) -> None:
    from fgins.io.imu_checks import imu_from_samples

    raw = _raw_rows(scanner)
    meas = _meas_rows(scanner)
    result.esf_meas_messages = [
        (tag, {k: v * _SCALE.get(k, 1.0) for k, v in values})
        for _, tag, values in scanner.esf_meas
    ]
    source, rows, nominal = "", None, 0.0
    if raw is not None and len(raw.tags) >= 2:
        source, rows, nominal = "ESF-RAW", raw, ESF_RAW_TICK_S
    elif meas is not None and len(meas.tags) >= 2:
        source, rows, nominal = "ESF-MEAS", meas, ESF_MEAS_TICK_S
    for stream, r in (("ESF-RAW", raw), ("ESF-MEAS", meas)):
        if r is not None:
            result.wheel_ticks += r.ticks
            if r.dropped:
                result.warnings.append(f"{stream}: {r.dropped} time tag(s) with only part of the "
                                       "six IMU axes and no partner: dropped (no sample "
                                       "interpolated)")  # fmt: skip
            restarted = r.jumps_back().size > 0
            if r.repeated and r.identical == r.repeated and not restarted:
                # Every repeat the same value at the same tag: the stream logged twice (two
                # ports into one file), as the navigation half says of its epochs.
                result.warnings.append(
                    f"{stream}: {r.repeated} IMU value(s) identical to earlier ones at the same "
                    "time tag (the stream logged twice?): dropped"
                )
            elif r.repeated and not restarted:  # two samples under one tag: which time the
                # second has is unknown (after a restart the tags repeat too: that is said)
                result.warnings.append(
                    f"{stream}: {r.repeated} IMU value(s) repeat the time tag of an earlier "
                    f"one (about {r.repeated // 6} sample(s)): dropped, the first kept; the "
                    "receiver's sensor time tags do not advance with its samples"
                )
    if rows is None:
        return
    result.imu_source = source
    result.imu_tags = rows.tags
    result.imu_temp = rows.temp
    result.imu_raw_gyro_deg_s = rows.gyro
    result.imu_raw_accel = rows.accel
    if rows.max_pair_gap > 0:
        result.warnings.append(
            f"{source}: accelerometer and gyro sent with separate time tags, paired by nearest time "
            f"tag (largest tag difference {1e3 * rows.max_pair_gap:.0f} ms)"
        )
    back = rows.jumps_back()
    if back.size:
        # Sorting by tag would interleave two runs of the sensor clock: refuse, clearly.
        result.warnings.append(
            f"{source}: sensor time tags jump back {back.size} time(s) (first after message "
            f"{int(back[0]) + 1}; a receiver restart?): IMU not used; split the log there"
        )
        return
    mapping = _time_map(source, rows.msg_index, rows.msg_last_tag, anchors, nominal)
    if mapping is None:
        result.warnings.append(
            f"{source}: {len(rows.tags)} IMU samples but no timed navigation epoch to map their "
            "time tags onto GNSS time: IMU not used"
        )
        return
    # Found between consecutive anchors against the median tick scale between them (a
    # clock's steady drift is in that scale; one fitted over a jump takes the jump into its
    # scale and moved every residual: "240 jumps of 0.0 s" for one of 200 s).
    steps = _anchor_steps(mapping)
    jumps = np.flatnonzero(np.abs(steps) > CLOCK_JUMP_S)
    if jumps.size:
        step = float(steps[jumps[0]])
        result.warnings.append(
            f"{source}: sensor time tags jump {'back' if step > 0 else 'forward'} by about "
            f"{abs(step):.1f} s against GNSS time {jumps.size} time(s) (first between navigation "
            f"epochs {int(jumps[0]) + 1} and {int(jumps[0]) + 2} of those with IMU data): IMU not "
            "used; split the log there"
        )
        return
    result.time_maps.append(mapping)
    # An anchor is the last tag before the epoch: quantised to one sample interval, so a
    # spread of up to two intervals (an ~11 Hz ESF-MEAS stream: 90 ms) is expected.
    spread_limit = max(ANCHOR_SPREAD_WARN_S, 2.0 * _median_interval(rows.tags) * nominal)
    if mapping.spread_s > spread_limit:
        result.warnings.append(f"{mapping.describe()}: above {spread_limit:.3g} s, the "
                               "IMU clock may have jumped; check the IMU time")  # fmt: skip
    if mapping.fitted and abs(mapping.scale / nominal - 1) > SCALE_WARN:
        result.warnings.append(f"{mapping.describe()}: tick scale far from nominal")
    t = mapping.offset + mapping.scale * rows.tags
    gyro = np.radians(rows.gyro)
    try:
        result.imu = imu_from_samples(t, gyro, rows.accel, source=f"{result.path} {source}",
                               warnings=result.warnings)  # fmt: skip
    except InputError as error:
        result.warnings.append(f"{source}: IMU not usable: {error}")
    if len(rows.speed_tags) >= 2:
        ts = mapping.offset + mapping.scale * rows.speed_tags
        order = np.argsort(ts, kind="stable")
        keep = np.concatenate([[True], np.diff(ts[order]) > 0])
        try:
            result.odometer = OdometerData(t=ts[order][keep], speed=rows.speed[order][keep])
        except InputError as error:
            result.warnings.append(f"{source}: wheel speed not usable: {error}")


def require_fix(result: UbxResult) -> GnssData:
    """The fixes of ``result``; a clear "no fix" error when there are none."""
    if result.gnss is not None and not np.any(result.gnss.fix_quality >= 1):
        raise InputError(
            f"{result.path}: no fix the receiver flags valid: all {len(result.gnss)} solutions "
            "have gnssFixOK clear (outside its accuracy masks); nothing to smooth"
        )
    if result.gnss is None or len(result.gnss) == 0:
        messages = sum(result.counts.values())
        untimed = result.epochs_without_time
        if untimed and untimed >= result.epochs - result.epochs_without_fix:
            raise InputError(
                f"{result.path}: no usable time: {result.epochs} navigation epochs, "
                f"{result.epochs_without_time} without a valid time (NAV-PVT validDate/"
                "validTime clear, no GPS week from NAV-SOL/NAV-TIMEGPS): a fix cannot be put "
                "on a clock; log NAV-PVT after the receiver has a time, or NAV-TIMEGPS"
            )
        if not any(result.counts.get(name) for name in _POSITION_MESSAGES):
            raise InputError(
                f"{result.path}: no fix: none of its {messages} messages is a navigation "
                "solution (NAV-PVT/SOL/POSLLH/HPPOSLLH/PVAT/POSECEF or NMEA GGA/RMC/GNS/GLL); "
                f"it holds {_holdings(result.counts)}: "
                "nothing to smooth; log NAV-PVT"
            )
        raise InputError(
            f"{result.path}: no fix: {messages} messages, {result.epochs} navigation epochs, "
            f"{result.epochs_without_fix} without a position fix; the receiver had no fix: "
            "nothing to smooth"
        )
    return result.gnss


# The messages an epoch's position can come from (the order of the module docstring).
_POSITION_MESSAGES = (
    "NAV-HPPOSLLH", "NAV-PVT", "NAV-PVAT", "NAV-POSLLH", "NAV-SOL", "NAV-POSECEF", "NMEA-GGA",
    "NMEA-RMC", "NMEA-GNS", "NMEA-GLL",
)  # fmt: skip
# What a log without a navigation solution may hold instead, and what that means to a user.
_NOT_A_SOLUTION = {
    "RXM-SFRBX": "raw navigation data subframes",
    "RXM-RAWX": "raw measurements (solve them first, e.g. with RTKLIB)",
    "RXM-RAW": "raw measurements (solve them first, e.g. with RTKLIB)",
    "HNR-PVT": "the high-rate sensor-fused output, not read as fixes",
    "LOG-RETRIEVEPOS": "positions retrieved from the receiver's flash log, not read",
    "LOG-BATCH": "batched fixes from the receiver's memory, not read",
    "NAV-SAT": "satellite status only",
}


def _holdings(counts: dict[str, int]) -> str:
    """The log's three most frequent messages, each with its meaning where known."""
    top = sorted(counts.items(), key=lambda item: -item[1])[:3]
    return ", ".join(
        f"{name} x{n}" + (f" ({_NOT_A_SOLUTION[name]})" if name in _NOT_A_SOLUTION else "")
        for name, n in top
    ) or "no decodable message"


def write_ubx_imu_csv(result: UbxResult, path: str | Path) -> int:
    """Write the receiver's IMU in the ``imu.csv`` layout (rad/s, m/s^2); rows written."""
    from fgins.io.csv_pair import write_imu_csv

    if result.imu is None:
        why = next((w for w in result.warnings if "IMU not used" in w), None)
        if why is not None:  # IMU messages there, refused for a reason: that reason
            raise InputError(f"{result.path}: the receiver's IMU is not usable: {why}; nothing to convert")
        raise InputError(
            f"{result.path}: no usable IMU (ESF-RAW/ESF-MEAS with gyro and accelerometer) in the "
            "log; nothing to convert"
        )
    write_imu_csv(result.imu, path)
    return len(result.imu)


def _stats(values: np.ndarray, unit: str) -> str:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return "n/a"
    return (
        f"{finite.min():.3f} / {np.median(finite):.3f} / {finite.max():.3f} {unit} "
        "(min / median / max)"
    )


def summarize_ubx(path: str | Path) -> str:
    """What ``fgins inspect LOG.ubx`` prints: messages and rates, fixes, accuracy, IMU, errors."""
    result = read_ubx(path)
    lines = [f"u-blox UBX log {result.path}"]
    span = result.last_time - result.first_time
    if result.gnss is not None and len(result.gnss) > 1:
        span += float(np.median(np.diff(result.gnss.t)))  # n epochs cover n periods
    by_name = ", ".join(
        f"{k} {v}" + (f" (~{v / span:.2f} Hz)" if span > 0 and v > 1 else "")
        for k, v in sorted(result.counts.items())
    )
    lines.append(f"  messages: {by_name or 'none'}")
    lines.append(
        f"  corrupt frames (bad checksum): {result.corrupt_frames}, cut frames: "
        f"{result.cut_frames}, undecodable: {result.undecodable}, noise bytes: "
        f"{result.noise_bytes}, RTCM3 frames skipped: {result.rtcm_frames}"
    )
    lines.append(
        f"  UBX navigation epochs: {result.epochs} ({result.epochs_without_fix} without a fix, "
        f"{result.epochs_without_time} without a valid time)"
    )
    gnss = result.gnss
    # The records' checks ``fgins convert`` makes (as an NMEA log's inspect): DOP
    # placeholders (99.99) are missing in the statistics too, counted in a warning.
    checks: list[str] = []
    if gnss is not None:
        from fgins.io.gnss_checks import check_gnss_records

        gnss = check_gnss_records(gnss, checks)
    if gnss is None:
        lines.append("  fixes: none (no fix)")
    else:
        t = gnss.t
        rate = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else math.nan
        lines.append(
            f"  fixes: {len(gnss)} ({result.nmea_fixes_added} from NMEA sentences), rate "
            f"{rate:.2f} Hz, time {t[0]:.3f} .. {t[-1]:.3f} POSIX UTC ({t[-1] - t[0]:.1f} s)"
        )
        # Over the fixes as kept, the ones from NMEA sentences among them (the UBX epochs'
        # own histogram left those out: an empty line for a log of NMEA fixes in UBX).
        qualities, counts = np.unique(gnss.fix_quality.astype(int), return_counts=True)
        histogram = ", ".join(f"{q}: {n}" for q, n in zip(qualities, counts, strict=True))
        lines.append(f"  fix quality of the fixes (GGA codes; 0 = flagged invalid): {histogram}")
        lines.append(f"  hAcc: {_stats(gnss.std[:, 0], 'm')}")
        lines.append(f"  vAcc: {_stats(gnss.std[:, 2], 'm')}")
        lines.append(f"  sAcc: {_stats(gnss.velocity_std[:, 0], 'm/s')}")
        for name in ("hdop", "vdop", "pdop"):
            lines.append(f"  {name}: {_stats(getattr(gnss, name), '')}")
        sats = gnss.num_sats[gnss.num_sats >= 0].astype(float)
        lines.append(f"  satellites used: {_stats(sats, '')}")
    imu = result.imu
    if result.imu_source:
        lines.append(f"  IMU: {result.imu_source}, {len(result.imu_tags)} samples")
        for mapping in result.time_maps:
            lines.append(f"    {mapping.describe()}")
    if imu is not None:
        dt = np.diff(imu.t)
        gaps = int(np.sum(dt > 3 * np.median(dt)))
        lines.append(
            f"    rate {imu.rate_hz:.1f} Hz over {imu.t[-1] - imu.t[0]:.1f} s, gaps > 3 periods: "
            f"{gaps} (longest {dt.max():.3f} s)"
        )
        lines.append(
            f"    gyro mean {np.round(imu.gyro.mean(axis=0), 5)} rad/s, accel mean "
            f"{np.round(imu.accel.mean(axis=0), 3)} m/s^2 (receiver IMU axes)"
        )
        temp = result.imu_temp[np.isfinite(result.imu_temp)]
        if temp.size:
            lines.append(f"    gyro temperature {temp.min():.2f} .. {temp.max():.2f} deg C")
    elif not result.imu_source:
        lines.append("  IMU: none (no ESF-RAW/ESF-MEAS with gyro and accelerometer)")
    if result.odometer is not None:
        lines.append(f"  wheel speed: {len(result.odometer.t)} samples")
    if result.wheel_ticks:
        lines.append(f"  wheel ticks: {result.wheel_ticks} values (not used: no tick scale)")
    lines.extend(f"  warning: {w}" for w in [*result.warnings, *checks])
    return "\n".join(lines)


def load_ubx_dataset(
    ubx: list[Path], others: list[Path], *, imu_topic: str | None = None, progress: bool = False
) -> Dataset:
    """A :class:`Dataset` from one UBX log, with its own IMU or an ``imu.csv``/MCAP IMU beside it.

    Another IMU given beside the log replaces the receiver's (it must be on the same time base:
    POSIX UTC seconds). Raises :class:`InputError` for a log without a fix, or without an IMU
    when none is given beside it.
    """
    from fgins.datatypes import Origin

    if len(ubx) > 1:
        raise InputError(f"give one UBX log, got {len(ubx)}: {', '.join(map(str, ubx))}")
    path = ubx[0]
    result = read_ubx(path)
    gnss = require_fix(result)
    warnings = list(result.warnings)
    imu = None
    imu_from = result.imu_source
    if len(others) > 1:
        # Each would replace the receiver's IMU, the last one winning unsaid.
        raise InputError(
            f"beside a UBX log give one IMU (an imu.csv or an MCAP), got {len(others)}: "
            f"{', '.join(map(str, others))}"
        )
    for other in others:
        from fgins.io.mcap_stream import is_mcap

        if other.is_file() and (other.suffix.lower() == ".mcap" or is_mcap(other)):
            from fgins.io.mcap import read_mcap

            mcap = read_mcap(other, imu_topic=imu_topic, progress=progress)
            imu, imu_from = mcap.dataset.imu, f"{other} (MCAP)"
            warnings.extend(mcap.warnings)
        elif other.is_file():
            from fgins.io.csv_pair import csv_kind, read_imu_csv

            if csv_kind(other) != "imu":
                raise InputError(
                    f"{other}: beside a UBX log give an imu.csv (header time,gyro_x,gyro_y,"
                    "gyro_z,accel_x,accel_y,accel_z) or an MCAP with an IMU"
                )
            imu, imu_from = read_imu_csv(other, warnings), str(other)
        else:
            raise InputError(f"{other}: not a file; beside a UBX log give an imu.csv or an MCAP")
    if imu is not None:
        # The receiver's own IMU is not used: what its reader said of it is no finding of
        # this run ("IMU not used; split the log there" beside a good imu.csv; outside tester).
        own = [w for w in result.warnings if w.startswith(("ESF-RAW", "ESF-MEAS"))]
        warnings = [w for w in warnings if w not in own]
        if own:
            warnings.append(
                f"{path}: its own IMU messages ({result.imu_source or 'ESF'}) not used: {imu_from} "
                f"given beside it ({len(own)} note(s) on them left out; `fgins inspect` shows them)"
            )
    if imu is None:
        imu = result.imu
    if imu is None:
        # The reader's own reason (unpaired ESF-MEAS tags, ESF-RAW without timed epochs) is
        # the one line the user needs: name it here, not only in `fgins inspect`.
        esf = [w for w in result.warnings if w.startswith(("ESF-RAW", "ESF-MEAS"))]
        if esf:  # the line that refused it first (samples repeating tags follow a jump back)
            refused = next((w for w in esf if "IMU not use" in w), esf[0])
            reason = f" (the IMU messages are there but unusable: {refused})"
        elif result.imu_source:
            reason = f" ({result.imu_source} present but unusable: see the warnings)"
        else:
            reason = ""
        raise InputError(f"no IMU in {path}{reason}; give an imu.csv beside it")
    usable = gnss.fix_quality >= 1
    first = int(np.flatnonzero(usable)[0])
    return Dataset(
        imu=imu,
        gnss=gnss,
        origin=Origin(*map(float, gnss.lla[first])),
        odometer=result.odometer if imu is result.imu else None,
        name=path.stem,
        warnings=warnings,
        metadata={"ubx_counts": result.counts, "imu_source": imu_from,
                  "ubx_time_maps": [m.describe() for m in result.time_maps],
                  "gnss_epochs_without_fix": result.epochs_without_fix,
                  "gnss_first_epoch_t": result.first_epoch_time,
                  IMU_TIMES_FROM_FIXES_KEY: imu is result.imu},
    )  # fmt: skip


def read_ubx_gnss(path: str | Path, time_offset_s: float = 0.0) -> tuple[GnssData, list[str]]:
    """The fixes of a UBX log (for ``fgins convert``) and the reader's warnings."""
    result = read_ubx(path)
    gnss = require_fix(result) if result.gnss is None else result.gnss
    if time_offset_s:
        gnss.t = gnss.t + time_offset_s
    return gnss, result.warnings


def convert_ubx_imu(path: str | Path, output: str | Path) -> str:
    """``fgins convert LOG --imu -o imu.csv``: write the receiver's IMU; a one-line summary."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not looks_like_ubx(path):
        raise InputError(f"{path}: --imu needs a u-blox UBX log (no valid UBX frame found)")
    if Path(output).suffix.lower() != ".csv":
        raise InputError(f"{output}: --imu writes the imu.csv layout; give an output ending .csv")
    result = read_ubx(path)
    rows = write_ubx_imu_csv(result, output)
    lines = [f"warning: {w}" for w in result.warnings]
    lines.append(
        f"wrote {rows} {result.imu_source} IMU samples ({result.imu.rate_hz:.1f} Hz, receiver "
        f"IMU axes, rad/s and m/s^2, time POSIX UTC) to {output}"
    )
    return "\n".join(lines)
