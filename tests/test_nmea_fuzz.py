"""Property tests: whatever bytes an NMEA log holds, the reader never raises anything but a
clean one-line InputError for "no usable fix", and damaged lines are counted."""

from __future__ import annotations

import math
import re
import tempfile
from functools import reduce
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgins.datatypes import InputError
from fgins.io.nmea import read_nmea


def _with_checksum(body: str) -> str:
    checksum = reduce(lambda acc, char: acc ^ ord(char), body, 0)
    return f"${body}*{checksum:02X}"


# One good epoch (u-blox style), checksums computed here, independently of the reader.
GOOD_LINES = [
    _with_checksum("GPRMC,123519.00,A,4807.03800,N,01131.00000,E,022.4,084.4,230394,,,A"),
    _with_checksum("GPGGA,123519.00,4807.03800,N,01131.00000,E,1,08,0.9,545.4,M,46.9,M,,"),
    _with_checksum("GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1"),
    _with_checksum("GPGST,123519.00,1.0,2.0,1.5,45.0,1.2,0.8,2.5"),
]
FUZZ_SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))


def _read_bytes(data: bytes):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.nmea"
        path.write_bytes(data)
        try:
            return read_nmea(path)
        except InputError as error:
            message = str(error)
            assert message and "\n" not in message
            assert "no usable GNSS fix" in message or "not a log fgins reads" in message
            return None


def test_good_epoch_is_decoded_exactly() -> None:
    result = _read_bytes(("\r\n".join(GOOD_LINES) + "\r\n").encode())
    assert result is not None and len(result.gnss) == 1
    lat, lon, height = result.gnss.lla[0]
    assert lat == pytest.approx(48 + 7.038 / 60, abs=1e-12)
    assert lon == pytest.approx(11 + 31.0 / 60, abs=1e-12)
    assert height == pytest.approx(545.4 + 46.9, abs=1e-9)
    assert result.gnss.std[0].tolist() == pytest.approx([0.8, 1.2, 2.5])  # east=lon, north=lat
    assert (result.gnss.pdop[0], result.gnss.hdop[0], result.gnss.vdop[0]) == (2.5, 1.3, 2.1)
    speed = 22.4 * 1852 / 3600
    east, north = speed * math.sin(math.radians(84.4)), speed * math.cos(math.radians(84.4))
    assert result.gnss.velocity[0, :2].tolist() == pytest.approx([east, north])
    assert math.isnan(result.gnss.velocity[0, 2])
    assert result.has_date and result.gnss.t[0] == 764426119.0  # 1994-03-23T12:35:19Z
    assert result.corrupt_lines == result.checksum_failures == 0


@FUZZ_SETTINGS
@given(st.binary(max_size=2000))
def test_random_bytes_never_crash(data: bytes) -> None:
    _read_bytes(data)


@FUZZ_SETTINGS
@given(st.lists(st.tuples(st.sampled_from(GOOD_LINES), st.integers(1, 80)), min_size=1))
def test_truncated_lines_are_counted(cuts: list[tuple[str, int]]) -> None:
    lines = [line[:cut] for line, cut in cuts]
    result = _read_bytes("\n".join(lines).encode())
    damaged = sum(1 for line, cut in cuts if cut < len(line))
    if result is not None:
        # a cut line loses its checksum: it is either rejected (counted) or, if it still holds
        # all its fields, decoded; never silently half-read.
        assert result.corrupt_lines + result.checksum_failures <= damaged
        assert result.gnss.lla[0, 0] == pytest.approx(48 + 7.038 / 60, abs=1e-3)


@FUZZ_SETTINGS
@given(st.integers(0, len(GOOD_LINES) - 1), st.sampled_from("0123456789ABCDEF"), st.booleans())
def test_flipped_checksum_is_a_checksum_failure(index: int, digit: str, last: bool) -> None:
    line = GOOD_LINES[index]
    position = len(line) - (1 if last else 2)
    if line[position] == digit:
        return
    damaged = line[:position] + digit + line[position + 1 :]
    lines = [*GOOD_LINES[:index], damaged, *GOOD_LINES[index + 1 :]]
    result = _read_bytes("\n".join(lines).encode())
    assert result is None or result.checksum_failures == 1


@FUZZ_SETTINGS
@given(st.lists(st.integers(0, 15), max_size=8), st.integers(0, len(GOOD_LINES) - 1))
def test_empty_fields_never_crash(emptied: list[int], index: int) -> None:
    body = GOOD_LINES[index][1:-3].split(",")
    for field_index in emptied:
        if 0 < field_index < len(body):
            body[field_index] = ""
    lines = [*GOOD_LINES[:index], _with_checksum(",".join(body)), *GOOD_LINES[index + 1 :]]
    result = _read_bytes("\n".join(lines).encode())
    if result is not None:
        assert result.corrupt_lines == result.checksum_failures == 0


@FUZZ_SETTINGS
@given(st.binary(max_size=40), st.sampled_from(["\n", "\r\n", "\r"]))
def test_leading_noise_and_line_endings(noise: bytes, newline: str) -> None:
    data = b"".join(
        noise.replace(b"$", b"") + line.encode() + newline.encode() for line in GOOD_LINES
    )
    result = _read_bytes(data)
    assert result is not None and len(result.gnss) == 1
    assert result.gnss.hdop[0] == 1.3


def test_no_fix_log_is_one_line_input_error(tmp_path: Path) -> None:
    path = tmp_path / "nofix.nmea"
    path.write_text(_with_checksum("GPGGA,123519.00,,,,,0,00,99.99,,,,,,") + "\n")
    with pytest.raises(InputError, match="no usable GNSS fix"):
        read_nmea(path)


def _gga(time: str, quality: int = 1, separation: str = "46.9") -> str:
    return _with_checksum(
        f"GPGGA,{time},4807.03800,N,01131.00000,E,{quality},08,0.9,545.4,M,{separation},M,,"
    )


def test_midnight_rollover_without_date_and_offset(tmp_path: Path) -> None:
    path = tmp_path / "midnight.nmea"
    lines = [_gga("235959.00"), _gga("000000.00"), _gga("000001.00", quality=0), _gga("000002.00")]
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path, time_offset_s=10.0)
    assert not result.has_date
    assert result.gnss.t.tolist() == [86399.0 + 10, 86400.0 + 10, 86402.0 + 10]
    assert result.epochs_without_fix == 1


def test_midnight_rollover_with_date_from_rmc(tmp_path: Path) -> None:
    rmc = _with_checksum("GPRMC,235959.00,A,4807.03800,N,01131.00000,E,0.0,,311299,,,A")
    path = tmp_path / "dated.nmea"
    path.write_text("\n".join([_gga("235958.00"), rmc, _gga("235959.00"), _gga("000000.50")]))
    result = read_nmea(path)
    assert result.has_date
    # 1999-12-31T23:59:58Z = 946684798; the last fix is on 2000-01-01.
    assert result.gnss.t.tolist() == [946684798.0, 946684799.0, 946684800.5]


def test_missing_separation_uses_geoid_model(tmp_path: Path) -> None:
    path = tmp_path / "nosep.nmea"
    path.write_text(_gga("120000.00", separation="") + "\n")
    result = read_nmea(path)
    assert result.geoid_from_model == 1 and result.geoid_modelled.tolist() == [True]
    # EGM at 48.117N 11.517E (Munich) is about 47 m; the receiver line above says 46.9 m.
    assert result.gnss.lla[0, 2] == pytest.approx(545.4 + 46.9, abs=2.0)


def test_a_log_of_another_binary_protocol_says_so(tmp_path) -> None:
    """A SiRF/TSIP-like binary log with one NMEA text line (as receivers interleave): the
    error names the likely cause and what fgins reads, not only "no fix"."""
    rng = np.random.default_rng(7)
    frames = [b"\xa0\xa2" + rng.integers(0, 256, 60, dtype=np.uint8).tobytes() + b"\xb0\xb3\n"
              for _ in range(40)]  # fmt: skip
    path = tmp_path / "binary.log"
    path.write_bytes(b"".join(frames) + b"$GPTXT,01,01,01,ANTENNA OK*35\r\n")
    with pytest.raises(InputError, match=r"another receiver protocol .*NMEA 0183 and u-blox UBX"):
        read_nmea(path)


# --- two receivers in one log (one epoch time, two positions) ------------------------------

LAT0, LON0 = 48.1173, 11.5167


def _ddmm(value: float, degree_digits: int) -> str:
    degrees = int(value)
    return f"{degrees:0{degree_digits}d}{(value - degrees) * 60:08.5f}"


def _fix_lines(talker: str, second: int, east_m: float, rmc: bool = True) -> list[str]:
    """GGA (+ RMC) of one fix ``east_m`` east of the reference point at 12:00:SS UTC."""
    lon = LON0 + east_m / (111_320.0 * math.cos(math.radians(LAT0)))
    lat, lon_text = _ddmm(LAT0, 2), _ddmm(lon, 3)
    time = f"1200{second:02d}.00"
    lines = [_with_checksum(f"{talker}GGA,{time},{lat},N,{lon_text},E,1,08,0.9,545.4,M,46.9,M,,")]
    if rmc:
        lines.append(_with_checksum(f"{talker}RMC,{time},A,{lat},N,{lon_text},E,0.0,,010524,,,A"))
    return lines


def _east_m(result) -> np.ndarray:
    lon = result.gnss.lla[:, 1]
    return (lon - LON0) * 111_320.0 * math.cos(math.radians(LAT0))


def test_two_receivers_interleaved_with_one_time_are_an_error(tmp_path: Path) -> None:
    """Two receivers (GP, GN) 30 m apart, same stamps, every epoch: the later one used to
    overwrite the earlier in silence (half the GGA lost, the track 30 m off)."""
    lines = []
    for second in range(20):
        lines += _fix_lines("GP", second, 0.0) + _fix_lines("GN", second, 30.0)
    path = tmp_path / "two_rx.nmea"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        InputError,
        match=r"two receivers in one log: talkers GP and GN give positions 30 m apart .*"
        r"20 epoch.*\(20 of 20 fix epochs\); split it by talker",
    ):
        read_nmea(path)


def test_a_few_epochs_of_a_second_talker_are_counted_and_the_main_one_kept(
    tmp_path: Path,
) -> None:
    lines = []
    for second in range(20):
        lines += _fix_lines("GP", second, 0.0)
        if second in (5, 6, 7):
            lines += _fix_lines("GN", second, 30.0)
    path = tmp_path / "some_two_rx.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 20
    np.testing.assert_allclose(_east_m(result), 0.0, atol=0.05)  # GP kept everywhere
    messages = [w for w in result.warnings if "two positions for one time" in w]
    assert len(messages) == 1, result.warnings
    assert re.search(
        r"talkers GP and GN .*30 m apart.* in 3 epoch\(s\).*kept talker GP", messages[0]
    )


def test_one_receiver_with_two_talkers_that_agree_is_merged_quietly(tmp_path: Path) -> None:
    """A multi-GNSS receiver printing GNGGA and GPRMC of one fix: no conflict, GGA's height."""
    lines = []
    for second in range(10):
        lines += _fix_lines("GN", second, 0.0, rmc=False) + _fix_lines("GP", second, 0.3)[1:]
    path = tmp_path / "one_rx.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 10 and not any("two" in w for w in result.warnings)
    np.testing.assert_allclose(result.gnss.lla[:, 2], 545.4 + 46.9)


@pytest.mark.parametrize("order", ["after", "before", "random"])
@pytest.mark.parametrize("east", [2.0, 3.0, 4.5])
def test_a_second_talker_close_by_is_said_and_the_main_one_kept_in_any_order(
    tmp_path: Path, order: str, east: float
) -> None:
    """A GLGGA 2-4.5 m from each GPGGA of the same time (under the 5 m of two receivers):
    the latest printed had been taken, so the track followed the minor talker, or zigzagged
    between the two in a random order (1.5-3 m off at z 6-17, unsaid: outside tester). The
    main talker's fixes are kept whatever the order, and the disagreement said."""
    rng = np.random.default_rng(int(east * 10))
    lines = []
    for second in range(30):
        main, other = _fix_lines("GP", second, 0.0), _fix_lines("GL", second, east, rmc=False)
        after = order == "after" or (order == "random" and rng.random() < 0.5)
        lines += main + other if after else other + main
    path = tmp_path / "two_talkers.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 30
    np.testing.assert_allclose(_east_m(result), 0.0, atol=0.05)
    messages = [w for w in result.warnings if "two positions for one time" in w]
    assert len(messages) == 1, result.warnings
    assert re.search(rf"{east:.1f} m apart .* in 30 epoch\(s\).*kept talker GP", messages[0]), messages


def test_the_vtg_of_an_epoch_whose_timed_sentences_were_lost_is_not_the_one_before(tmp_path: Path) -> None:
    """GGA, RMC, VTG, GSA per epoch, the GGA and RMC of some epochs lost: their VTG and GSA
    came after the previous epoch's own and replaced its speed and course (by up to 3.6 m/s:
    outside tester) and its DOPs. Each epoch keeps its own; the orphans are counted."""
    lat, lon = _ddmm(LAT0, 2), _ddmm(LON0, 3)
    lost = {4, 9, 10, 15}
    lines = []
    for second in range(20):
        time, knots, course = f"1200{second:02d}.00", 2.0 * second, 10.0 * second
        vtg = _with_checksum(f"GPVTG,{course:.1f},T,,M,{knots:.2f},N,{knots * 1.852:.2f},K,A")
        pdop = 1.0 + 0.1 * second
        gsa = _with_checksum(f"GPGSA,A,3,01,02,03,04,05,,,,,,,,{pdop:.1f},1.0,1.0")
        if second not in lost:
            lines += [_with_checksum(f"GPGGA,{time},{lat},N,{lon},E,1,08,0.9,545.4,M,46.9,M,,"),
                      _with_checksum(f"GPRMC,{time},A,{lat},N,{lon},E,{knots:.2f},{course:.1f},010524,,,A")]  # fmt: skip
        lines += [vtg, gsa]
    path = tmp_path / "lost.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    seconds = np.round(result.gnss.t - result.gnss.t[0]).astype(int)
    assert sorted(set(range(20)) - set(seconds.tolist())) == sorted(lost)
    np.testing.assert_allclose(result.gnss.speed, 2.0 * seconds * 1852 / 3600, atol=0.01)
    np.testing.assert_allclose(result.gnss.course, 10.0 * seconds, atol=0.05)
    # Its GSA (the same satellites) likewise: it had replaced the epoch's DOPs.
    np.testing.assert_allclose(result.gnss.pdop, 1.0 + 0.1 * seconds, atol=1e-9)
    assert any("4 VTG sentence(s) and 4 GSA sentence(s) after their epoch" in w for w in result.warnings), result.warnings


@pytest.mark.parametrize("order", ["after", "before"])
def test_an_rtk_talker_beside_an_autonomous_one_is_the_one_kept(tmp_path: Path, order: str) -> None:
    """An RTK receiver printing its RTK-fixed GNGGA and a GPS-only autonomous GPGGA 1-4 m
    away for each epoch: the autonomous fixes were taken under the RTK sigmas and the 2 cm
    log "diverged" (outside tester). The more precise talker is the one kept, said."""
    rng = np.random.default_rng(3)
    lat = _ddmm(LAT0, 2)
    lines = []
    for second in range(30):
        time = f"1200{second:02d}.00"
        rtk = _with_checksum(f"GNGGA,{time},{lat},N,{_ddmm(LON0, 3)},E,4,12,0.7,545.4,M,46.9,M,1.0,0000")
        east = rng.uniform(1.5, 4.0)
        lon = _ddmm(LON0 + east / (111_320.0 * math.cos(math.radians(LAT0))), 3)
        single = _with_checksum(f"GPGGA,{time},{lat},N,{lon},E,1,07,1.2,546.0,M,46.9,M,,")
        lines += [rtk, single] if order == "after" else [single, rtk]
    path = tmp_path / "rtk_and_single.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    np.testing.assert_allclose(_east_m(result), 0.0, atol=0.05)
    assert set(result.gnss.fix_quality.tolist()) == {4}
    assert any("kept talker GN" in w for w in result.warnings), result.warnings


@pytest.mark.parametrize("with_rmc", [False, True])
@pytest.mark.parametrize("order", ["after", "before"])
def test_per_constellation_sentences_without_a_position_leave_the_combined_fix(
    tmp_path: Path, with_rmc: bool, order: str
) -> None:
    """NMEA 4.10: the combined solution as GNGNS, then one GNS per constellation (GPGNS,
    GLGNS) with empty position fields, or a GLGGA of a system without a solution (quality
    0). The empty ones wiped the epoch's position: a GNS log was refused as "no usable GNSS
    fix", a GNS + RMC one lost every height (outside tester). Each epoch keeps the combined
    fix and its height, whatever the order."""
    lat, lon = _ddmm(LAT0, 2), _ddmm(LON0, 3)
    lines = []
    for second in range(20):
        time = f"1200{second:02d}.00"
        combined = [_with_checksum(f"GNGNS,{time},{lat},N,{lon},E,AA,09,0.9,373.794,47.6,,")]
        if with_rmc:
            combined.append(_with_checksum(f"GNRMC,{time},A,{lat},N,{lon},E,0.0,,010524,,,A"))
        empty = [_with_checksum(f"GPGNS,{time},,,,,AN,06,,,,,"), _with_checksum(f"GLGNS,{time},,,,,NA,03,,,,,"),
                 _with_checksum(f"GLGGA,{time},,,,,0,00,99.99,,,,,,")]  # fmt: skip
        lines += combined + empty if order == "after" else empty + combined
    path = tmp_path / "gns410.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 20
    np.testing.assert_allclose(result.gnss.lla[:, 2], 373.794 + 47.6)
    np.testing.assert_allclose(_east_m(result), 0.0, atol=0.05)
    assert not any("two positions" in w for w in result.warnings), result.warnings


def test_a_talker_repeating_an_epoch_far_away_is_counted_and_the_first_kept(
    tmp_path: Path,
) -> None:
    lines = []
    for second in range(20):
        lines += _fix_lines("GP", second, 0.0, rmc=False)
        if second in (3, 9):
            lines += _fix_lines("GP", second, 111.0, rmc=False)
    path = tmp_path / "repeat.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 20
    np.testing.assert_allclose(_east_m(result), 0.0, atol=0.05)
    messages = [w for w in result.warnings if "two positions for one time" in w]
    assert len(messages) == 1, result.warnings
    assert re.search(r"talker GP gives two positions 111 m apart .* in 2 epoch.*first", messages[0])


def test_two_logs_of_one_talker_with_the_same_times_are_an_error(tmp_path: Path) -> None:
    first = [line for s in range(10) for line in _fix_lines("GP", s, 0.0)]
    second = [line for s in range(10) for line in _fix_lines("GP", s, 500.0)]
    path = tmp_path / "concatenated.nmea"
    path.write_text("\n".join(first + second) + "\n")
    with pytest.raises(InputError, match=r"two receivers in one log: talker GP gives two "
                       r"positions 50[01] m apart.*give each receiver's"):  # fmt: skip
        read_nmea(path)


def test_date_of_an_rmc_with_status_v_is_not_used(tmp_path: Path) -> None:
    """A receiver starting up sends RMC status V with its firmware's default date (MTK-3301:
    050180); the valid RMCs later give the day. Every fix, and the no-fix epochs before the
    first valid date, are on the valid date (rolled over midnight by the usual rule)."""
    start_up = _with_checksum("GPRMC,235958.00,V,,,,,,,050180,,,N")
    valid = _with_checksum("GPRMC,000001.00,A,4807.03800,N,01131.00000,E,0.0,,230808,,,A")
    lines = [start_up, _gga("235958.00", quality=0), _gga("000000.00"), valid, _gga("000001.00")]
    path = tmp_path / "start_up.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    midnight = 1219449600.0  # 2008-08-23T00:00:00Z
    assert result.has_date
    assert result.gnss.t.tolist() == [midnight, midnight + 1.0]
    assert result.first_epoch_t == midnight - 2.0  # the quality-0 epoch, on 2008-08-22
    assert any("1 RMC sentence(s) with status V" in w for w in result.warnings)


def test_a_log_dated_only_by_invalid_rmc_is_undated(tmp_path: Path) -> None:
    start_up = _with_checksum("GPRMC,120000.00,V,4807.03800,N,01131.00000,E,0.0,,010108,,,N")
    path = tmp_path / "undated.nmea"
    path.write_text("\n".join([start_up, _gga("120000.00"), _gga("120001.00")]) + "\n")
    result = read_nmea(path)
    assert not result.has_date
    assert result.gnss.t.tolist() == [43200.0, 43201.0]
    assert any("only dates are in RMC sentences with status V" in w for w in result.warnings)


def test_gga_quality_with_zero_satellites_is_dropped_and_counted(tmp_path: Path) -> None:
    def gga(time: str, sats: str) -> str:
        return _with_checksum(
            f"GPGGA,{time},4807.03800,N,01131.00000,E,1,{sats},3.3,545.4,M,46.9,M,,"
        )

    lines = [gga("120000.00", "00"), gga("120001.00", "0"), gga("120002.00", ""),
             gga("120003.00", "05")]  # fmt: skip
    path = tmp_path / "zero_sats.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    # An empty satellite field is unknown, not 0: that fix stays.
    assert np.mod(result.gnss.t, 86400).tolist() == [43202.0, 43203.0]
    assert result.epochs_without_fix == 2
    assert any(
        "2 epochs without a usable position were skipped (2 of them GGA with a fix quality "
        "but 0 satellites used" in w
        for w in result.warnings
    )


@pytest.mark.parametrize("rate_hz", [5, 10])
def test_a_fast_receiver_printing_whole_seconds_keeps_each_seconds_first_fix(
    tmp_path: Path, rate_hz: int
) -> None:
    """A 5-10 Hz receiver whose time field has no decimals prints every fix of a second
    under that second's start. The first is the fix of that time; the last had been kept
    (each fix 0.8-0.9 s late, its speed too, the 80-90 % left out unsaid)."""
    lines = []
    seconds = 12
    for k in range(seconds * rate_hz):
        t = k / rate_hz
        east, speed = 2.0 * t + 0.5 * t * t, 2.0 + t  # accelerating east at 1 m/s^2
        lon = LON0 + east / (111_320.0 * math.cos(math.radians(LAT0)))
        lat, lon_text, time = _ddmm(LAT0, 2), _ddmm(lon, 3), f"1200{int(t):02d}"
        knots = speed / (1852.0 / 3600.0)
        lines.append(_with_checksum(f"GPGGA,{time},{lat},N,{lon_text},E,1,08,0.9,545.4,M,46.9,M,,"))
        lines.append(_with_checksum(f"GPRMC,{time},A,{lat},N,{lon_text},E,{knots:.3f},90.0,010524,,,A"))
    path = tmp_path / "fast.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    whole = np.arange(seconds, dtype=float)
    assert len(result.gnss) == seconds
    np.testing.assert_allclose(_east_m(result), 2.0 * whole + 0.5 * whole**2, atol=0.05)
    np.testing.assert_allclose(result.gnss.speed, 2.0 + whole, atol=0.01)
    said = [w for w in result.warnings if "repeat their talker's sentence type" in w]
    left_out = 2 * seconds * (rate_hz - 1)  # GGA and RMC
    assert len(said) == 1 and said[0].startswith(f"{left_out} position sentence(s)"), result.warnings
    assert "whole-second times" in said[0] and "first of each time kept" in said[0]
    assert not any("two positions" in w for w in result.warnings), result.warnings


def test_a_duplicated_line_is_not_counted_as_another_fix(tmp_path: Path) -> None:
    lines = [line for s in range(5) for line in _fix_lines("GP", s, 0.0) * 2]
    path = tmp_path / "duplicated.nmea"
    path.write_text("\n".join(lines) + "\n")
    result = read_nmea(path)
    assert len(result.gnss) == 5
    assert not any("repeat their talker's" in w for w in result.warnings), result.warnings
