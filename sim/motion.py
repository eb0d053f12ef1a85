"""Motion profiles: what the vehicle does, as smooth speed / attitude histories.

A profile is built from :class:`Segment` s (speed ramps, turns, pitch changes) and sampled on
a uniform grid. The velocity always points along the body x axis (a car without side slip, an
aircraft at zero angle of attack / sideslip), so the attitude and the speed fully determine the
motion; :mod:`fgins.sim.strapdown` turns that into exact IMU commands and truth.

Angles: yaw is ENU yaw (from east, counter-clockwise, rad), pitch positive nose up, roll
positive right side down (DESIGN.md attitude convention; heading = 90 deg - yaw).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import InputError

STANDARD_GRAVITY = 9.80665


@dataclass(frozen=True)
class Segment:
    """One manoeuvre of a profile, lasting ``duration_s``.

    ``speed_end`` ramps the speed smoothly from its current value (None keeps it);
    ``turn_deg`` changes the yaw smoothly by that angle (positive = left);
    ``radius_m`` instead turns continuously on a circle of that radius (sign: + left);
    ``pitch_end_deg`` ramps the pitch (= flight-path angle) smoothly.
    """

    duration_s: float
    speed_end: float | None = None
    turn_deg: float = 0.0
    radius_m: float | None = None
    pitch_end_deg: float | None = None


@dataclass
class MotionProfile:
    """Sampled motion: times (s), speed along body x (m/s), yaw/pitch/roll (rad), (N,) each."""

    t: np.ndarray
    speed: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    vehicle: str
    yaw_rate: np.ndarray | None = None  # rad/s, ENU yaw rate as commanded (None: not known)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def rotation(self) -> np.ndarray:
        """Body-to-ENU rotations (N, 3, 3): R = Rz(yaw) Ry(-pitch) Rx(roll)."""
        return euler_to_rotation(self.roll, self.pitch, self.yaw)

    def turns(
        self, min_rate_deg_per_s: float = 0.5, min_duration_s: float = 2.0
    ) -> list[tuple[float, float]]:
        """Windows (start, end) in profile time where |yaw rate| exceeds ``min_rate_deg_per_s``
        for at least ``min_duration_s``: where outages in turns should be placed."""
        rate = self.yaw_rate if self.yaw_rate is not None else np.gradient(self.yaw, self.t)
        turning = np.abs(rate) > np.radians(min_rate_deg_per_s)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], turning.astype(np.int8), [0]])))
        windows = []
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            start, end = float(self.t[a]), float(self.t[b - 1])
            if end - start >= min_duration_s:
                windows.append((start, end))
        return windows

    def velocity(self) -> np.ndarray:
        """ENU velocity (N, 3): speed along the body x axis."""
        cp = np.cos(self.pitch)
        return self.speed[:, None] * np.column_stack(
            [cp * np.cos(self.yaw), cp * np.sin(self.yaw), np.sin(self.pitch)]
        )


def euler_to_rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Vectorised body-to-ENU rotation from roll, pitch (nose up +), ENU yaw (rad)."""
    cr, sr = np.cos(roll), np.sin(roll)
    # Body y points left, so a positive (nose-up) pitch is a negative rotation about y.
    cp, sp = np.cos(-pitch), np.sin(-pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    r = np.empty((*np.shape(roll), 3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def _smooth_step(u: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero slope at both ends (so rates start and stop without jumps)."""
    return u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi)


def build_profile(
    segments: list[Segment],
    rate_hz: float,
    duration_s: float,
    *,
    vehicle: str = "car",
    initial_speed: float = 0.0,
    initial_heading_deg: float = 0.0,
    coordinated_turns: bool = False,
) -> MotionProfile:
    """Sample ``segments`` (repeated cyclically as needed) at ``rate_hz`` for ``duration_s``.

    ``coordinated_turns`` banks the vehicle so that the lift balances the centripetal
    acceleration (aircraft): roll = -atan(speed * yaw_rate / g).
    """
    if rate_hz <= 0 or duration_s <= 0:
        raise InputError(f"profile: rate {rate_hz} Hz and duration {duration_s} s must be > 0")
    if not segments or all(s.duration_s <= 0 for s in segments):
        raise InputError("profile: need at least one segment with a positive duration")
    n = round(duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    speed = np.full(n, float(initial_speed))
    yaw_rate = np.zeros(n)
    pitch = np.zeros(n)
    start, index = 0.0, 0
    current_speed, current_pitch = float(initial_speed), 0.0
    while start < t[-1]:
        seg = segments[index % len(segments)]
        index += 1
        if seg.duration_s <= 0:
            continue
        end = start + seg.duration_s
        inside = (t >= start) & (t < end)
        after = t >= end
        u = (t[inside] - start) / seg.duration_s
        if seg.speed_end is not None:
            speed[inside] = current_speed + (seg.speed_end - current_speed) * _smooth_step(u)
            current_speed = seg.speed_end
        else:
            speed[inside] = current_speed
        speed[after] = current_speed
        if seg.pitch_end_deg is not None:
            target = np.radians(seg.pitch_end_deg)
            pitch[inside] = current_pitch + (target - current_pitch) * _smooth_step(u)
            current_pitch = target
        else:
            pitch[inside] = current_pitch
        pitch[after] = current_pitch
        if seg.radius_m is not None:
            yaw_rate[inside] = speed[inside] / seg.radius_m
        elif seg.turn_deg:
            # Raised-cosine yaw rate: integrates to turn_deg over the segment.
            yaw_rate[inside] = (
                np.radians(seg.turn_deg) / seg.duration_s * (1.0 - np.cos(2.0 * np.pi * u))
            )
        start = end
    if np.any(speed < 0):
        raise InputError("profile: a segment asks for a negative speed")
    yaw = np.radians(90.0 - initial_heading_deg) + np.concatenate(
        [[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) / rate_hz)]
    )
    roll = np.zeros(n)
    if coordinated_turns:
        roll = -np.arctan(speed * yaw_rate / STANDARD_GRAVITY)
    return MotionProfile(
        t=t, speed=speed, yaw=yaw, pitch=pitch, roll=roll, vehicle=vehicle, yaw_rate=yaw_rate
    )


# --- ready-made profiles -------------------------------------------------------------------


def urban_car(rate_hz: float, duration_s: float) -> MotionProfile:
    """City driving: stops, 90-degree turns at junctions, 8-14 m/s between them."""
    block = [
        Segment(10.0),  # standing (lets estimators align)
        Segment(8.0, speed_end=12.0),
        Segment(15.0),
        Segment(4.0, speed_end=6.0),
        Segment(8.0, turn_deg=90.0),
        Segment(6.0, speed_end=14.0),
        Segment(20.0),
        Segment(5.0, speed_end=5.0),
        Segment(7.0, turn_deg=-90.0),
        Segment(5.0, speed_end=10.0),
        Segment(12.0, turn_deg=25.0),
        Segment(10.0),
        Segment(6.0, speed_end=0.0),
    ]
    return build_profile(block, rate_hz, duration_s, vehicle="car", initial_heading_deg=30.0)


def highway(rate_hz: float, duration_s: float) -> MotionProfile:
    """Motorway: on-ramp acceleration to ~30 m/s, long gentle curves, slight grades."""
    block = [
        Segment(20.0, speed_end=28.0, turn_deg=-40.0),
        Segment(30.0, pitch_end_deg=1.5),
        Segment(40.0, turn_deg=20.0, speed_end=32.0),
        Segment(30.0, pitch_end_deg=-1.0),
        Segment(40.0, turn_deg=-25.0),
        Segment(20.0, speed_end=27.0, pitch_end_deg=0.0),
        Segment(30.0, turn_deg=15.0),
    ]
    return build_profile(block, rate_hz, duration_s, vehicle="car", initial_heading_deg=75.0)


def circular_loop(
    rate_hz: float, duration_s: float, radius_m: float = 25.0, speed_m_per_s: float = 11 / 3.6
) -> MotionProfile:
    """Start standing, speed up on the circle, then drive round it at constant speed."""
    if radius_m <= 0 or speed_m_per_s <= 0:
        raise InputError("circular loop: radius and speed must be > 0")
    block = [
        Segment(5.0),
        Segment(5.0, speed_end=speed_m_per_s, radius_m=radius_m),
        Segment(1e9, radius_m=radius_m),
    ]
    return build_profile(block, rate_hz, duration_s, vehicle="car", initial_heading_deg=0.0)


def aircraft(rate_hz: float, duration_s: float, cruise_m_per_s: float = 100.0) -> MotionProfile:
    """Take-off roll, climb, coordinated turns (about 25 deg bank), cruise, gentle descents."""
    v = cruise_m_per_s
    takeoff = [
        Segment(5.0),
        Segment(30.0, speed_end=0.6 * v),
        Segment(5.0, pitch_end_deg=8.0, speed_end=0.65 * v),
        Segment(60.0, speed_end=0.9 * v),
        Segment(20.0, pitch_end_deg=3.0, speed_end=v, turn_deg=60.0),
        Segment(10.0, pitch_end_deg=0.0),
    ]
    cruise = [
        Segment(60.0),
        Segment(40.0, turn_deg=-120.0),
        Segment(50.0, pitch_end_deg=2.0),
        Segment(20.0, pitch_end_deg=0.0),
        Segment(45.0, turn_deg=150.0),
        Segment(60.0),
        Segment(15.0, pitch_end_deg=-2.0),
        Segment(30.0, turn_deg=-90.0),
        Segment(15.0, pitch_end_deg=0.0),
    ]
    takeoff_s = sum(s.duration_s for s in takeoff)
    repeats = max(1, int(np.ceil(max(duration_s - takeoff_s, 0.0) / 365.0)) + 1)
    return build_profile(
        takeoff + cruise * repeats,
        rate_hz,
        duration_s,
        vehicle="aircraft",
        initial_heading_deg=250.0,
        coordinated_turns=True,
    )


PROFILES = {
    "urban": urban_car,
    "highway": highway,
    "loop": circular_loop,
    "aircraft": aircraft,
}
