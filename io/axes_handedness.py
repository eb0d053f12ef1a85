"""Are the accelerometer's axes right-handed with the gyro's? (input-validation layer,
:mod:`fgins.io.validate`). GTSAM-free.

One accelerometer axis with its sign flipped, or two axes swapped, in a logger's column
mapping makes a mirror image of the specific force against a right-handed gyro. Nothing
else sees it: the accelerometer's norm is gravity's, its mean still points up and the gyro
still turns with the track; no rotation of the IMU in the vehicle maps a mirror image onto
the truth, so the mounting, the clocks and the sigmas were all "corrected" around it (an
urban car with accel_y negated: 264 m off the truth with exit code 0; accel_x and accel_y
swapped: 55 m).

What tells: a vehicle that follows its track feels its acceleration along and across the
track in the horizontal plane of its IMU. Written as complex numbers in that plane (the one
normal to the mean specific force, ``up``, turned counter-clockwise about it by ``i``), the
acceleration the fixes show in track axes, ``A = along + i left``, and the specific force in
IMU axes, ``F``, are related by one constant rotation, ``F = z A`` (``z``: the IMU's yaw in
the vehicle), when the axes are right-handed, and by ``F = z conj(A)`` when the
accelerometer is mirrored: a left turn reads as a right one while braking still reads as
braking. Both are fitted over the drive; the mirrored one explaining it far better is an
error. Reversing, the track runs backward from the body: each stretch between stops gets
its own sign. A drive with only turns or only speed changes fits both alike and is not judged; nor
is an aircraft, whose coordinated turns put no force across the body, nor a vehicle that
need not follow its track (the caller's choice).
"""

from __future__ import annotations

import numpy as np

from fgins.datatypes import GnssData, InputError, median_interval
from fgins.planar import complex_at, horizontal_axes, window_means, yaw_about

# The accelerations compared are means over a window of +-WINDOW_S around each second: the
# receiver's velocity differenced over it, or, without velocities, the fixes' second
# difference (3 m fixes: 0.15 x 3 m / s^2 of noise at 8 s, 2 m/s^2 at 4 s).
VELOCITY_WINDOW_S = 4.0
POSITION_WINDOW_S = 8.0
MIN_SPEED_M_PER_S = 3.0  # a course to take the track axes from
STOP_CHORD_S = 2.0
MIN_WINDOWS = 20
# Refused when the mirrored fit leaves at most MIRRORED_RESIDUAL_RATIO of the right-handed
# fit's unexplained part and correlates at MIRRORED_MIN_CORRELATION. Seen: right-handed drives
# (KITTI; fgins's cars with and without velocities, FLU, FRD and a turned mounting) 4.5-33
# times less unexplained right-handed; the same mirrored (accel_x or accel_y negated, or the
# two swapped) 0.03-0.22, at correlation 0.91-0.99; aircraft (no force across the body in
# their turns) about 1, not judged.
MIRRORED_RESIDUAL_RATIO = 0.5
MIRRORED_MIN_CORRELATION = 0.7


def check_accel_handedness(imu, gnss: GnssData, enu: np.ndarray) -> None:
    """Raise an :class:`InputError` when the accelerometer's axes fit the track as a mirror
    image of the gyro's (module docstring)."""
    fit = handedness_fit(imu, gnss, enu)
    if fit is None:
        return
    right, mirrored, correlation = fit
    if mirrored <= MIRRORED_RESIDUAL_RATIO * right and correlation >= MIRRORED_MIN_CORRELATION:
        raise InputError(
            "imu: the accelerometer's axes are a mirror image of the gyro's (a left-handed "
            "set: one axis's sign flipped, or two axes swapped, in the column mapping): the "
            "drive's horizontal accelerations fit the track only mirrored (residual "
            f"{mirrored / right:.2f} times the right-handed fit's, correlation "
            f"{correlation:.2f}), a left turn read as a right one; give accel_x, accel_y, "
            "accel_z as right-handed axes, the same as gyro_x, gyro_y, gyro_z"
        )


def handedness_fit(imu, gnss: GnssData, enu: np.ndarray) -> tuple[float, float, float] | None:
    """(residual of the right-handed fit, of the mirrored fit, the mirrored fit's
    correlation) over the drive's moving seconds; None with too few of them."""
    velocity = _horizontal_velocity(gnss)
    window = VELOCITY_WINDOW_S if velocity is not None else POSITION_WINDOW_S
    t = gnss.t
    if t.size < 2:
        return None
    # Sparser fixes (0.2 Hz: 5 s apart) need two fix intervals a side, and take one interval
    # as dense: with 8 s and 4 s no window was, and a mirrored accelerometer went unchecked.
    usual_gap = median_interval(t)
    window = max(window, 2.0 * usual_gap)
    grid = np.arange(max(t[0], imu.t[0]) + window, min(t[-1], imu.t[-1]) - window, 1.0)
    if grid.size < MIN_WINDOWS:
        return None
    # Fixes dense around each second's window (an outage makes its acceleration a guess).
    ends = np.clip(np.searchsorted(t, grid + np.array([[-window], [0.0], [window]])), 1, t.size - 1)
    dense = np.max(t[ends] - t[ends - 1], axis=0) <= max(window / 2, 1.5 * usual_gap)

    position = enu[:, 0] + 1j * enu[:, 1]
    chord = complex_at(grid + window, t, position) - complex_at(grid - window, t, position)
    if velocity is not None:
        known = np.isfinite(velocity)
        accel = (complex_at(grid + window, t[known], velocity[known]) - complex_at(grid - window, t[known], velocity[known]))
        accel /= 2.0 * window
    else:
        accel = (chord - 2.0 * (complex_at(grid, t, position) - complex_at(grid - window, t, position))) / window**2
    # The track's direction is the body's forward one or, reversing, its opposite: one sign
    # per stretch between stops, fitted. A turn taken reversing reads as a mirrored one in
    # track axes (an independent simulator's car reversing 90 s with turns: refused, 0.08).
    # To turn round, the speed over +-STOP_CHORD_S passes below MIN_SPEED_M_PER_S (the long
    # chord would not do: round a 30 m circle at 8 m/s it spans 245 deg and flickers about
    # 3 m/s, and a stretch per flicker let the mirrored fit take the circle).
    short = complex_at(grid + STOP_CHORD_S, t, position) - complex_at(grid - STOP_CHORD_S, t, position)
    going = np.abs(short) / (2.0 * STOP_CHORD_S) > MIN_SPEED_M_PER_S
    use = dense & going & (np.abs(chord) / (2.0 * window) > MIN_SPEED_M_PER_S)
    if use.sum() < MIN_WINDOWS:
        return None
    stretch = np.cumsum(np.diff(going.astype(int), prepend=0) == 1)[use]
    track = accel[use] * np.conj(chord[use] / np.abs(chord[use]))  # along + i left
    right, mirrored = (
        _correlation(force - force.mean(), track, stretch)
        for force in (_horizontal_force(imu, grid, window, velocity is not None, mirror)[use]
                      for mirror in (False, True))
    )  # fmt: skip
    if right is None or mirrored is None:
        return None
    return 1.0 - right**2, 1.0 - mirrored**2, mirrored


def _horizontal_velocity(gnss: GnssData) -> np.ndarray | None:
    """The receiver's horizontal velocity (east + i north) where most fixes give one."""
    if gnss.velocity is None:
        return None
    velocity = gnss.velocity[:, 0] + 1j * gnss.velocity[:, 1]
    return velocity if np.isfinite(velocity).mean() >= 0.8 else None


def _horizontal_force(imu, grid: np.ndarray, window: float, box: bool, mirror: bool) -> np.ndarray:
    """The specific force in the IMU's horizontal plane (complex, counter-clockwise about
    the mean specific force; its mirror image with ``mirror``) averaged as the fixes'
    acceleration is: a box of +-window (velocity differences) or a triangle (positions'
    second differences), each sample turned into the IMU's axes at the window's middle by
    the gyro's rotation about up (a mirrored accelerometer's axes turn the other way: its
    mirror image is what turns with the gyro)."""
    up = np.mean(imu.accel, axis=0)
    up /= np.linalg.norm(up)
    first_axis, second_axis = horizontal_axes(up)
    force = imu.accel @ first_axis + 1j * (imu.accel @ second_axis)
    if mirror:
        force = np.conj(force)
    yaw = yaw_about(imu, up)
    steady = force * np.exp(1j * yaw)  # in axes that do not turn with the body about up
    mean = window_means(imu.t, steady, grid, window, box)
    return mean * np.exp(-1j * np.interp(grid, imu.t, yaw))


def _correlation(force: np.ndarray, track: np.ndarray, stretch: np.ndarray) -> float | None:
    """How well ``force = z s track`` fits (|correlation|; complex ``z`` free, ``s`` = +-1
    free per stretch), twice, the second time without the seconds it fits worst (a multipath
    fix's acceleration)."""
    keep = np.ones(track.size, dtype=bool)
    for _ in range(2):
        f, a = force[keep], track[keep]
        power = float(np.sum(np.abs(a) ** 2))
        if power <= 0.0 or a.size < MIN_WINDOWS:
            return None
        signs = _stretch_signs(f * np.conj(a), stretch[keep], int(stretch.max()) + 1)
        signed = track * signs[stretch]
        signed -= signed.mean()
        z = np.sum(f * np.conj(signed[keep])) / float(np.sum(np.abs(signed[keep]) ** 2))
        misfit = np.abs(force - z * signed)
        keep = misfit <= 3.0 * np.median(misfit[keep]) + 0.05
    f, a = force[keep], track[keep]
    if a.size < MIN_WINDOWS:
        return None
    signs = _stretch_signs(f * np.conj(a), stretch[keep], int(stretch.max()) + 1)
    signed = track * signs[stretch]
    signed = (signed - signed.mean())[keep]
    power, felt = float(np.sum(np.abs(signed) ** 2)), float(np.sum(np.abs(f) ** 2))
    if power <= 0.0 or felt <= 0.0:
        return None
    return float(np.abs(np.sum(f * np.conj(signed))) / np.sqrt(power * felt))


def _stretch_signs(products: np.ndarray, stretch: np.ndarray, count: int) -> np.ndarray:
    """Signs s (indexed by stretch) maximising |sum_k s_k c_k|, c_k the stretch's sum of
    ``products``: the best sum's direction splits the c_k by sign, so trying directions
    every 0.5 deg (and settling) finds it."""
    sums = (np.bincount(stretch, weights=products.real, minlength=count)
            + 1j * np.bincount(stretch, weights=products.imag, minlength=count))  # fmt: skip
    directions = np.exp(1j * np.linspace(0.0, np.pi, 360, endpoint=False))
    signs = np.where((sums[None, :] * np.conj(directions[:, None])).real >= 0.0, 1.0, -1.0)
    best = signs[int(np.argmax(np.abs(signs @ sums)))]
    for _ in range(len(sums)):
        settled = np.where((sums * np.conj(best @ sums)).real >= 0.0, 1.0, -1.0)
        if np.array_equal(settled, best):
            break
        best = settled
    return best


# A vehicle that need not follow its track (a multirotor, a pedestrian) or banks into its
# turns (an aircraft) is judged in three dimensions instead: over windows of WINDOW_3D_S,
# the accelerometer carried by the gyro into one frame must match the specific force the
# fixes show in the navigation frame, a + g up, through one proper rotation (and a slow one
# for the gyro's bias). Each column mistake undone is fitted alike: an axis negated or two
# swapped in the accelerometer, in the gyro, or in both (a left-handed IMU), and the
# accelerometer turned 90 deg about z against the gyro (two sensors in different frames).
# The data as given fitting MIRRORED_3D_RATIO times worse than the best mistake undone is
# said (a warning), MIRRORED_3D_ERROR_RATIO times an error. Seen: an independent
# simulator's right-handed aircraft 0.23-1.0, a consumer aircraft 0.41-1.0, a consumer
# multirotor that hovers and yaws in place 1.0-1.69; mirrored (accel_y negated) a banking
# aircraft 4.4, a gentle one 1.8 (not said), the multirotor 2.2-2.5 (not said); a
# multirotor with gyro_x negated, gyro x/y swapped, or both sensors' x/y swapped 3.2-3.6
# (it had run to 103 m inside an outage, the blame on the fixes' sigmas, exit code 0);
# aircraft with the gyro's or both sensors' columns mistaken 13-16 (207 km with EKF+RTS,
# exit code 0), the accelerometer turned 90 deg 3.3. Cars are judged by the track test
# above: their roll and pitch are too small for the 3-D fit to tell a gyro's x from its y.
WINDOW_3D_S = 30.0
HALF_BOX_3D_S = 2.0
MIRRORED_3D_RATIO = 3.0
MIRRORED_3D_ERROR_RATIO = 8.0
MIN_WINDOWS_3D = 3
MAX_WINDOWS_3D = 60  # 30 min of windows at most, whatever the flight's length (cost bound)
_SWAPS = {"x and y": [1, 0, 2], "x and z": [2, 1, 0], "y and z": [0, 2, 1]}
_IDENTITY = np.eye(3)


def _column_mistakes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Mistake name -> (accelerometer matrix, gyro matrix) that makes it from true readings."""
    mistakes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for index, axis in enumerate("xyz"):
        negated = np.diag([-1.0 if k == index else 1.0 for k in range(3)])
        mistakes[f"accel_{axis} negated"] = (negated, _IDENTITY)
        mistakes[f"gyro_{axis} negated"] = (_IDENTITY, negated)
        mistakes[f"accel_{axis} and gyro_{axis} negated"] = (negated, negated)
    for pair, order in _SWAPS.items():
        a, b = pair.split(" and ")
        swapped = _IDENTITY[order]
        mistakes[f"accel_{a} and accel_{b} swapped"] = (swapped, _IDENTITY)
        mistakes[f"gyro_{a} and gyro_{b} swapped"] = (_IDENTITY, swapped)
        mistakes[f"{a} and {b} swapped in both sensors"] = (swapped, swapped)
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    mistakes["the accelerometer turned +90 deg about z against the gyro"] = (quarter, _IDENTITY)
    mistakes["the accelerometer turned -90 deg about z against the gyro"] = (quarter.T, _IDENTITY)
    return mistakes


COLUMN_MISTAKES = _column_mistakes()


def handedness_note_3d(imu, gnss: GnssData, enu: np.ndarray, gravity: float) -> str | None:
    """A warning line when the accelerometer fits the fixes in 3-D far better with one
    column mistake undone (see WINDOW_3D_S); None when as given fits, or the flight's
    windows cannot tell (straight and level, or too few). Raises :class:`InputError` where
    it fits MIRRORED_3D_ERROR_RATIO times better: no solution from such data is right."""
    fit = handedness_fit_3d(imu, gnss, enu, gravity)
    if fit is None or not fit[1]:
        return None
    as_given, mistakes = fit
    name = min(mistakes, key=mistakes.__getitem__)
    ratio = as_given / max(mistakes[name], 1e-12)
    if ratio < MIRRORED_3D_RATIO:
        return None
    text = (
        "the IMU's axes look wrong: carried by the gyro, the accelerometer fits the fixes' "
        f"specific force through one rotation only with {name} (residual "
        f"{mistakes[name]:.2f} m/s^2 against {as_given:.2f} as given, {ratio:.1f}x; "
        "similar mistakes may fit as well); check the column mapping (accel_x, accel_y, "
        "accel_z and gyro_x, gyro_y, gyro_z must be the same right-handed axes)"
    )
    if ratio >= MIRRORED_3D_ERROR_RATIO:
        raise InputError(f"imu: {text}")
    return f"imu: {text}: the solution is wrong if so"


# A fit as given within this RMS (m/s^2) leaves no room for a mistake undone to fit
# MIRRORED_3D_RATIO times better: the fixes' own acceleration noise is ~0.06 of it with
# 0.1 m/s velocities (right-handed flights and multirotors 0.06-0.08, a consumer aircraft
# 0.19; mistaken ones 0.21-0.95). The mistakes are fitted only above it: 21 of them cost
# about 2 s per 10 min of a 100 Hz flight.
SCREEN_3D_M_S2 = 0.1


def handedness_fit_3d(
    imu, gnss: GnssData, enu: np.ndarray, gravity: float, *, screen: bool = True
) -> tuple[float, dict[str, float]] | None:
    """(RMS residual of the data as given, {mistake undone: its RMS residual}) over the
    flight's windows, m/s^2 (no mistake fitted where ``screen`` and the data as given fit
    within SCREEN_3D_M_S2); None with fewer than MIN_WINDOWS_3D windows."""
    if screen:
        first = _fit_3d(imu, gnss, enu, gravity, {})
        if first is None or first[0] <= SCREEN_3D_M_S2:
            return first
    return _fit_3d(imu, gnss, enu, gravity, COLUMN_MISTAKES)


def _fit_3d(
    imu, gnss: GnssData, enu: np.ndarray, gravity: float, mistakes: dict[str, tuple[np.ndarray, np.ndarray]]
) -> tuple[float, dict[str, float]] | None:
    from fgins.geodesy import skew_batch, so3_exp

    t = gnss.t
    velocity = _velocity_3d(gnss)
    half = HALF_BOX_3D_S if velocity is not None else POSITION_WINDOW_S / 2
    start, end = max(t[0], imu.t[0]) + 2 * half, min(t[-1], imu.t[-1]) - 2 * half
    if end - start < MIN_WINDOWS_3D * WINDOW_3D_S:
        return None
    # A mistake M made the data M x from the true x: undone, x = M^T data (rows: data @ M).
    hypotheses = {"as given": (_IDENTITY, _IDENTITY), **mistakes}
    squared = dict.fromkeys(hypotheses, 0.0)
    count = 0
    starts = np.arange(start, end - WINDOW_3D_S + 1e-9, WINDOW_3D_S)
    if starts.size > MAX_WINDOWS_3D:  # a long flight: evenly spread windows tell as well
        starts = starts[np.linspace(0, starts.size - 1, MAX_WINDOWS_3D).round().astype(int)]
    for window_start in starts:
        grid = np.arange(window_start, window_start + WINDOW_3D_S, 1.0)
        ends = np.clip(np.searchsorted(t, grid + np.array([[-half], [half]])), 1, t.size - 1)
        if np.max(t[ends] - t[ends - 1]) > half:  # a gap in the fixes: no acceleration there
            continue
        specific = _fixes_acceleration(grid, t, enu, velocity, half) + np.array([0.0, 0.0, gravity])
        lo = np.searchsorted(imu.t, grid[0] - 2 * half)
        hi = np.searchsorted(imu.t, grid[-1] + 2 * half)
        if hi - lo < 10 * grid.size:
            continue
        times = imu.t[lo:hi]
        steps = np.diff(times)[:, None]
        turned: dict[bytes, np.ndarray] = {}  # per gyro matrix: the gyro's carried frames
        tau = grid - grid.mean()
        for name, (accel_mistake, gyro_mistake) in hypotheses.items():
            key = gyro_mistake.tobytes()
            if key not in turned:
                gyro = imu.gyro[lo:hi] @ gyro_mistake
                turned[key] = _carried(so3_exp(0.5 * (gyro[1:] + gyro[:-1]) * steps))
            carried = np.einsum("nij,nj->ni", turned[key], imu.accel[lo:hi] @ accel_mistake)
            force = _box_means(grid, times, carried, half, velocity is not None)
            squared[name] += _rotation_fit(specific, force, tau, so3_exp, skew_batch)
        count += grid.size
    if count < MIN_WINDOWS_3D * WINDOW_3D_S:
        return None
    rms = {name: float(np.sqrt(value / count)) for name, value in squared.items()}
    as_given = rms.pop("as given")
    return as_given, rms


def _velocity_3d(gnss: GnssData) -> np.ndarray | None:
    if gnss.velocity is None or np.isfinite(gnss.velocity).all(axis=1).mean() < 0.8:
        return None
    return gnss.velocity


def _fixes_acceleration(grid, t, enu, velocity, half) -> np.ndarray:
    """The fixes' acceleration (K, 3) at ``grid``: the velocity's difference over +-half, or
    the positions' second difference over +-half."""
    if velocity is not None:
        known = np.isfinite(velocity).all(axis=1)
        at = [np.column_stack([np.interp(x, t[known], velocity[known, k]) for k in range(3)])
              for x in (grid - half, grid + half)]  # fmt: skip
        return (at[1] - at[0]) / (2.0 * half)
    at = [np.column_stack([np.interp(x, t, enu[:, k]) for k in range(3)])
          for x in (grid - half, grid, grid + half)]  # fmt: skip
    return (at[2] - 2.0 * at[1] + at[0]) / half**2


def _carried(steps: np.ndarray) -> np.ndarray:
    """Prefix products of the rotation steps (n, 3, 3): (n + 1) rotations from the first
    sample's axes, a doubling scan of batched 3x3 products (vectorised, log2 n passes)."""
    out = np.concatenate([np.eye(3)[None], steps])
    shift = 1
    while shift < len(out):
        out[shift:] = np.einsum("nij,njk->nik", out[:-shift], out[shift:])
        shift *= 2
    return out


def _box_means(grid, times, values, half, box: bool) -> np.ndarray:
    """Means of ``values`` (n, 3) over +-half about ``grid`` (box), or the triangle a
    second difference of positions weighs them by."""
    dt = np.diff(times)[:, None]
    once = np.vstack([np.zeros(3), np.cumsum(0.5 * (values[1:] + values[:-1]) * dt, axis=0)])
    if box:
        at = [np.column_stack([np.interp(x, times, once[:, k]) for k in range(3)])
              for x in (grid - half, grid + half)]  # fmt: skip
        return (at[1] - at[0]) / (2.0 * half)
    twice = np.vstack([np.zeros(3), np.cumsum(0.5 * (once[1:] + once[:-1]) * dt, axis=0)])
    at = [np.column_stack([np.interp(x, times, twice[:, k]) for k in range(3)])
          for x in (grid - half, grid, grid + half)]  # fmt: skip
    return (at[2] - 2.0 * at[1] + at[0]) / half**2


def _rotation_fit(specific, force, tau, so3_exp, skew_batch, iterations: int = 3) -> float:
    """Sum of squared residuals of ``specific = C Exp(w tau) force`` (C a proper rotation,
    ``w`` a slow rotation for the gyro's bias): Kabsch, then Gauss-Newton on both, each step
    halved until it lowers the residual (never above Kabsch's)."""
    u, _, vt = np.linalg.svd(force.T @ specific)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ fix @ u.T
    drift = np.zeros(3)

    def residual_of(rotation: np.ndarray, drift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        moved = np.einsum("nij,nj->ni", so3_exp(drift[None] * tau[:, None]), force)
        return specific - moved @ rotation.T, moved

    residual, moved = residual_of(rotation, drift)
    cost = float(np.sum(residual**2))
    for _ in range(iterations):
        jacobian = np.einsum("ij,njk->nik", rotation, skew_batch(moved))
        system = np.concatenate([jacobian, jacobian * tau[:, None, None]], axis=2).reshape(-1, 6)
        step = np.linalg.lstsq(system, -residual.reshape(-1), rcond=None)[0]
        # Undamped, a window of steady flight (the specific force barely turning: rotation
        # and drift nearly inseparable) stepped from 0.36 to 12 m/s^2, and right-handed
        # data read as mirrored.
        for _halving in range(8):
            trial_rotation, trial_drift = rotation @ so3_exp(step[:3]), drift + step[3:]
            trial, trial_moved = residual_of(trial_rotation, trial_drift)
            trial_cost = float(np.sum(trial**2))
            if trial_cost < cost:
                break
            step = step / 2
        else:
            break
        rotation, drift, residual, moved, cost = trial_rotation, trial_drift, trial, trial_moved, trial_cost
    return cost
