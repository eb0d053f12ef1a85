"""Error metrics of a trajectory against a reference (truth or withheld GNSS)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import Trajectory
from fgins.outages import in_windows


@dataclass
class Errors:
    """Horizontal/vertical errors (m) at reference epochs, split by inside/outside outages."""

    t: np.ndarray
    horizontal: np.ndarray
    vertical: np.ndarray
    inside: np.ndarray
    horizontal_std: np.ndarray

    @staticmethod
    def _rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")

    def summary(self) -> dict[str, float]:
        out = {
            "h_rms_outage": self._rms(self.horizontal[self.inside]),
            "h_max_outage": float(self.horizontal[self.inside].max())
            if self.inside.any()
            else float("nan"),
            "v_rms_outage": self._rms(self.vertical[self.inside]),
            "h_rms_aided": self._rms(self.horizontal[~self.inside]),
            "v_rms_aided": self._rms(self.vertical[~self.inside]),
            "h_rms_all": self._rms(self.horizontal),
        }
        # Fraction of outage epochs whose horizontal error is inside the reported 3 sigma.
        if self.inside.any() and np.all(np.isfinite(self.horizontal_std[self.inside])):
            within = self.horizontal[self.inside] <= 3 * self.horizontal_std[self.inside]
            out["within_3sigma_outage"] = float(within.mean())
        return out


def errors_against(
    trajectory: Trajectory,
    reference_t: np.ndarray,
    reference_enu: np.ndarray,
    t0: float,
    windows: list[tuple[float, float]],
) -> Errors:
    """Errors of ``trajectory`` (interpolated) at the reference epochs it spans."""
    span = (reference_t >= trajectory.t[0]) & (reference_t <= trajectory.t[-1])
    t = reference_t[span]
    estimate = trajectory.at(t)
    difference = estimate - reference_enu[span]
    std = np.column_stack(
        [np.interp(t, trajectory.t, trajectory.position_std[:, i]) for i in range(2)]
    )
    return Errors(
        t=t,
        horizontal=np.linalg.norm(difference[:, :2], axis=1),
        vertical=np.abs(difference[:, 2]),
        inside=in_windows(t, t0, windows),
        horizontal_std=np.linalg.norm(std, axis=1),
    )
