"""scripts/real_scan_figures.py: docs/ holds the default configuration; a variant goes to --out."""

import hashlib

import pytest

from tests.conftest import shared_data
from tests.repo_scripts import ROOT, repo_script


@pytest.fixture(scope="module")
def script():
    with repo_script("scripts/real_scan_figures.py") as module:
        yield module


def _docs_digest() -> str:
    files = [ROOT / "docs" / "real_scans.md", *sorted((ROOT / "docs" / "figures" / "real_scans").glob("*.png"))]
    return hashlib.sha256(b"".join(f.read_bytes() for f in files if f.exists())).hexdigest()


def test_a_variant_without_out_is_refused_in_one_line(script, tmp_path, capsys):
    before = _docs_digest()
    assert script.main(["--set", "extraction.vertical_structure.min_core_fraction=0.7", "--data", str(tmp_path)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "--set" in out and "--out" in out
    assert _docs_digest() == before


def test_missing_data_is_one_line_and_writes_nothing(script, tmp_path, capsys):
    out_dir = tmp_path / "out"
    assert script.main(["--data", str(tmp_path / "nowhere"), "--out", str(out_dir)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "nowhere" in out and "not found" in out
    assert not out_dir.exists()


def test_a_variant_writes_its_page_and_figures_under_out_only(script, tmp_path, capsys):
    data = shared_data("kitti_raw_2011_09_26_drive_0001_scans").parent
    shared_data("kitti_object_velodyne")
    before = _docs_digest()
    out_dir = tmp_path / "variant"
    setting = "extraction.vertical_structure.min_points=1000"        # only pieces of >= 1000 returns: fewer walls found
    assert script.main(["--data", str(data), "--set", setting, "--out", str(out_dir)]) == 0
    page = (out_dir / "real_scans.md").read_text()
    assert f"`--set {setting}`" in page
    assert len(list(out_dir.glob("*.png"))) == 8 and "](0000000065.png)" in page
    default_page = (ROOT / "docs" / "real_scans.md").read_text()
    found = lambda text: text.split("**all eight**")[1].split("**")[1]  # noqa: E731
    assert found(page) != found(default_page)          # the variant's own numbers, not the docs'
    assert _docs_digest() == before
    capsys.readouterr()


def test_why_a_wall_was_missed_names_the_tests_its_pieces_failed(script):
    import numpy as np

    from featmap.evaluation.wall_lists import ListedLine
    from featmap.extraction.explain import explain_scan
    from tests.extraction.test_vertical_structure import building, cast_scan

    scan = cast_scan([building(30, -25, 45, 25, 12.0), {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4}])
    explanation = explain_scan(scan)
    fence = ListedLine("fence", np.array([8.0, 3.0]), np.array([8.0, 15.0]))
    why = script.why_missed(explanation, fence, 0.5)
    assert why.split("; ")[0].endswith(" m: top, tall") and float(why.split(" m:")[0]) > 10
    front = ListedLine("front", np.array([30.0, -25.0]), np.array([30.0, 25.0]))
    assert script.why_missed(explanation, front, 0.5) == "no dropped piece of 0.5 m or more"       # found, not dropped
    assert script.why_missed(explain_scan(np.array([[10.0, 0.0, 0.5]] * 5)), fence, 0.5) == "no piece"
