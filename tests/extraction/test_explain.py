"""featmap.extraction.explain and ``featmap explain``: the tests each piece of a scan fails, near a point or
counted per test; bad input is one line and exit status 2."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.extraction.explain import explain_scan
from featmap.extraction.vertical_structure import PieceTests, extract_vertical_structure
from tests.conftest import write_room_log
from tests.extraction.test_vertical_structure import building, cast_scan


@pytest.fixture(scope="module")
def fence_scan() -> np.ndarray:
    """A building front at x 30 (y -25..25) and a 1.4 m fence along x 8 from y 3 to 15 (HDL-64E)."""
    return cast_scan([building(30, -25, 45, 25, 12.0), {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4}])


def test_the_fence_near_a_point_fails_the_top_and_tall_tests_and_the_front_passes_both_stages(fence_scan):
    explanation = explain_scan(fence_scan)
    np.testing.assert_array_equal(explanation.result.segments, extract_vertical_structure(fence_scan).segments)
    (fence,) = [v for v in explanation.near((8.0, 9.0), 0.3) if v.length_m > 3]
    assert (fence.stage, fence.failed) == ("height", ("top", "tall"))
    assert fence.length_m == pytest.approx(12, abs=0.3) and fence.distance_m < 0.1
    assert fence.measured["top_m"] == pytest.approx(1.4, abs=0.15) and fence.measured["returns"] > 100
    assert fence.measured_text().startswith(f"returns {fence.measured['returns']:.0f}, top 1.")
    front = [v for v in explanation.near((30.0, 0.0), 0.2) if v.length_m > 40]
    assert [(v.stage, v.failed) for v in front] == [("height", ()), ("final", ())]
    assert front[1].measured["rms_m"] == pytest.approx(0.02, abs=0.01) and set(front[1].measured) == {"returns", "rms_m", "core", "behind"}
    assert explanation.failure_counts("height")["tall"] >= 1 and explanation.failure_counts("final")["rms"] == 0


def test_pieces_near_a_point_come_nearest_first_in_the_velodyne_frame():
    from featmap.extraction.explain import ScanExplanation
    from featmap.extraction.base import ScanSegments

    tests = PieceTests(a=np.array([[10.0, 0.0], [10.0, 5.0], [40.0, 0.0]]), b=np.array([[10.0, 4.0], [12.0, 5.0], [40.0, 9.0]]),
                       passed={"tall": np.array([True, False, True]), "top": np.array([True, False, False])})
    explanation = ScanExplanation(ScanSegments.empty(), {"height": tests}, np.eye(3))
    near = explanation.near((10.5, 4.5), 1.0)
    assert [round(v.distance_m, 2) for v in near] == [0.5, 0.71]         # to (10.5, 5), to the end (10, 4)
    assert [v.failed for v in near] == [("tall", "top"), ()]
    assert explanation.failure_counts("height") == {"tall": 1, "top": 2}
    turned = ScanExplanation(ScanSegments.empty(), {"height": tests},
                             np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))   # levelled = R @ velodyne
    (piece,) = turned.near((0.0, -10.0), 0.1)
    assert np.allclose(piece.segment, [0.0, -10.0, 4.0, -10.0])


def test_a_scan_with_too_few_returns_has_no_stage():
    explanation = explain_scan(np.array([[10.0, 0.0, 0.5]] * 5))
    assert explanation.stages == {} and len(explanation.result) == 0 and explanation.near((10, 0), 5) == []


def test_the_command_lists_the_pieces_near_a_point_and_counts_without_one(fence_scan, tmp_path):
    path = tmp_path / "fence.bin"
    fence_scan.astype("<f4").tofile(path)
    res = CliRunner().invoke(app, ["explain", str(path), "--at", "8,9", "--radius", "0.3"])
    assert res.exit_code == 0, res.output
    assert "1 wall segment(s)" in res.output and "top, tall" in res.output and "returns" in res.output
    res = CliRunner().invoke(app, ["explain", str(path)])
    assert res.exit_code == 0, res.output
    assert "pieces failing it" in res.output and "not_trunk" in res.output


def test_the_command_draws_the_pieces_into_a_png(fence_scan, tmp_path):
    path = tmp_path / "fence.bin"
    fence_scan.astype("<f4").tofile(path)
    png = tmp_path / "out" / "why.png"
    res = CliRunner().invoke(app, ["explain", str(path), "--at", "8,9", "--plot", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"wrote {png}" in " ".join(res.output.split())
    assert [p.name for p in png.parent.iterdir()] == ["why.png"]            # no temporary file left


def test_the_command_explains_a_frame_of_a_drive(case1_drive):
    res = CliRunner().invoke(app, ["explain", "--drive", case1_drive.drive, "--data-dir", str(case1_drive.root),
                                   "--frame", "20"])
    assert res.exit_code == 0, res.output
    assert "frame 20" in res.output and "final tests" in res.output


def test_bad_input_is_one_line_and_status_2(case1_drive, tmp_path):
    log = write_room_log(tmp_path / "room.log", np.random.default_rng(0), n_scans=5)
    drive = ["--drive", case1_drive.drive, "--data-dir", str(case1_drive.root)]
    cases = [(["explain", str(tmp_path / "nowhere.bin")], "scan file not found"),
             (["explain", "x.bin", "--at", "1,a"], "--at '1,a': expected X,Y"),
             (["explain", "x.bin", "--at", "1,nan"], "expected X,Y"),
             (["explain", "x.bin", "--world", "residential"], "leave out --world"),
             (["explain", "x.bin", "--frame", "3", "--data-dir", "d"], "leave out --data-dir, --frame"),
             (["explain", *drive, "--frame", "40"], "--frame 40: "),
             (["explain", "--dataset", "carmen", "--source", str(log)], "2D source"),
             (["explain", "x.bin", "--set", "extraction.method_3d=ransac_planes"], "vertical_structure only"),
             (["explain", "x.bin", "--radius", "-1"], "--radius"),
             (["explain", "x.bin", "--plot", "why.jpg"], "--plot why.jpg: the drawing is a PNG")]
    for args, says in cases:
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 2, (args, res.output)
        lines = res.output.strip().splitlines()
        assert len(lines) == 1 and says in lines[0], (args, res.output)
