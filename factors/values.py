"""Typed, fast writes into a ``gtsam.Values``.

``Values.insert_or_assign`` has ~46 pybind overloads, tried in order with conversion; a
positional ConstantBias or float reaches its overload only after every geometry type and
the numpy casters have refused it: ~0.1-0.2 ms a call, which was a sizeable part of an
iSAM2 update (issue 9). Naming the value's keyword (the overload's parameter name) lets
pybind skip every other overload without converting anything: ~5-30 us.
"""

from __future__ import annotations

import gtsam
import numpy as np


def put_pose(values: gtsam.Values, key: int, pose: gtsam.Pose3) -> None:
    values.insert_or_assign(key, pose3=pose)


def put_vector(values: gtsam.Values, key: int, vector: np.ndarray) -> None:
    values.insert_or_assign(key, vector=np.asarray(vector, dtype=float))


def put_bias(values: gtsam.Values, key: int, bias: gtsam.imuBias.ConstantBias) -> None:
    values.insert_or_assign(key, constant_bias=bias)


def put_double(values: gtsam.Values, key: int, value: float) -> None:
    values.insert_or_assign(key, c=float(value))
