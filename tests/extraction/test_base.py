"""The per-scan result, its round trip through plain arrays, the world transform, and the registry."""

import numpy as np
import pytest

from featmap.errors import ConfigError
from featmap.extraction import EXTRACTORS, ExtractionConfig, ScanSegments, extract_scan, extractor_for, world_fields
from featmap.extraction.base import segments_to_world

QUARTER_TURN = np.array([[0.0, -1.0, 0.0, 100.0], [1.0, 0.0, 0.0, 50.0], [0.0, 0.0, 1.0, 2.0], [0, 0, 0, 1]])


def _three_d():
    return ScanSegments(segments=np.array([[12.0, -10.0, 12.0, 8.0]]), n_points=np.array([300]), rms=np.array([0.02]),
                        z_mean=np.array([0.5]), z_min=np.array([-1.7]), z_max=np.array([2.4]))


def test_world_transform_of_a_3d_piece_moves_both_endpoints_and_heights():
    world = segments_to_world(_three_d(), QUARTER_TURN)
    # (x, y) -> (100 - y, 50 + x) for a quarter turn about z
    assert world[0] == pytest.approx([110.0, 62.0, 92.0, 62.0])
    fields = world_fields(_three_d(), QUARTER_TURN)
    assert fields["z_min"][0] == pytest.approx(0.3) and fields["z_max"][0] == pytest.approx(4.4)
    assert list(fields) == ["n_points", "z_min", "z_max", "rms"]


def test_a_2d_scan_has_no_heights_and_stays_in_the_plane():
    two_d = ScanSegments(np.array([[1.0, 2.0, 3.0, 2.0]]), np.array([10]), np.array([0.01]))
    assert two_d.dimension == 2
    assert segments_to_world(two_d, QUARTER_TURN)[0] == pytest.approx([98.0, 51.0, 98.0, 53.0])
    assert list(world_fields(two_d, QUARTER_TURN)) == ["n_points", "rms"]


def test_arrays_round_trip_and_bad_arrays_are_refused():
    for segs in (_three_d(), ScanSegments.empty(2), ScanSegments.empty(3)):
        back = ScanSegments.from_arrays(segs.arrays())
        assert back.dimension == segs.dimension
        for key, value in segs.arrays().items():
            assert np.array_equal(getattr(back, key), value)
    bad = _three_d().arrays()
    bad["rms"] = np.zeros(3)
    with pytest.raises(ValueError, match="'rms' has shape"):
        ScanSegments.from_arrays(bad)


def test_the_registry_picks_the_extractor_of_the_scan_dimension():
    cfg = ExtractionConfig()
    extractor = extractor_for(3, cfg)
    assert extractor.dimension == 3 and extractor.name == cfg.method_3d
    assert set(e.name for e in EXTRACTORS) <= set(ExtractionConfig.model_fields)
    with pytest.raises(ConfigError, match="no extractor for 7D scans"):
        extractor_for(7, cfg)
    assert len(extract_scan(np.zeros((0, 4), np.float32), 3, cfg)) == 0
