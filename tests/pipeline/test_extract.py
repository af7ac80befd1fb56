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
