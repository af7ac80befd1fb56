"""The seed lists: tuning, probe and held-out worlds never overlap, and listing a seed re-simulates nothing."""

from pathlib import Path

import pytest

from featmap.simulation import simulate
from featmap.simulation.splits import (EIGHTH_HELDOUT_SEEDS, FIFTH_HELDOUT_SEEDS, FOURTH_HELDOUT_SEEDS, HELDOUT_SEEDS, HELDOUT_SPLITS,
                                       PROBE_SEEDS, SECOND_HELDOUT_SEEDS, SEVENTH_HELDOUT_SEEDS, SIXTH_HELDOUT_SEEDS,
                                       THIRD_HELDOUT_SEEDS, TUNING_SEEDS,
                                       held_out_seeds, split_seeds)


def test_tuning_probe_and_heldout_seeds_are_apart():
    sets = (HELDOUT_SEEDS, SECOND_HELDOUT_SEEDS, THIRD_HELDOUT_SEEDS, FOURTH_HELDOUT_SEEDS, FIFTH_HELDOUT_SEEDS,
            SIXTH_HELDOUT_SEEDS, SEVENTH_HELDOUT_SEEDS, EIGHTH_HELDOUT_SEEDS)
    assert all(len(seeds) >= 8 for seeds in sets) and len(TUNING_SEEDS) >= 4
    assert sum(len(seeds) for seeds in sets) == len(held_out_seeds())         # no seed in two held-out sets
    assert held_out_seeds() == set().union(*sets)
    assert not set(TUNING_SEEDS) & held_out_seeds()
    assert not set(PROBE_SEEDS) & (set(TUNING_SEEDS) | held_out_seeds())   # looked into: never held out
    assert split_seeds("tuning") == TUNING_SEEDS
    assert all(split_seeds(name) == seeds for name, seeds in HELDOUT_SPLITS.items())
    with pytest.raises(ValueError, match="unknown split 'test'; allowed: tuning, heldout, heldout2, heldout3, heldout4, heldout5, heldout6, heldout7, heldout8"):
        split_seeds("test")


def test_listing_a_seed_does_not_change_the_simulation_fingerprint(monkeypatch):
    spec = {"world": "w", "seed": 1}
    before = simulate.simulation_fingerprint(spec)
    read_bytes = Path.read_bytes

    def edited(name):
        def read(path):
            data = read_bytes(path)
            return data + b"\n# edited\n" if path.name == name else data
        return read

    monkeypatch.setattr(Path, "read_bytes", edited("splits.py"))
    assert simulate.simulation_fingerprint(spec) == before
    monkeypatch.setattr(Path, "read_bytes", edited("procedural.py"))
    assert simulate.simulation_fingerprint(spec) != before              # the generator is simulator code
    assert (Path(simulate.__file__).parent / "splits.py").exists()      # the name left out is a real module


def _featmap_imports(path: Path) -> set[str]:
    """The featmap modules a source file imports (at module level or inside functions)."""
    import ast
    import importlib.util

    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("featmap"):
            found.add(node.module)
            if importlib.util.find_spec(node.module).submodule_search_locations is not None:   # a package
                found |= {f"{node.module}.{a.name}" for a in node.names
                          if importlib.util.find_spec(f"{node.module}.{a.name}") is not None}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("featmap")}
    return found


def test_every_module_the_simulator_imports_is_in_its_fingerprint_or_said_to_shape_no_output():
    import importlib.util

    todo = [f"featmap.simulation.{p.stem}" for p in Path(simulate.__file__).parent.glob("*.py")
            if p.name not in simulate.NOT_SIMULATOR_CODE | {"__init__.py"}]
    seen = set()
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo += _featmap_imports(Path(importlib.util.find_spec(name).origin))
    outside = {name for name in seen if not name.startswith("featmap.simulation")} - {"featmap", "featmap.io"}
    assert outside == set(simulate.SIMULATOR_DEPENDENCIES) | set(simulate.NOT_OUTPUT_DEPENDENCIES)
    assert not set(simulate.SIMULATOR_DEPENDENCIES) & set(simulate.NOT_OUTPUT_DEPENDENCIES)


def test_an_edit_to_a_module_the_simulator_writes_with_changes_the_fingerprint(monkeypatch):
    spec = {"world": "w", "seed": 1}
    before = simulate.simulation_fingerprint(spec)
    read_bytes = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda path: read_bytes(path) + (b"#" if path.name == "sim_truth.py" else b""))
    assert simulate.simulation_fingerprint(spec) != before
