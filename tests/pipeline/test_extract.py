"""Extraction of a whole source: the world-frame points each scan contributes, with their scans."""

import numpy as np

from featmap.datasets.carmen import CarmenSource
from featmap.pipeline import SegmentStore, load_config
from featmap.pipeline.extract import extract_source
from tests.conftest import write_room_log


def test_world_points_carry_the_frame_of_the_scan_they_came_from(tmp_path):
    source = CarmenSource(write_room_log(tmp_path / "room.log", np.random.default_rng(0), n_scans=12),
                          frames=slice(2, 12, 3))
    extraction = extract_source(source, load_config("indoor_2d").extraction, SegmentStore(None))
    points, scans = extraction.world_points(), extraction.world_point_scans()
    assert extraction.frames == [2, 5, 8, 11] and len(scans) == len(points)
    for frame, segments, pose in zip(extraction.frames, extraction.scans, extraction.poses):
        assert np.array_equal(points[scans == frame], segments.support_points_world(pose))


def test_world_table_keeps_the_max_gap_column_when_the_first_scans_are_empty():
    """An empty scan has no max_gap (``ScanSegments.empty``); the scans with segments still carry theirs."""
    from featmap.extraction.base import ScanSegments
    from featmap.pipeline.extract import Extraction

    wall = ScanSegments(segments=np.array([[5.0, -2.0, 5.0, 2.0]]), n_points=np.array([400]), rms=np.array([0.02]),
                        z_mean=np.array([0.5]), z_min=np.array([-1.5]), z_max=np.array([2.0]),
                        max_gap=np.array([0.07]))
    poses = np.repeat(np.eye(4)[None], 3, axis=0)
    poses[:, 0, 3] = [0.0, 1.0, 2.0]
    table = Extraction([0, 1, 2], [ScanSegments.empty(), wall, ScanSegments.empty()], poses, 3).world_table()
    assert table.scan.tolist() == [1] and table.extra["max_gap"].tolist() == [0.07]
    assert table.segments.tolist() == [[6.0, -2.0, 6.0, 2.0]]


def test_world_table_says_where_the_sensor_stood_for_each_segment():
    """sensor_x / sensor_y (the fusion's visibility clause reads them) are the translation of the pose the
    table was made with: the source's, or refined poses given instead."""
    from featmap.extraction.base import ScanSegments
    from featmap.pipeline.extract import Extraction

    two = ScanSegments(segments=np.array([[5.0, -2.0, 5.0, 2.0], [8.0, 1.0, 9.0, 1.0]]), n_points=np.array([400, 50]),
                       rms=np.array([0.02, 0.03]))
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[:, :2, 3] = [[0.0, 0.0], [3.0, -1.0]]
    extraction = Extraction([0, 1], [two, two], poses, 2)
    table = extraction.world_table()
    assert table.extra["sensor_x"].tolist() == [0.0, 0.0, 3.0, 3.0]
    assert table.extra["sensor_y"].tolist() == [0.0, 0.0, -1.0, -1.0]
    refined = poses.copy()
    refined[1, :2, 3] = [3.5, -0.5]
    again = extraction.world_table(refined)
    assert again.extra["sensor_x"].tolist()[2:] == [3.5, 3.5] and again.extra["sensor_y"].tolist()[2:] == [-0.5, -0.5]
