"""The default extractor on the eight real KITTI scans, against the eye-checked lists in
``real_scan_walls.yaml`` (how they were made is written at its top). Skipped without ../shared/data.

Every listed wall must be found (one segment or pieces covering >= 90 % of it), no segment may lie in
a clutter box (cars, hedges, trees) and at most ``max_unlisted`` on nothing listed. Where the current
extractor falls short, the list says why (``known_miss`` / ``known_clutter``) and the test is a
strict xfail: it fails as soon as the shortfall is gone, so the list gets updated.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import pytest

from featmap.extraction import ExtractionConfig, extract_scan
from featmap.io.kitti_raw import read_velo_bin
from featmap.evaluation.wall_lists import read_wall_lists, score_wall_list
from tests.conftest import shared_data

LISTS = read_wall_lists(Path(__file__).with_name("real_scan_walls.yaml"))


@lru_cache(maxsize=None)
def _score(scan: str):
    points = read_velo_bin(shared_data(*scan.split("/")))
    segments = extract_scan(points, 3, ExtractionConfig()).segments
    return segments, score_wall_list(segments, LISTS.scans[scan], LISTS.tolerance_m, LISTS.min_coverage)


def _wall_cases():
    for scan, wall_list in LISTS.scans.items():
        for k, wall in enumerate(wall_list.walls):
            marks = [pytest.mark.xfail(strict=True, reason=wall.known_miss)] if wall.known_miss else []
            yield pytest.param(scan, k, id=f"{Path(scan).stem}-{wall.name}", marks=marks)


@pytest.mark.parametrize("scan,k", list(_wall_cases()))
def test_every_visible_wall_is_found(scan, k):
    segments, score = _score(scan)
    wall = LISTS.scans[scan].walls[k]
    assert score.found[k], (f"{wall.name} {wall.p}->{wall.q}: {score.coverage[k]:.2f} covered; "
                            f"segments:\n{segments.round(1)}")


def _clutter_cases():
    for scan, wall_list in LISTS.scans.items():
        marks = [pytest.mark.xfail(strict=True, reason=wall_list.known_clutter)] if wall_list.known_clutter else []
        yield pytest.param(scan, id=Path(scan).stem, marks=marks)


@pytest.mark.parametrize("scan", list(_clutter_cases()))
def test_no_segment_on_cars_hedges_or_trees(scan):
    segments, score = _score(scan)
    assert score.n_clutter == 0, segments[score.status == "clutter"].round(1)


@pytest.mark.parametrize("scan", list(LISTS.scans), ids=lambda s: Path(s).stem)
def test_few_segments_on_unlisted_structure(scan):
    segments, score = _score(scan)
    assert score.n_unlisted <= LISTS.scans[scan].max_unlisted, segments[score.status == "unlisted"].round(1)


def test_the_lists_cover_both_full_scans_and_the_six_crops():
    assert len(LISTS.scans) == 8
    assert sum(len(w.walls) for w in LISTS.scans.values()) >= 40
