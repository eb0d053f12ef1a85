"""NMEA 0183 reader: real receiver logs -> :class:`fgins.datatypes.GnssData`.

Sentences are split out of the raw bytes (leading junk, binary noise, CR/LF variants
tolerated), checked and tokenised by pynmea2, then merged into fix epochs by their time of day
(sentences of one fix arrive in any order; some receivers send no GGA). Sentences without a
time (GSA, VTG) belong to the epoch of the latest timed sentence, as in gpsd.

Time (the ``gnss.csv`` convention of DESIGN.md): POSIX UTC seconds when the log carries a
date (RMC/ZDA), else seconds since the UTC midnight of the first epoch; monotonic across
midnight either way. Dates are used as logged (old week-rollover dates are not "fixed"), but
only from an RMC with status A or a ZDA: an RMC with status V carries the receiver's start-up
default before it knows the time (1980-01-05, 2008-01-01...), so its date is ignored (counted
where it disagrees); epochs before the first valid date get it by the midnight rule.

Where the receiver's clock jumps back and new positions reuse times already seen, the first
position of each time is kept and the others counted (as for two receivers in one log).

A GGA with a fix quality but 0 satellites used is no fix (a receiver coasting on its last
position; gpsd reports such epochs as mode 1): its position is not used, counted. So is a GGA
with an empty quality field, and an epoch the receiver marks "no fix" (RMC status V, GSA
mode 1) where no sentence claims a fix (see :func:`_receiver_says_no_fix`).

Heights are ellipsoidal: MSL altitude + geoid separation; where the receiver leaves the
separation empty the EGM2008 grid of :mod:`fgins.io.geoid` supplies it (counted).
Fixes without an altitude (RMC/GLL-only epochs, 2D fixes) get NaN height.
"""

from __future__ import annotations

import calendar
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pynmea2

from fgins.datatypes import GnssData, InputError
from fgins.io.geoid import GEOID_MODEL_NAME, geoid_undulation

KNOT_M_S = 1852.0 / 3600.0
KMH_M_S = 1.0 / 3.6

# One sentence candidate: '$', address, fields, optional '*HH'. Stops at the next '$'.
# '!' starts AIS encapsulation sentences: counted, never decoded.
_SENTENCE_RE = re.compile(r"[$!]([A-Z0-9]{3,12}),([^$!*\r\n]*)(\*[0-9A-Fa-f]{2})?")

# Field counts of complete sentences: a sentence without checksum is accepted only when it has
# at least this many fields, so a line cut short is counted as corrupt instead of half-read.
_MIN_FIELDS = {"GGA": 14, "RMC": 11, "GSA": 17, "GST": 8, "VTG": 8, "ZDA": 6, "GNS": 12, "GLL": 6}

# Mode indicators (RMC/GLL/VTG field 'mode', GNS per-constellation characters) -> GGA codes.
_MODE_TO_QUALITY = {"N": 0, "A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8}
# Best first, for GNS strings with one character per constellation ("RN", "AD"...).
_MODE_RANK = "RFPDAEMSN"

# Position sources, best first: GGA and GNS carry altitude and quality, RMC/GLL only 2D.
_POSITION_PRIORITY = ("GGA", "GNS", "RMC", "GLL")

# Two valid positions for one epoch time further apart than this (horizontal, m) are two
# receivers (interleaved talkers, or logs concatenated), not one fix printed twice (RMC's
# coarser digits, a GGA and a GNS of one solution agree to centimetres).
CONFLICT_DISTANCE_M = 5.0
# Two talkers' positions of one sentence type and time this far apart (m) are two solutions
# (a GPS-only and a multi-GNSS one, or two antennas close together): the kept talker's is
# used, said. One solution printed by two talkers agrees to the format's digits.
NEAR_DISTANCE_M = 1.0
# More epochs than this fraction in conflict: the log is two receivers' streams, an error.
CONFLICT_MAX_FRACTION = 0.5

_Position = tuple[float, float, float, float, int, bool]


@dataclass
class NmeaResult:
    """What :func:`read_nmea` found in one log.

    ``gnss`` holds one row per fix epoch with a usable position; ``counts`` the number of
    well-formed sentences per type ("GGA", "RMC", ..., proprietary ones as "P...");
    ``talkers`` the same per talker ("GP", "GN", ...). ``geoid_modelled`` marks the rows of
    ``gnss`` whose height used the geoid model (their number is ``geoid_from_model``).
    ``epochs_without_fix`` counts epochs with a time but no usable position.
    """

    gnss: GnssData
    counts: dict[str, int]
    corrupt_lines: int
    checksum_failures: int
    warnings: list[str]
    has_date: bool
    geoid_from_model: int
    talkers: dict[str, int] = field(default_factory=dict)
    epochs_without_fix: int = 0
    # Time of the first epoch with a time, with a fix or not (the t0 of outage windows).
    first_epoch_t: float = math.nan
    geoid_modelled: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    epoch_quality_histogram: dict[int, int] = field(default_factory=dict)


class _Epoch:
    """Everything the sentences of one time of day said."""

    __slots__ = (
        "by_talker",
        "course",
        "date",
        "dops",
        "gga_hdop",
        "gga_no_satellites",
        "gsa_prns",
        "gsa_sats",
        "latest",
        "motion_by_talker",
        "num_sats",
        "positions",
        "repeat_distance",
        "repeat_talker",
        "repeats",
        "resolution_ms",
        "said_fix",
        "said_no_fix",
        "speed",
        "std",
        "tod",
        "untrusted_date",
        "vtg_talkers",
    )

    def __init__(self, tod: float, resolution_ms: int = 1) -> None:
        self.tod = tod
        # the coarsest step of the time fields that named this epoch (see _Reader._epoch_at)
        self.resolution_ms = resolution_ms
        # source -> (lat, lon, alt_msl, geoid_sep, quality, valid); the latest of any talker
        self.positions: dict[str, _Position] = {}
        # talker -> source -> position: which receiver stream said what (see _resolve)
        self.by_talker: dict[str, dict[str, _Position]] = {}
        # talker -> (speed, course) of that talker's RMC/VTG
        self.motion_by_talker: dict[str, tuple[float, float]] = {}
        # one talker, one sentence type, two positions far apart (the first is kept)
        self.repeat_distance = 0.0
        self.repeat_talker = ""
        self.repeats = 0  # a talker's later fixes of one sentence type at this time (left out)
        self.latest: dict[tuple[str, str], _Position] = {}  # (talker, type) -> its last repeat
        self.date: tuple[int, int, int] | None = None
        # the date of an RMC with status V: the receiver's guess (its start-up default)
        self.untrusted_date: tuple[int, int, int] | None = None
        self.gga_no_satellites = False  # GGA: quality > 0 with 0 satellites used
        # the receiver's own word on the epoch, any talker (see _receiver_says_no_fix): a fix
        # (GGA/GNS quality > 0, RMC/GLL status A, GSA mode 2/3) or no fix (RMC status V, GSA
        # mode 1)
        self.said_fix = False
        self.said_no_fix = False
        self.dops: tuple[float, float, float] | None = None  # pdop, hdop, vdop from GSA
        self.gga_hdop = math.nan
        self.num_sats = -1
        self.gsa_sats = 0
        self.std: tuple[float, float, float] | None = None
        self.speed = math.nan
        self.course = math.nan
        self.vtg_talkers: set[str] = set()  # talkers whose VTG this epoch took
        self.gsa_prns: set[str] = set()  # satellites its GSAs named


def _num(text: str) -> float:
    """A numeric field; NaN when empty or malformed."""
    try:
        value = float(text)
    except ValueError:
        return math.nan
    return value if math.isfinite(value) else math.nan


def _time_of_day(text: str) -> float:
    """'hhmmss[.ss]' -> seconds since midnight; ValueError when malformed."""
    if len(text) < 6 or not text[:6].isdigit():
        raise ValueError(f"bad time field {text!r}")
    hours, minutes = int(text[0:2]), int(text[2:4])
    seconds = float(text[4:])
    if hours > 23 or minutes > 59 or not 0 <= seconds < 61:
        raise ValueError(f"bad time field {text!r}")
    return hours * 3600 + minutes * 60 + seconds


def _time_resolution_ms(text: str) -> int:
    """The step of a 'hhmmss[.sss]' field in ms: 1000 without decimals, 10 with two."""
    decimals = len(text) - text.index(".") - 1 if "." in text else 0
    return 10 ** (3 - min(decimals, 3))


# Sentences of one epoch whose time fields differ by less than the coarser field's step are
# one epoch when that step is at most this (0.1 s: a 10 Hz receiver's next epoch is a full
# step later; a whole-second field is never matched to a fractional one).
EPOCH_MERGE_MAX_MS = 100


def _angle(text: str, hemisphere: str, degree_digits: int) -> float:
    """'dddmm.mmmm' + hemisphere -> signed degrees; NaN when empty or malformed."""
    if len(text) <= degree_digits or hemisphere not in "NSEW" or not hemisphere:
        return math.nan
    try:
        degrees = int(text[:degree_digits])
        minutes = float(text[degree_digits:])
    except ValueError:
        return math.nan
    if not (0 <= minutes < 60 and math.isfinite(minutes)):
        return math.nan
    value = degrees + minutes / 60.0
    limit = 90.0 if degree_digits == 2 else 180.0
    if value > limit:
        return math.nan
    return -value if hemisphere in "SW" else value


def _lat_lon(fields: list[str], start: int) -> tuple[float, float]:
    return _angle(fields[start], fields[start + 1], 2), _angle(
        fields[start + 2], fields[start + 3], 3
    )


def _field(fields: list[str], index: int) -> str:
    return fields[index].strip() if index < len(fields) else ""


def _mode_quality(mode: str) -> int:
    """Best quality among mode characters ('A', 'D', 'RR', 'AN'...); -1 when absent."""
    present = [c for c in mode.upper() if c in _MODE_TO_QUALITY]
    if not present:
        return -1
    best = min(present, key=_MODE_RANK.index)
    return _MODE_TO_QUALITY[best]


def _distance_m(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Horizontal distance (m) between two (lat, lon, ...) positions metres apart (the WGS-84
    radii of curvature at the first one)."""
    e2 = 6.69437999014e-3
    w = 1.0 - e2 * math.sin(math.radians(a[0])) ** 2
    north = math.radians(a[0] - b[0]) * 6_378_137.0 * (1.0 - e2) / w**1.5
    east = math.radians(a[1] - b[1]) * 6_378_137.0 / math.sqrt(w) * math.cos(math.radians(a[0]))
    return math.hypot(east, north)


def _checksum_ok(sentence: str) -> bool:
    """True when the '*HH' checksum matches or is absent (some old receivers send none)."""
    body, star, given = sentence[1:].partition("*")
    if not star:
        return True
    computed = 0
    for char in body:
        computed ^= ord(char)
    return given.upper() == f"{computed:02X}"


def _split_sentences(line: str) -> tuple[list[str], bool]:
    """Sentence candidates in one line, and whether the line held anything else but noise."""
    found = [m.group(0) for m in _SENTENCE_RE.finditer(line)]
    return found, bool(found)


class _Reader:
    """Stateful pass over the lines of one log."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self.talkers: Counter[str] = Counter()
        self.corrupt = 0
        self.checksum_failures = 0
        self.epochs: dict[int, _Epoch] = {}
        self.current: _Epoch | None = None
        self.day = 0
        self.last_tod: float | None = None
        self.untimed_before_first = 0
        self.orphan_vtg = 0  # VTGs after an epoch's own, before the next time (see _on_vtg)
        self.orphan_gsa = 0  # GSAs naming satellites the epoch's GSAs named (see _on_gsa)
        self.backward_jumps = 0
        self.talker = ""  # the talker of the sentence being handled
        # the sentence being handled is stamped with an earlier time than the log already
        # reached, of an epoch that exists: the receiver's clock jumped back (see _set_position)
        self.stamped_back = False

    # -- line level -------------------------------------------------------------------------
    def feed_line(self, line: str) -> None:
        # '|' is reserved in NMEA 0183; gpsd's logs use it to mark TCP segment boundaries
        # inside a sentence. Dropping it is safe: the checksum still guards the sentence.
        stripped = line.replace("|", "").strip()
        if not stripped:
            return
        candidates, _ = _split_sentences(stripped)
        if not candidates:
            # '#' lines are comments (gpsd log headers); anything else without a sentence is
            # noise. A '#' glued to a real sentence is noise before '$', handled above.
            self.corrupt += not stripped.startswith("#")
            return
        for sentence in candidates:
            self.feed_sentence(sentence)

    def feed_sentence(self, sentence: str) -> None:
        address = sentence[1:].split(",", 1)[0].upper()
        kind = address[2:] if not address.startswith("P") and len(address) == 5 else ""
        if kind not in _MIN_FIELDS:
            # Not decoded here (proprietary, AIS, GSV...): only its checksum matters.
            if _checksum_ok(sentence):
                self._count(sentence)
            else:
                self.checksum_failures += 1
            return
        try:
            message = pynmea2.parse(sentence)
        except pynmea2.ChecksumError:
            self.checksum_failures += 1
            return
        except pynmea2.SentenceTypeError:
            self._count(sentence)  # well-formed, just a type pynmea2 does not know
            return
        except Exception:  # pynmea2 raises ParseError, ValueError, AttributeError...
            self.corrupt += 1
            return
        fields = [str(f) for f in message.data]
        if "*" not in sentence and len(fields) < _MIN_FIELDS.get(kind, 0):
            self.corrupt += 1  # no checksum and too short: a truncated line
            return
        handler = getattr(self, f"_on_{kind.lower()}", None)
        self.talker = address[:2]
        if handler is not None:
            try:
                handler(fields)
            except (ValueError, IndexError):
                self.corrupt += 1
                return
        self._count(sentence)

    def _count(self, sentence: str) -> None:
        address = sentence[1:].split(",", 1)[0].upper()
        if sentence.startswith("!"):
            self.counts["AIS"] += 1
        elif address.startswith("P"):
            self.counts[address[:4]] += 1
            self.talkers["P"] += 1
        else:
            self.counts[address[2:]] += 1
            self.talkers[address[:2]] += 1

    # -- epoch bookkeeping ------------------------------------------------------------------
    def _epoch_at(self, tod_text: str) -> _Epoch:
        tod = _time_of_day(tod_text)
        day = self.day
        self.stamped_back = False
        if self.last_tod is None:
            self.last_tod = tod
        elif tod < self.last_tod - 43200.0:  # passed midnight
            self.day += 1
            day = self.day
            self.last_tod = tod
        elif tod > self.last_tod + 43200.0 and self.day > 0:  # a late sentence of yesterday
            day = self.day - 1
        else:
            self.stamped_back = tod < self.last_tod - 1.5
            self.backward_jumps += self.stamped_back
            self.last_tod = max(self.last_tod, tod)
        key = day * 86_400_000 + round(tod * 1000)
        resolution = _time_resolution_ms(tod_text)
        epoch = self.epochs.get(key)
        if epoch is None and (current := self.current) is not None:
            # One epoch's sentences with time fields of different resolutions (Magellan: GLL
            # 200619.295, GGA and RMC 200619.30) are one fix, not two 5 ms apart (each
            # position counted twice, "200 Hz" with gaps): the latest epoch within the
            # coarser field's step, at most EPOCH_MERGE_MAX_MS, is this one, at the finer time.
            step = max(resolution, current.resolution_ms)
            apart = abs((day * 86400.0 + tod) - current.tod) * 1000.0
            if step <= EPOCH_MERGE_MAX_MS and apart < step - 1e-6:
                epoch = current
                if resolution < current.resolution_ms:
                    epoch.tod, epoch.resolution_ms = day * 86400.0 + tod, resolution
        self.stamped_back = self.stamped_back and epoch is not None
        if epoch is None:
            epoch = self.epochs[key] = _Epoch(day * 86400.0 + tod, resolution)
        self.current = epoch
        return epoch

    def _set_position(self, epoch: _Epoch, source: str, position: _Position) -> bool:
        """Store one sentence's position, per talker too. A talker repeating a sentence type
        at one time with a position far from its first is a second receiver: first kept.

        After the receiver's clock jumped back (Humminbird M37: 19:41:24 -> 19:41:11, then
        new positions under the old times), any sentence type counts: the epoch's GLL came
        from the first pass, its GGA from the second, and preferring GGA made a zigzag of
        both passes. Otherwise types are not compared with each other: some receivers stamp
        RMC a second late (CH-4701), GGA's position is the one of its time. False when the
        position was left out."""
        own = epoch.by_talker.setdefault(self.talker, {})
        # (a faster receiver's fixes of one second are compared each with the one before it)
        previous = epoch.latest.get((self.talker, source), own.get(source))
        earlier = own.values() if self.stamped_back else [previous]
        if position[5]:
            distance = max(
                (_distance_m(first, position) for first in earlier if first and first[5]),
                default=0.0,
            )
            if distance > CONFLICT_DISTANCE_M:
                epoch.repeat_distance = max(epoch.repeat_distance, distance)
                epoch.repeat_talker = self.talker
                return False
            first = own.get(source)
            if first is not None and first[5]:
                # The talker's second fix of this type at this time: a receiver faster than
                # its time field (5-10 Hz printing whole seconds, whose fixes of one second
                # all say its start). The first is the one of that time; the last had been
                # kept, 0.8-0.9 s late, the loss unsaid and blamed on receiver latency
                # (outside tester). A byte-identical repeat is a duplicated line.
                epoch.repeats += position[:5] != first[:5]
                epoch.latest[(self.talker, source)] = position
                return False
        own[source] = position
        epoch.positions[source] = position
        return True

    def _set_motion(self, epoch: _Epoch, speed: float, course: float) -> None:
        old_speed, old_course = epoch.motion_by_talker.get(self.talker, (math.nan, math.nan))
        if math.isfinite(speed):
            epoch.speed = old_speed = speed
        if math.isfinite(course):
            epoch.course = old_course = course
        epoch.motion_by_talker[self.talker] = (old_speed, old_course)

    def _untimed_epoch(self) -> _Epoch | None:
        if self.current is None:
            self.untimed_before_first += 1
        return self.current

    # -- sentence handlers (fields as strings; IndexError/ValueError -> corrupt) -------------
    def _on_gga(self, f: list[str]) -> None:
        if not f[0]:
            return
        epoch = self._epoch_at(f[0])
        lat, lon = _lat_lon(f, 1)
        # An empty quality field is no fix (MyGuide 3100 sends its "no fix" epochs so, next
        # to RMC status V and GSA mode 1; gpsd reports them as mode 1), as is 0.
        quality_text = f[5].strip()
        quality = int(quality_text) if quality_text.isdigit() else 0
        sats = _field(f, 6)
        if sats.isdigit():
            # The largest count of the epoch's GGA/GNS sentences: one talker's GGA (GPGGA 03,
            # GAGGA 01) beside a GNGNS of all systems (08) counts one constellation (gpsd: 8).
            epoch.num_sats = max(epoch.num_sats, int(sats))
        epoch.gga_hdop = _num(_field(f, 7))
        alt = _num(_field(f, 8))
        sep = _num(_field(f, 10))
        valid = quality > 0 and math.isfinite(lat) and math.isfinite(lon)
        # A quality with 0 satellites used (an empty field is unknown, not 0) is a receiver
        # coasting on its last position: no fix, as gpsd reads it (hemi: 15 such epochs).
        if valid and sats.isdigit() and int(sats) == 0:
            valid = False
            epoch.gga_no_satellites = True
        epoch.said_fix |= valid
        self._set_position(epoch, "GGA", (lat, lon, alt, sep, quality, valid))

    def _on_gns(self, f: list[str]) -> None:
        if not f[0]:
            return
        epoch = self._epoch_at(f[0])
        lat, lon = _lat_lon(f, 1)
        quality = max(_mode_quality(_field(f, 5)), 0)
        sats = _field(f, 6)
        if sats.isdigit():
            epoch.num_sats = max(epoch.num_sats, int(sats))
        if not math.isfinite(epoch.gga_hdop):
            epoch.gga_hdop = _num(_field(f, 7))
        valid = quality > 0 and math.isfinite(lat) and math.isfinite(lon)
        sep = _num(_field(f, 9))
        epoch.said_fix |= valid
        self._set_position(epoch, "GNS", (lat, lon, _num(_field(f, 8)), sep, quality, valid))

    def _on_rmc(self, f: list[str]) -> None:
        if not f[0]:
            return
        epoch = self._epoch_at(f[0])
        date = _field(f, 8)
        if len(date) == 6 and date.isdigit():
            day, month, year = int(date[:2]), int(date[2:4]), int(date[4:])
            year += 1900 if year >= 80 else 2000
            if 1 <= month <= 12 and 1 <= day <= 31:
                # Status V: the receiver does not know the time yet either; its date is the
                # firmware's start-up default (MTK-3301: 1980-01-05), not the day.
                if f[1] == "A":
                    epoch.date = (year, month, day)
                else:
                    epoch.untrusted_date = (year, month, day)
        epoch.said_no_fix |= f[1] == "V"
        lat, lon = _lat_lon(f, 2)
        mode = _mode_quality(_field(f, 11))
        valid = f[1] == "A" and mode != 0 and math.isfinite(lat) and math.isfinite(lon)
        quality = mode if mode > 0 else 1
        epoch.said_fix |= valid
        if self._set_position(epoch, "RMC", (lat, lon, math.nan, math.nan, quality, valid)):
            self._set_motion(epoch, _num(_field(f, 6)) * KNOT_M_S, _num(_field(f, 7)))

    def _on_gll(self, f: list[str]) -> None:
        if len(f) < 6 or not f[4]:
            return
        epoch = self._epoch_at(f[4])
        lat, lon = _lat_lon(f, 0)
        mode = _mode_quality(_field(f, 6))
        valid = f[5] == "A" and mode != 0 and math.isfinite(lat) and math.isfinite(lon)
        quality = mode if mode > 0 else 1
        epoch.said_fix |= valid
        self._set_position(epoch, "GLL", (lat, lon, math.nan, math.nan, quality, valid))

    def _on_zda(self, f: list[str]) -> None:
        if not f[0]:
            return
        epoch = self._epoch_at(f[0])
        if f[1].isdigit() and f[2].isdigit() and f[3].isdigit():
            day, month, year = int(f[1]), int(f[2]), int(f[3])
            if 1 <= month <= 12 and 1 <= day <= 31 and year >= 1980:
                epoch.date = (year, month, day)

    def _on_gst(self, f: list[str]) -> None:
        if not f[0]:
            return
        epoch = self._epoch_at(f[0])
        sigma_lat, sigma_lon, sigma_alt = (_num(_field(f, i)) for i in (5, 6, 7))
        if any(math.isfinite(s) for s in (sigma_lat, sigma_lon, sigma_alt)):
            epoch.std = (sigma_lon, sigma_lat, sigma_alt)

    def _on_gsa(self, f: list[str]) -> None:
        epoch = self._untimed_epoch()
        if epoch is None:
            return
        prns = {prn.strip() for prn in f[2:14] if prn.strip()}
        if prns & epoch.gsa_prns:
            # Satellites this epoch's GSAs named already: the next epoch's set, whose timed
            # sentences were lost (one GSA per constellation names disjoint satellites). It
            # had added its count to this epoch's (18 where the receiver used 9: outside
            # tester) and replaced its DOPs. Left out, counted with the VTGs.
            self.orphan_gsa += 1
            return
        epoch.gsa_prns |= prns
        epoch.said_fix |= f[1].strip() in ("2", "3")
        epoch.said_no_fix |= f[1].strip() == "1"
        pdop, hdop, vdop = (_num(_field(f, i)) for i in (14, 15, 16))
        if any(math.isfinite(d) for d in (pdop, hdop, vdop)):
            epoch.dops = (pdop, hdop, vdop)
        epoch.gsa_sats += len(prns)

    def _on_vtg(self, f: list[str]) -> None:
        epoch = self._untimed_epoch()
        if epoch is None:
            return
        if self.talker in epoch.vtg_talkers:
            # A second VTG of one talker before a new time: the next epoch's, whose timed
            # sentences were lost; it had replaced this epoch's speed and course (by up to
            # 3.6 m/s: outside tester). Left out, counted.
            self.orphan_vtg += 1
            return
        epoch.vtg_talkers.add(self.talker)
        course = _num(f[0])
        knots = _num(_field(f, 4))
        kmh = _num(_field(f, 6))
        speed = knots * KNOT_M_S if math.isfinite(knots) else kmh * KMH_M_S
        self._set_motion(epoch, speed, course)


def _receiver_says_no_fix(epoch: _Epoch) -> bool:
    """The receiver itself marks the epoch "no fix" (RMC status V, GSA mode 1) and none of
    its sentences claims a fix (GGA/GNS quality > 0, RMC/GLL status A, GSA mode 2/3: a
    multi-constellation receiver sends a GSA per system, and a Garmin in simulator mode RMC
    V next to a quality-8 GGA, which gpsd reports as a fix). gpsd reports such epochs as
    mode 1 (MyGuide 3100: GGA with an empty quality, RMC V, GSA 1): a position there is the
    receiver's last or dead-reckoned guess, not a fix."""
    return epoch.said_no_fix and not epoch.said_fix


def _epoch_position(
    positions: dict[str, _Position],
) -> tuple[float, float, float, float, int] | None:
    """(lat, lon, alt_msl, geoid_sep, quality) from the best valid source, or None."""
    for source in _POSITION_PRIORITY:
        pos = positions.get(source)
        if pos is not None and pos[5]:
            lat, lon, alt, sep, quality, _ = pos
            if not math.isfinite(alt):  # a 2D source: borrow altitude from GGA/GNS if any
                for other in ("GGA", "GNS"):
                    alt_pos = positions.get(other)
                    if alt_pos is not None and math.isfinite(alt_pos[2]):
                        alt, sep = alt_pos[2], alt_pos[3]
                        break
            return lat, lon, alt, sep, quality
    return None


@dataclass
class _Conflicts:
    """Epochs where two receivers' positions met at one time (see CONFLICT_DISTANCE_M)."""

    kept: str = ""  # the talker whose positions are used where talkers disagree
    talker_distances: list[float] = field(default_factory=list)
    dropped_talkers: Counter[str] = field(default_factory=Counter)
    repeat_distances: list[float] = field(default_factory=list)
    repeat_talkers: Counter[str] = field(default_factory=Counter)
    epochs: int = 0  # epochs with either kind of conflict
    # talkers whose positions of one sentence type differ by NEAR_DISTANCE_M to
    # CONFLICT_DISTANCE_M for one time (two solutions of a receiver, or two receivers close)
    near_distances: list[float] = field(default_factory=list)


# Fix qualities (GGA codes) by precision, for choosing among talkers: RTK fixed, float,
# differential (DGPS, PPS, SBAS), autonomous, dead reckoning.
_QUALITY_PRECISION = {4: 5, 5: 4, 2: 3, 3: 3, 9: 3, 1: 2, 6: 1}


def _kept_talker(epochs: list[_Epoch]) -> str:
    """The talker with a valid position in most epochs, then with the more precise fixes (an
    RTK GNGGA beside a GPS-only autonomous GPGGA: the GPGGA had been taken, a 2 cm log
    "diverged"), then with most valid position sentences (a GPGGA + GPRMC receiver against
    a GLGGA one), then the first seen."""
    counts: Counter[str] = Counter()
    precision: Counter[str] = Counter()
    sentences: Counter[str] = Counter()
    for epoch in epochs:
        for talker, positions in epoch.by_talker.items():
            if (position := _epoch_position(positions)) is not None:
                counts[talker] += 1
                precision[talker] += _QUALITY_PRECISION.get(position[4], 0)
                sentences[talker] += sum(bool(p[5]) for p in positions.values())
    return (
        max(counts, key=lambda talker: (counts[talker], precision[talker], sentences[talker]))
        if counts
        else ""
    )


def _combined_positions(epoch: _Epoch, reference: str) -> tuple[dict[str, _Position], float]:
    """The epoch's positions by sentence type, ``reference``'s first, and how far apart
    (m) other talkers put a sentence type that it also gives with a fix."""
    own = epoch.by_talker.get(reference, {})
    combined = dict(own)
    apart = 0.0
    for talker, positions in epoch.by_talker.items():
        if talker == reference:
            continue
        for source, position in positions.items():
            mine = combined.get(source)
            if mine is None or (position[5] and not mine[5]):
                combined[source] = position
            elif mine[5] and position[5] and source in own:
                apart = max(apart, _distance_m(own[source], position))
    return combined, apart


def _resolve(
    epoch: _Epoch, conflicts: _Conflicts
) -> tuple[tuple[float, float, float, float, int] | None, float, float]:
    """The epoch's position, speed and course. Talkers that agree are merged (one receiver
    printing GN and GP sentences); talkers that disagree are two receivers: the kept
    talker's stream is used and the epoch counted."""
    if epoch.repeat_distance > 0:
        conflicts.repeat_distances.append(epoch.repeat_distance)
        conflicts.repeat_talkers[epoch.repeat_talker] += 1
    merged = (_epoch_position(epoch.positions), epoch.speed, epoch.course)
    valid = {
        talker: position
        for talker, positions in epoch.by_talker.items()
        if (position := _epoch_position(positions)) is not None
    }
    reference = conflicts.kept if conflicts.kept in valid else next(iter(valid), "")
    far = {
        talker: distance
        for talker, position in valid.items()
        if talker != reference
        and (distance := _distance_m(valid[reference], position)) > CONFLICT_DISTANCE_M
    }
    conflicts.epochs += bool(far) or epoch.repeat_distance > 0
    if not far:
        if not valid:
            return merged
        # Talkers within CONFLICT_DISTANCE_M: the kept talker's sentences first, another
        # talker's for a sentence type the kept one does not send or sends without a fix
        # (GNRMC + GPGGA of one solution). The latest of any talker had been taken: a GLGGA
        # 3 m from each GPGGA made the track the last one printed, or a zigzag of both
        # (1.5-3 m off at z 6-17, unsaid), and NMEA 4.10's per-constellation GPGNS/GLGNS
        # with empty position fields after each GNGNS wiped its position (a GNS log refused
        # as "no usable GNSS fix", a GNS+RMC one left without heights: outside tester).
        combined, apart = _combined_positions(epoch, reference)
        if apart > NEAR_DISTANCE_M:
            conflicts.near_distances.append(apart)
        speed, course = epoch.motion_by_talker.get(reference, (math.nan, math.nan))
        return (
            _epoch_position(combined),
            speed if math.isfinite(speed) else epoch.speed,
            course if math.isfinite(course) else epoch.course,
        )
    conflicts.talker_distances.append(max(far.values()))
    conflicts.dropped_talkers.update(far)
    speed, course = epoch.motion_by_talker.get(reference, (math.nan, math.nan))
    return valid[reference], speed, course


def _conflict_messages(path: Path, conflicts: _Conflicts, n_fixes: int) -> list[str]:
    """Warnings for a few epochs with two receivers' positions; InputError for most."""
    parts = []
    if conflicts.talker_distances:
        dropped = "/".join(sorted(conflicts.dropped_talkers))
        parts.append(
            f"talkers {conflicts.kept} and {dropped} give positions "
            f"{np.median(conflicts.talker_distances):.0f} m apart (median) for one time in "
            f"{len(conflicts.talker_distances)} epoch(s)"
        )
    if conflicts.repeat_distances:
        talkers = "/".join(sorted(conflicts.repeat_talkers))
        parts.append(
            f"talker {talkers} gives two positions {np.median(conflicts.repeat_distances):.0f} m "
            f"apart (median) for one time in {len(conflicts.repeat_distances)} epoch(s)"
        )
    near = []
    if conflicts.near_distances:
        near = [
            f"two positions for one time: talkers give positions of one sentence type "
            f"{np.median(conflicts.near_distances):.1f} m apart (median) for one time in "
            f"{len(conflicts.near_distances)} epoch(s) (under {CONFLICT_DISTANCE_M:g} m: two "
            "solutions of one receiver, or two receivers close together); kept talker "
            f"{conflicts.kept}'s positions there"
        ]
    if not parts:
        return near
    if conflicts.epochs > CONFLICT_MAX_FRACTION * n_fixes:
        advice = (
            f"split it by talker (e.g. keep only the ${conflicts.kept} lines) and give one receiver's log"
            if not conflicts.repeat_distances
            else "give each receiver's (or each session's) log on its own"
        )
        raise InputError(
            f"{path}: two receivers in one log: {'; '.join(parts)} ({conflicts.epochs} of "
            f"{n_fixes} fix epochs); {advice}"
        )
    kept = []
    if conflicts.talker_distances:
        kept.append(f"kept talker {conflicts.kept}'s positions there")
    if conflicts.repeat_distances:
        kept.append("kept the first position given for each such time")
    return [f"two positions for one time: {'; '.join(parts)}; {' and '.join(kept)}", *near]


def _read_lines(path: Path) -> list[str]:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read NMEA log ({exc.strerror}); check the path") from None
    # latin-1 maps every byte to one character, so binary noise never stops decoding.
    return raw.decode("latin-1").splitlines()


def _parse(path: Path) -> _Reader:
    reader = _Reader()
    for line in _read_lines(path):
        reader.feed_line(line)
    return reader


def read_nmea(path: str | Path, *, time_offset_s: float = 0.0) -> NmeaResult:
    """Read an NMEA 0183 log into fix epochs (see the module docstring for conventions).

    Raises :class:`fgins.datatypes.InputError` when the file cannot be read or holds no usable fix.
    """
    path = Path(path)
    reader = _parse(path)
    return _assemble(path, reader, time_offset_s)


def _assemble(path: Path, reader: _Reader, time_offset_s: float) -> NmeaResult:
    epochs = [reader.epochs[k] for k in sorted(reader.epochs)]
    warnings: list[str] = []
    if reader.backward_jumps:
        warnings.append(f"time of day went backwards {reader.backward_jumps} times")
    if reader.untimed_before_first:
        warnings.append(
            f"{reader.untimed_before_first} GSA/VTG sentences before the first timed sentence"
        )
    if repeats := sum(epoch.repeats for epoch in reader.epochs.values()):
        coarse = sum(bool(e.repeats) and e.resolution_ms >= 1000 for e in reader.epochs.values())
        why = (
            " (a receiver faster than 1 Hz printing whole-second times: each time is its "
            "second's start)"
            if coarse > 0.5 * sum(bool(e.repeats) for e in reader.epochs.values())
            else ""
        )
        warnings.append(
            f"{repeats} position sentence(s) repeat their talker's sentence type for one time "
            f"with another position{why}: the first of each time kept, the others not used"
        )
    if reader.orphan_vtg or reader.orphan_gsa:
        found = [f"{n} {kind} sentence(s)" for n, kind in ((reader.orphan_vtg, "VTG"), (reader.orphan_gsa, "GSA")) if n]
        warnings.append(
            f"{' and '.join(found)} after their epoch's own and before the next time (an epoch "
            "whose timed sentences were lost): not used"
        )

    # Time base: seconds since the first epoch's UTC midnight, moved to POSIX by a date.
    seconds = np.array([e.tod for e in epochs], dtype=float)
    dated = [(i, e.date) for i, e in enumerate(epochs) if e.date is not None]
    has_date = bool(dated)
    if has_date:
        first_index, (year, month, day) = dated[0]
        midnight = calendar.timegm((year, month, day, 0, 0, 0))
        base = midnight - math.floor(seconds[first_index] / 86400.0) * 86400.0
        day_of = {i: calendar.timegm((*d, 0, 0, 0)) for i, d in dated}
        inconsistent = sum(
            1 for i, m in day_of.items() if m != base + math.floor(seconds[i] / 86400.0) * 86400
        )
        if inconsistent:
            warnings.append(f"{inconsistent} epochs whose date disagrees with the first date")
        ignored = sum(
            1
            for s, e in zip(seconds, epochs, strict=True)
            if e.date is None
            and e.untrusted_date is not None
            and calendar.timegm((*e.untrusted_date, 0, 0, 0))
            != base + math.floor(s / 86400.0) * 86400
        )
        if ignored:
            warnings.append(
                f"{ignored} RMC sentence(s) with status V (not valid) carry another date "
                "(the receiver's start-up default): ignored, the date of the valid ones used"
            )
        seconds = seconds + base
    elif any(e.untrusted_date is not None for e in epochs):
        warnings.append(
            "the log's only dates are in RMC sentences with status V (not valid: the "
            "receiver's start-up default): not used; times are seconds since UTC midnight"
        )

    rows: list[tuple[float, ...]] = []
    quality_histogram: Counter[int] = Counter()
    without_fix = 0
    no_satellites = 0
    conflicts = _Conflicts(kept=_kept_talker(epochs))
    receiver_no_fix = 0
    for t, epoch in zip(seconds, epochs, strict=True):
        said_no_fix = _receiver_says_no_fix(epoch)
        position, speed, course = (None, 0.0, 0.0) if said_no_fix else _resolve(epoch, conflicts)
        if position is None:
            without_fix += 1
            receiver_no_fix += said_no_fix
            no_satellites += epoch.gga_no_satellites and not said_no_fix
            gga = epoch.positions.get("GGA")
            quality_histogram[gga[4] if gga and not said_no_fix else 0] += 1
            continue
        lat, lon, alt, sep, quality = position
        quality_histogram[quality] += 1
        pdop, hdop, vdop = epoch.dops if epoch.dops else (math.nan, epoch.gga_hdop, math.nan)
        if not math.isfinite(hdop):
            hdop = epoch.gga_hdop
        std = epoch.std or (math.nan, math.nan, math.nan)
        sats = epoch.num_sats if epoch.num_sats >= 0 else (epoch.gsa_sats or -1)
        rows.append(
            (
                t,
                lat,
                lon,
                alt,
                sep,
                *std,
                hdop,
                vdop,
                pdop,
                quality,
                sats,
                speed,
                course,
            )
        )
    if not rows:
        sentences = sum(reader.counts.values())
        if not sentences and not reader.checksum_failures and not _has_dollar(path):
            raise _not_a_log(path)  # a config file, a note: not an NMEA log all "corrupt"
        what = (
            "most of the file is not NMEA: another receiver protocol (SiRF, TSIP, RTCM, ...)? "
            "fgins reads NMEA 0183 and u-blox UBX logs"
            if reader.corrupt > sentences
            else "check that the receiver had a fix and the file is NMEA 0183"
        )
        raise InputError(
            f"{path}: no usable GNSS fix in {sentences} NMEA sentences ({reader.corrupt} "
            f"corrupt lines, {reader.checksum_failures} checksum failures); {what}"
        )
    warnings.extend(_conflict_messages(path, conflicts, len(rows)))
    table = np.array(rows, dtype=float)
    lat, lon, alt_msl, sep = table[:, 1], table[:, 2], table[:, 3], table[:, 4]
    modelled = np.isfinite(alt_msl) & ~np.isfinite(sep)
    if modelled.any():
        sep = sep.copy()
        sep[modelled] = geoid_undulation(lat[modelled], lon[modelled])
    height = alt_msl + np.where(np.isfinite(sep), sep, 0.0)
    speed, course = table[:, 13], table[:, 14]
    course_rad = np.radians(course)
    velocity = np.column_stack(
        [speed * np.sin(course_rad), speed * np.cos(course_rad), np.full(len(table), np.nan)]
    )
    if without_fix:
        reasons = []
        if receiver_no_fix:
            reasons.append(
                f"{receiver_no_fix} of them marked no fix by the receiver (RMC status V or GSA "
                "mode 1 with no sentence saying otherwise)"
            )
        if no_satellites:
            reasons.append(
                f"{no_satellites} of them GGA with a fix quality but 0 satellites used: no fix, "
                "as gpsd reads them"
            )
        why = f" ({'; '.join(reasons)})" if reasons else ""
        warnings.append(f"{without_fix} epochs without a usable position were skipped{why}")
    if reader.corrupt or reader.checksum_failures:
        warnings.append(
            f"skipped {reader.corrupt} corrupt or truncated line(s) and "
            f"{reader.checksum_failures} sentence(s) failing their checksum"
        )
    if modelled.any():
        warnings.append(
            f"{int(modelled.sum())} epochs without geoid separation: used {GEOID_MODEL_NAME}"
        )
    gnss = GnssData(
        t=table[:, 0] + time_offset_s,
        lla=np.column_stack([lat, lon, height]),
        velocity=velocity,
        std=table[:, 5:8],
        hdop=table[:, 8],
        vdop=table[:, 9],
        pdop=table[:, 10],
        fix_quality=table[:, 11],
        num_sats=table[:, 12],
        speed=speed,
        course=course,
    )
    return NmeaResult(
        gnss=gnss,
        counts=dict(reader.counts),
        corrupt_lines=reader.corrupt,
        checksum_failures=reader.checksum_failures,
        warnings=warnings,
        has_date=has_date,
        geoid_from_model=int(modelled.sum()),
        talkers=dict(reader.talkers),
        epochs_without_fix=without_fix,
        first_epoch_t=float(seconds[0]) + time_offset_s if len(seconds) else math.nan,
        geoid_modelled=modelled,
        epoch_quality_histogram=dict(quality_histogram),
    )


def _stats(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return "n/a"
    return f"{finite.min():.2f} / {np.median(finite):.2f} / {finite.max():.2f}"


_SENTENCE_START = re.compile(rb"[$!][A-Z]{4,6},")


def _has_dollar(path: Path) -> bool:
    """Whether the file's first 64 KiB hold an NMEA sentence start ('$' or '!', a talker and
    type, a comma), even of a corrupt sentence. A bare '$' is not one: a README with shell
    prompts and prices was summarised as an NMEA log "not usable", at exit 0."""
    with path.open("rb") as handle:
        return _SENTENCE_START.search(handle.read(65536)) is not None


def _not_a_log(path: Path) -> InputError:
    return InputError(
        f"{path}: not a log fgins reads: no NMEA sentence, UBX frame, MCAP or bag, and no "
        "CSV header fgins knows (imu.csv, gnss.csv, baro.csv, wheel.csv, accel_array.csv)"
    )


def summarize_nmea(path: str | Path) -> str:
    """A human-readable report of one NMEA log (what ``fgins inspect FILE.nmea`` prints)."""
    path = Path(path)
    reader = _parse(path)
    if not reader.counts and reader.checksum_failures == 0 and not _has_dollar(path):
        # Not one sentence: not an NMEA log at all (a config file, a text note), rather
        # than an NMEA log whose every line is "corrupt".
        raise _not_a_log(path)
    lines = [f"NMEA log {path}"]
    by_type = ", ".join(f"{k} {v}" for k, v in sorted(reader.counts.items()))
    by_talker = ", ".join(f"{k} {v}" for k, v in sorted(reader.talkers.items()))
    lines.append(f"  sentences by type:   {by_type or 'none'}")
    lines.append(f"  sentences by talker: {by_talker or 'none'}")
    lines.append(
        f"  corrupt lines: {reader.corrupt}, checksum failures: {reader.checksum_failures}"
    )
    try:
        result = _assemble(path, reader, 0.0)
    except InputError as error:
        lines.append(f"  not usable: {error}")
        return "\n".join(lines)
    from fgins.io.gnss_checks import check_gnss_records

    # The records' checks ``fgins convert`` makes: DOP placeholders (0.00, 99.99) are missing
    # in the DOP statistics too, counted in a warning; quality 6-8 fixes said.
    checks: list[str] = []
    gnss = check_gnss_records(result.gnss, checks)
    t = gnss.t
    period = float(np.median(np.diff(t))) if len(t) > 1 else math.nan
    lines.append(
        f"  fixes: {len(gnss)} (+{result.epochs_without_fix} epochs without a position), "
        f"rate {1.0 / period if period > 0 else math.nan:.2f} Hz"
    )
    time_kind = "POSIX UTC (date found)" if result.has_date else "seconds of day (no date)"
    lines.append(f"  time span: {t[0]:.3f} .. {t[-1]:.3f} s ({t[-1] - t[0]:.1f} s), {time_kind}")
    histogram = ", ".join(f"{q}: {n}" for q, n in sorted(result.epoch_quality_histogram.items()))
    lines.append(f"  fix quality histogram (GGA codes): {histogram}")
    for name in ("hdop", "vdop", "pdop"):
        lines.append(f"  {name} min / median / max: {_stats(getattr(gnss, name))}")
    if len(t) > 1 and period > 0:
        gaps = np.flatnonzero(np.diff(t) > 3 * period)
        lines.append(f"  gaps > 3 periods: {len(gaps)}")
        lines.extend(
            f"    {t[i]:.3f} -> {t[i + 1]:.3f} ({t[i + 1] - t[i]:.1f} s)" for i in gaps[:10]
        )
    heights = int(np.isfinite(gnss.lla[:, 2]).sum()) if len(gnss) else 0
    if heights == 0:
        # RMC/GLL only: no height to convert, nothing from the receiver (it was said to be).
        source = "none needed: no fix has a height (2-D only)"
    elif result.geoid_from_model:
        source = f"{GEOID_MODEL_NAME} for {result.geoid_from_model} epochs"
    else:
        source = "receiver (GGA/GNS separation)"
    lines.append(f"  geoid separation: {source}")
    if 0 < heights < len(gnss):
        lines.append(f"  heights: {heights} of {len(gnss)} fixes (the others 2-D)")
    lines.extend(f"  warning: {w}" for w in [*result.warnings, *checks])
    return "\n".join(lines)
