"""benchmarks/bench_clutter.py: segments on clutter, counted on a tiny street with a van beside the route."""

import json

import pytest

from tests.conftest import TINY_WORLD
from tests.repo_scripts import repo_script


@pytest.fixture(scope="module")
def bench():
    with repo_script("benchmarks/bench_clutter.py") as module:
        yield module


def test_a_van_beside_the_route_is_counted_as_car_and_the_houses_are_not(bench, tmp_path, monkeypatch, capsys):
    # a 2.3 m van beside the route (its near side 2.5 m from it): to the simulator a 5.2 m box, which the extraction keeps as a wall
    world = tmp_path / "van.yaml"
    world.write_text(TINY_WORLD.replace("name: tiny", "name: van") + "  - {id: van, kind: car, position: [12, -3.5], "
                     "size: [5.2, 2.0, 2.3]}\n")
    monkeypatch.chdir(tmp_path)                                  # the drive is simulated into ./data/sim
    out = tmp_path / "rows.json"
    assert bench.main(["--world", str(world), "--workers", "1", "--cache-dir", str(tmp_path / "cache"),
                       "--json", str(out), "--variant", "extraction.vertical_structure.cell_min_top_m=2.5"]) == 0
    (label, row), (variant, taller) = [(r["configuration"], r) for r in json.loads(out.read_text())]
    kinds = bench.CLUTTER_KINDS
    assert label == "as configured" and variant == "extraction.vertical_structure.cell_min_top_m=2.5"
    assert row["scans"] == 31 and row["per_scan_on"][kinds.index("car")] > 10     # most scans keep the van
    assert sum(row["per_scan_on"]) == row["per_scan_on"][kinds.index("car")]      # the houses lie on walls
    assert row["precision"] < 1.0 and row["recall"] > 0.9
    assert "per-scan segments on clutter per 100 scans" in capsys.readouterr().out
    # the variant ran with its own extraction: cells must reach 2.5 m, above the van's roof
    assert taller["per_scan_on"][kinds.index("car")] == 0


def test_bad_flags_are_one_line_and_status_2(bench, capsys):
    assert bench.main(["--workers", "0"]) == 2
    assert bench.main(["--variant", ""]) == 2
    assert bench.main(["--set", "nonsense.key=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("bench_clutter: error: ") for line in err)
