"""Shared fixtures: small simulated drives with ground truth (seconds to make)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

SHARED = Path(os.environ.get("FEATMAP_SHARED", Path(__file__).resolve().parents[1] / ".." / "shared")) / "data"


@pytest.fixture(scope="session")
def case1_drive(tmp_path_factory):
    """prescan_case1 (one building), 40 frames of a 32-beam sensor: 32 m of driving along its south wall."""
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import simulate_drive
    from featmap.simulation.worlds import load_world

    root = tmp_path_factory.mktemp("case1")
    return simulate_drive(load_world("prescan_case1"), root, SENSORS["vlp32"], n_frames=40, seed=0)


@pytest.fixture
def drive_copy(case1_drive, tmp_path):
    """A private copy of ``case1_drive`` that a test may corrupt."""
    dst = tmp_path / "kitti"
    shutil.copytree(case1_drive.root, dst)
    return dst, case1_drive.drive


def shared_data(*parts) -> Path:
    path = SHARED.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} not available (../shared/data is optional)")
    return path
