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


def test_by_object_lists_each_object_segments_lie_on_and_the_low_walls(bench, tmp_path, monkeypatch, capsys):
    # a dense trimmed 2.3 m hedge north of the route and a 2.2 m masonry garden wall south of it
    world = tmp_path / "garden.yaml"
    world.write_text(TINY_WORLD.replace("name: tiny", "name: garden")
                     + "  - {id: privet, kind: hedge, line: [[16, 4], [23, 4]], height: 2.3, width: 0.8, irregularity: 0.03,"
                       " porosity: 0.05, depth_m: 0.03}\n"
                       "  - {id: garden_wall, kind: building, footprint: [[2, -4.3], [10, -4.3], [10, -4], [2, -4]], height: 2.2}\n")
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "rows.json"
    assert bench.main(["--world", str(world), "--workers", "1", "--cache-dir", str(tmp_path / "cache"),
                       "--json", str(out), "--by-object"]) == 0
    (row,) = json.loads(out.read_text())
    by_id = {o["id"]: o for o in row["by_object"]}
    assert set(by_id) == {"privet", "garden_wall"}               # the houses are 8-10 m high: not low walls
    hedge, wall = by_id["privet"], by_id["garden_wall"]
    assert (hedge["kind"], hedge["height"], wall["kind"], wall["height"]) == ("hedge", 2.3, "low wall", 2.2)
    # both are kept as walls in most of the 31 scans: to one scan a dense trimmed hedge is a garden wall
    assert wall["segments"] >= 15 and hedge["segments"] >= 15 and hedge["scans"] == hedge["segments"]
    assert hedge["features"] == 1 and wall["features"] == 1
    assert row["per_scan_on"][bench.CLUTTER_KINDS.index("hedge")] == hedge["segments"]
    printed = capsys.readouterr().out
    assert "privet" in printed and "garden_wall" in printed and "low wall" in printed      # the object table
