"""scripts/explain_extraction.py: the tests each piece of a scan fails, near a point or counted; bad input
is one line and exit status 2."""

import numpy as np
import pytest

from tests.extraction.test_vertical_structure import building, cast_scan
from tests.repo_scripts import repo_script


@pytest.fixture(scope="module")
def script():
    with repo_script("scripts/explain_extraction.py") as module:
        yield module


@pytest.fixture(scope="module")
def fence_scan(tmp_path_factory):
    """A .bin scan of a building front at x 30 and a 1.4 m fence along x 8 from y 3 to 15."""
    scan = cast_scan([building(30, -25, 45, 25, 12.0), {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4}])
    path = tmp_path_factory.mktemp("scan") / "fence.bin"
    scan.astype("<f4").tofile(path)
    return path


def test_the_fence_near_the_point_fails_the_top_and_tall_tests(script, fence_scan, capsys):
    assert script.main([str(fence_scan), "--at", "8,9", "--radius", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "1 wall segment(s)" in out
    assert "top, tall" in out                              # the fence, at the height stage
    assert "0 within 0.3 m" in out                         # it never reaches the final tests


def test_stage_rows_lists_nearby_pieces_nearest_first_in_the_velodyne_frame(script):
    from featmap.extraction.vertical_structure import PieceTests

    tests = PieceTests(a=np.array([[10.0, 0.0], [10.0, 5.0], [40.0, 0.0]]), b=np.array([[10.0, 4.0], [12.0, 5.0], [40.0, 9.0]]),
                       passed={"tall": np.array([True, False, True]), "top": np.array([True, False, False])})
    rows = script.stage_rows(tests, np.eye(3), np.array([10.5, 4.5]), 1.0)
    assert [round(d, 2) for d, *_ in rows] == [0.5, 0.71]                     # to (10.5, 5), to the end (10, 4)
    assert [failed for *_, failed in rows] == [["tall", "top"], []]
    assert len(script.stage_rows(tests, np.eye(3), None, 1.0)) == 3
    assert script.failure_counts(tests) == {"tall": 1, "top": 2}
    turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])     # levelled = R @ velodyne
    (_, a, b, _), = script.stage_rows(tests, turned, np.array([0.0, -10.0]), 0.1)
    assert np.allclose(a, [0.0, -10.0]) and np.allclose(b, [4.0, -10.0])


def test_without_a_point_it_counts_the_pieces_each_test_drops(script, fence_scan, capsys):
    assert script.main([str(fence_scan)]) == 0
    out = capsys.readouterr().out
    assert "pieces failing it" in out and "not_trunk" in out and "sparse_noise_curve" not in out


@pytest.mark.parametrize("args, says", [
    (["{missing}"], "scan file not found"),
    (["--seed", "7108", "--frame", "0"], "held out"),
    (["--seed", "11", "--frame", "0", "--sim-root", "{missing}"], "is missing"),
])
def test_bad_input_is_one_line_and_status_2(script, tmp_path, capsys, args, says):
    args = [a.format(missing=tmp_path / "nowhere.bin") for a in args]
    assert script.main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err


@pytest.mark.parametrize("args", [[], ["--seed", "11"], ["x.bin", "--seed", "11", "--frame", "0"], ["x.bin", "--at", "1,a"],
                                  ["x.bin", "--radius", "-1"]])
def test_bad_arguments_stop_the_parser(script, args):
    with pytest.raises(SystemExit) as stop:
        script.main(args)
    assert stop.value.code == 2
