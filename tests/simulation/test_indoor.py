"""Simulated indoor floors: deterministic, readable as a CARMEN log, and mapped onto their true surfaces."""

import numpy as np
from typer.testing import CliRunner

from featmap.cli import app
from featmap.evaluation.map_metric import SegmentIndex, sample_segments
from featmap.geometry import move_segments_2d, rigid_motion_2d
from featmap.io.carmen import carmen_beam_angles, flaser_log_text, read_carmen
from featmap.io.pose_csv import read_trajectory_xy
from featmap.io.segments_csv import read_fused_csv
from featmap.simulation.indoor import INDOOR_SEEDS, NO_RETURN_M, generate_indoor


def test_a_floor_is_the_same_for_the_same_seed_and_its_beams_land_on_its_surfaces():
    a, b = generate_indoor(INDOOR_SEEDS[0]), generate_indoor(INDOOR_SEEDS[0])
    assert np.array_equal(a.surfaces, b.surfaces) and np.array_equal(a.ranges, b.ranges)
    assert not np.array_equal(a.surfaces, generate_indoor(INDOOR_SEEDS[1]).surfaces)
    # every return, placed with the true pose, lies within the range noise (<= 2 cm, 5 sigma) of a surface
    angles = carmen_beam_angles(a.ranges.shape[1])
    k = np.arange(0, len(a.poses), 25)
    heading = a.poses[k, 2:3] + angles
    r = a.ranges[k]
    hit = r < NO_RETURN_M
    points = np.stack([a.poses[k, :1] + r * np.cos(heading), a.poses[k, 1:2] + r * np.sin(heading)], axis=-1)[hit]
    assert SegmentIndex(a.surfaces, 0.1).near(points).all()
    # the robot stays in the corridor: no pose within 0.5 m of a surface
    assert not SegmentIndex(a.surfaces, 0.5).near(a.poses[:, :2]).any()


def test_the_log_reads_back(tmp_path):
    drive = generate_indoor(INDOOR_SEEDS[2])
    path = tmp_path / "floor.log"
    path.write_text(flaser_log_text(drive.ranges[:50], drive.logged[:50], drive.stamps[:50], comment="a floor"))
    log = read_carmen(path)
    assert np.allclose(log.ranges, drive.ranges[:50], atol=5e-4)
    assert np.allclose(log.pose, drive.logged[:50], atol=1e-6)


def test_featmap_run_maps_a_floor_onto_its_walls(tmp_path):
    """The indoor preset on a floor it was never tuned on: laid on the floor by its refined
    trajectory (an indoor refinement keeps only its first scan where the log put it), the proposed
    features lie on the true surfaces."""
    drive = generate_indoor(INDOOR_SEEDS[4])                     # two laps: the refinement closes its loop
    path = tmp_path / "floor.log"
    path.write_text(flaser_log_text(drive.ranges, drive.logged, drive.stamps))
    res = CliRunner().invoke(app, ["run", "--carmen", str(path), "--out", str(tmp_path / "run"), "--method", "proposed",
                                   "--cache-dir", str(tmp_path / "cache")])
    assert res.exit_code == 0, res.output
    fused, _ = read_fused_csv(tmp_path / "run" / "fused_proposed.csv")
    assert len(fused) >= 20
    rot, shift = rigid_motion_2d(read_trajectory_xy(tmp_path / "run" / "trajectory_refined.csv"), drive.poses[:, :2])
    points, _, weight = sample_segments(move_segments_2d(fused, rot, shift), 0.02)
    on = SegmentIndex(drive.surfaces, 0.05).near(points)
    assert weight[on].sum() / weight.sum() > 0.97
