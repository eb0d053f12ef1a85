"""Shared fixtures. Tests import the package as ``fgins`` (never the repository root)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def shared_dir() -> Path | None:
    """The read-only ``shared/`` folder beside the checkout (or $FGINS_SHARED)."""
    candidates = [os.environ.get("FGINS_SHARED"), Path(__file__).resolve().parents[2] / "shared"]
    for candidate in candidates:
        if candidate and Path(candidate).is_dir():
            return Path(candidate)
    return None


@pytest.fixture
def no_loading(monkeypatch):
    """fgins.api.load refused: a command that must stop on its arguments or its output path
    before it reads any input fails the test if it loads one."""
    from fgins import api

    def refuse(*args, **kwargs):
        raise AssertionError("the input was loaded although the command was refused first")

    monkeypatch.setattr(api, "load", refuse)


@pytest.fixture(scope="session")
def kitti():
    from fgins.io.kitti import read_kitti

    return read_kitti()


@pytest.fixture(scope="session")
def kitti_config(kitti):
    from fgins.config import load_config

    return load_config(dataset_imu=kitti.imu_config, dataset_gnss=kitti.gnss_config)


@pytest.fixture(scope="session")
def shared() -> Path:
    """The shared/ folder with the real NMEA logs; skips the test where it is absent."""
    folder = shared_dir()
    if folder is None:
        pytest.skip("../shared (real NMEA logs) not present; set FGINS_SHARED")
    return folder
