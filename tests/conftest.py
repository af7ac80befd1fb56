"""Shared fixtures: small simulated drives with ground truth (seconds to make)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
from pathlib import Path

import pytest

SIGINT_IGNORED_AT_START = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
"""The test process itself started with Ctrl-C ignored (e.g. a background job of a non-interactive shell)."""

LOOPBACK_ONLY = Path(__file__).resolve().parent / "loopback_only"
# Every Python process the tests start imports loopback_only/sitecustomize.py first and talks to 127.0.0.1 only.
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(LOOPBACK_ONLY), os.environ.get("PYTHONPATH", "")) if p)


def _load_loopback_guard():
    spec = importlib.util.spec_from_file_location("featmap_tests_loopback_only", LOOPBACK_ONLY / "sitecustomize.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


LOOPBACK_GUARD = _load_loopback_guard()


@pytest.fixture(autouse=True)
def _no_traffic_beyond_this_machine(monkeypatch):
    """Tests talk to 127.0.0.1 only (a local tile server, a local Dask scheduler): a connection or a name lookup
    for any other host is refused at once (``loopback_only/sitecustomize.py``; the processes the tests start
    import it themselves), so the code under test takes its offline path and nothing reaches the outside."""
    for owner, attribute, function in LOOPBACK_GUARD.guarded().values():
        monkeypatch.setattr(owner, attribute, function)


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


# A 12 m x 8 m room: a 1 m doorway in the north wall, a 1 m x 1 m pillar in the middle.
ROOM_WITH_PILLAR = ([0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 6.5, 8], [5.5, 8, 0, 8], [0, 8, 0, 0],
        [5.5, 8, 5.5, 9], [6.5, 8, 6.5, 9],
        [6, 3, 7, 3], [7, 3, 7, 4], [7, 4, 6, 4], [6, 4, 6, 3])


def write_room_log(path: Path, rng, n_scans: int = 60, slam: bool = False, first_pose_error=(0.0, 0.0, 0.0)) -> Path:
    """A CARMEN log of a robot driving a loop around the pillar (1 cm range noise, exact poses).

    ``slam``: the log's ODOM records are zeros (as in a SLAM-corrected log) instead of the scan poses;
    ``first_pose_error``: (dx, dy, dtheta) added to the first scan's logged pose."""
    import numpy as np

    from featmap.io.carmen import carmen_beam_angles, flaser_log_text
    from featmap.simulation.segments import cast_rays_2d

    angles = carmen_beam_angles(180)
    phi = 2 * np.pi * np.arange(n_scans) / n_scans
    poses = np.column_stack([6.5 + 4.0 * np.cos(phi), 3.5 + 2.2 * np.sin(phi), phi + np.pi / 2])
    ranges = []
    for pose in poses:
        r = cast_rays_2d(np.array(ROOM_WITH_PILLAR, float), pose, angles, max_range=81.83)
        ranges.append(np.where(r < 81.83, r + rng.normal(0, 0.01, len(r)), r))
    logged = poses.copy()
    logged[0] += first_pose_error
    text = flaser_log_text(np.array(ranges), logged, 0.2 * np.arange(n_scans), odometry=None if slam else logged,
                           comment="synthetic")
    path.write_text("PARAM robot_frontlaser_offset 0.0 nohost 0\n" + text)
    return path


TINY_WORLD = """name: tiny
geo_origin: {lat: 49.0100, lon: 8.4200}
route: {waypoints: [[0, 0], [24, 0]], speed_mps: 8, turn_radius_m: 0}
objects:
  - {id: A, kind: building, footprint: [[-5, 6], [15, 6], [15, 16], [-5, 16]], height: 8}
  - {id: B, kind: building, footprint: [[18, 6], [40, 6], [40, 14], [18, 14]], height: 10}
  - {id: C, kind: building, footprint: [[0, -16], [30, -16], [30, -7], [0, -7]], height: 9}
"""


@pytest.fixture(scope="session")
def tiny_worlds(tmp_path_factory) -> Path:
    """Three 24 m drives along one short street with three buildings (about 30 HDL-64E frames each):
    ``tiny.yaml`` and two worlds that extend it with other routes (``tiny_b`` driven the other way)."""
    folder = tmp_path_factory.mktemp("tiny_worlds")
    (folder / "tiny.yaml").write_text(TINY_WORLD)
    (folder / "tiny_b.yaml").write_text("name: tiny_b\nextends: tiny.yaml\n"
                                        "route: {waypoints: [[32, 0], [8, 0]], speed_mps: 8, turn_radius_m: 0}\n")
    (folder / "tiny_c.yaml").write_text("name: tiny_c\nextends: tiny.yaml\n"
                                        "route: {waypoints: [[12, 0], [36, 0]], speed_mps: 8, turn_radius_m: 0}\n")
    return folder


@pytest.fixture(scope="session")
def dask_client():
    """A LocalCluster of two single-threaded worker processes on 127.0.0.1 (no dashboard), and its client."""
    pytest.importorskip("distributed")
    from distributed import Client

    from featmap.batch import local_cluster

    cluster = local_cluster(2)
    client = Client(cluster)
    yield client
    client.close()
    cluster.close()


def untimed_metrics(folder: Path) -> dict:
    """A run's metrics.json without what depends on timing or on the cache (timings, seconds, scans
    extracted now or served from the cache): what two equivalent runs must agree on."""
    import json

    metrics = json.loads((Path(folder) / "metrics.json").read_text())
    metrics.pop("timings_s")
    for record in metrics["methods"].values():
        record.pop("seconds")
    if metrics.get("refinement"):
        metrics["refinement"].pop("seconds")
    metrics["scans"].pop("extracted_now")
    metrics["scans"].pop("from_cache")
    return metrics
