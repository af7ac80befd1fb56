"""scripts/see_through_shares.py: one share per piece the final tests passed, also where the extractor then
joins two pieces of one wall (extend_hidden_m)."""

import numpy as np
import pytest

from tests.extraction.test_vertical_structure import building, cast_scan, on_line
from tests.repo_scripts import repo_script


@pytest.fixture(scope="module")
def script():
    with repo_script("scripts/see_through_shares.py") as module:
        yield module


def test_a_wall_the_extractor_joins_over_a_bush_has_a_share_per_piece(script):
    from featmap.extraction.vertical_structure import VerticalStructureConfig, extract_vertical_structure

    bush = {"kind": "tree", "position": [12.0, -13.3], "trunk_height": 0.8, "trunk_radius": 0.1, "crown_radius": 1.4}
    scan = cast_scan([building(10, -15.3, 35, -15.0, 2.2), bush])
    config = VerticalStructureConfig()
    assert len(extract_vertical_structure(scan, config)) == 1           # joined under the bush
    pieces, shares, sparse = script.extract_with_shares(scan, config)
    assert len(pieces) == len(shares) == len(sparse) == 2
    assert all(on_line(s, [10, -15], [35, -15], 0.05) for s in pieces.segments)
    assert np.all(shares < 0.05) and not sparse.any()                   # a wall hides what is behind it


def test_a_scan_with_no_wall_has_no_share(script):
    from featmap.extraction.vertical_structure import VerticalStructureConfig

    pieces, shares, sparse = script.extract_with_shares(np.array([[10.0, 0.0, 0.5, 0.0]] * 5), VerticalStructureConfig())
    assert len(pieces) == len(shares) == len(sparse) == 0
