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

from featmap.errors import InputFileError
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


WALL_LIST = """scans:
  drive/0000000000.bin:
    walls:
      - {name: front, p: [0, 5], q: [10, 5]}
"""


def test_a_key_given_twice_in_a_wall_list_is_one_line_naming_the_line(tmp_path):
    """Read as strictly as a config file: PyYAML alone keeps the last 'q' without a word."""
    path = tmp_path / "walls.yaml"
    path.write_text(WALL_LIST.replace("q: [10, 5]}", "q: [10, 5], q: [20, 5]}"))
    with pytest.raises(InputFileError, match=r"walls.yaml:4: not valid YAML \('q' is given twice\)") as info:
        read_wall_lists(path)
    assert "\n" not in str(info.value) and info.value.line == 4


def test_exponent_numbers_in_a_wall_list_are_numbers(tmp_path):
    """1e1 and 5e-1 without a dot are numbers, as in a config file (YAML 1.1 reads them as strings, and
    'max_unlisted' refused the string)."""
    path = tmp_path / "walls.yaml"
    path.write_text(WALL_LIST.replace("q: [10, 5]}", "q: [1e1, 5]}\n    max_unlisted: 1e1") + "tolerance_m: 5e-1\n")
    lists = read_wall_lists(path)
    scan = lists.scans["drive/0000000000.bin"]
    assert (scan.max_unlisted, lists.tolerance_m, list(scan.walls[0].q)) == (10, 0.5, [10.0, 5.0])


def test_a_segment_lies_on_a_listed_wall_when_half_of_it_does():
    import numpy as np

    from featmap.evaluation.wall_lists import ListedLine, lying_on

    line = ListedLine("front", np.array([0.0, 5.0]), np.array([10.0, 5.0]))
    segments = [[2, 5.2, 8, 5.2],        # along it, 0.2 m off
                [7, 5.0, 14, 5.0],       # 3.5 m of 7 m within its extent and 0.5 m of its end
                [8, 5.0, 14, 5.0],       # 2.5 m of 6 m
                [5, 5.8, 9, 5.8],        # 0.8 m off
                [2, 4.0, 2, 6.0]]        # across it
    assert lying_on(segments, line, 0.5).tolist() == [True, True, False, False, False]
    assert lying_on(np.zeros((0, 4)), line).tolist() == []
