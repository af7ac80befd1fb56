"""scripts/refresh_figures.py: which steps a change selects, and a resumed run does only what is left."""

import re
import sys
from pathlib import Path

import pytest

from tests.repo_scripts import repo_script

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rf():
    with repo_script("scripts/refresh_figures.py") as module:
        yield module


def test_every_docs_block_is_written_by_exactly_one_step(rf):
    blocks = []
    for page in (ROOT / "docs").glob("*.md"):
        blocks += re.findall(r"<!-- table:([a-z0-9_]+) -->", page.read_text())
    written = [block for step in rf.STEPS for block in step.blocks]
    assert sorted(written) == sorted(blocks)
    for step in rf.STEPS:                                   # every command names a script of the repository
        assert (ROOT / step.args[0]).is_file(), step.args


def test_a_change_selects_the_steps_that_measure_it(rf):
    names = lambda steps: [s.name for s in steps]
    two_d = names(rf.select(rf.STEPS, {"extraction_2d"}, None, []))
    assert "real_2d" in two_d and "indoor_2d" in two_d and "real_scans" not in two_d and "reproduce_paper" not in two_d
    three_d = names(rf.select(rf.STEPS, {"extraction_3d"}, None, ["online_heldout"]))
    assert "generalization_heldout" in three_d and "real_scans" in three_d and "online_heldout" not in three_d
    assert "real_2d" not in three_d
    assert names(rf.select(rf.STEPS, {"all"}, None, [])) == names(rf.STEPS)
    assert names(rf.select(rf.STEPS, set(), ["footprints", "real_scans"], [])) == ["real_scans", "footprints"]
    assert rf.hand_written({"speed"}) == rf.hand_written({"all"}) and "benchmarks/bench_sweep.py" in rf.hand_written({"speed"})
    assert rf.hand_written({"extraction_2d"}) == ["benchmarks/bench_carmen.py"]
    with pytest.raises(ValueError, match="unknown step.*nonsense"):
        rf.select(rf.STEPS, set(), ["nonsense"], [])


def _fake(rf, name, code, shared=False):
    return rf.Step(name, ("-c", code), frozenset({"fusion"}), (), shared)


def test_a_resumed_run_skips_what_was_done_for_the_same_code(rf, tmp_path):
    marks = tmp_path / "marks"
    marks.mkdir()
    steps = [_fake(rf, name, f"open(r'{marks / name}', 'a').write('x')") for name in ("a", "b")]
    failing = _fake(rf, "c", "import sys; sys.exit(3)")
    state = tmp_path / "state"

    outcomes = rf.run_steps([steps[0], failing, steps[1]], sys.executable, state, "code1", None, print_line=lambda _: None)
    assert [(n, o.split(" ")[0]) for n, o, _ in outcomes] == [("a", "ran"), ("c", "FAILED")]      # stops at c
    assert "c.log" in outcomes[1][1] and not (marks / "b").exists()

    outcomes = rf.run_steps(steps, sys.executable, state, "code1", None, print_line=lambda _: None)
    assert [(n, o) for n, o, _ in outcomes] == [("a", "done before"), ("b", "ran")]
    assert (marks / "a").read_text() == "x" and (marks / "b").read_text() == "x"

    outcomes = rf.run_steps(steps, sys.executable, state, "code2", None, print_line=lambda _: None)   # code changed
    assert [o for _, o, _ in outcomes] == ["ran", "ran"]
    assert (marks / "a").read_text() == "xx"


def test_force_runs_the_selected_steps_again_on_the_same_code_and_keeps_the_others(rf, tmp_path):
    marks = tmp_path / "marks"
    marks.mkdir()
    steps = [_fake(rf, name, f"open(r'{marks / name}', 'a').write('x')") for name in ("a", "b")]
    state = tmp_path / "state"
    rf.run_steps(steps, sys.executable, state, "code1", None, print_line=lambda _: None)

    outcomes = rf.run_steps(steps[1:], sys.executable, state, "code1", None, print_line=lambda _: None, force=True)
    assert [(n, o) for n, o, _ in outcomes] == [("b", "ran")]
    assert (marks / "a").read_text() == "x" and (marks / "b").read_text() == "xx"
    assert set(rf.load_state(state / "state.json", "code1")) == {"a", "b"}      # a stays recorded
    outcomes = rf.run_steps(steps, sys.executable, state, "code1", None, print_line=lambda _: None)
    assert [o for _, o, _ in outcomes] == ["done before", "done before"]


def test_a_step_without_its_data_is_not_run_and_not_counted_done(rf, tmp_path):
    step = _fake(rf, "real", "raise SystemExit(0)", shared=True)
    for _ in range(2):
        outcomes = rf.run_steps([step], sys.executable, tmp_path, "code", None, print_line=lambda _: None)
        assert outcomes == [("real", "not run: no shared data", 0.0)]
    assert rf.load_state(tmp_path / "state.json", "code") == {}


def test_the_code_digest_follows_the_code(rf, tmp_path):
    for folder in ("featmap", "configs", "benchmarks", "scripts"):
        (tmp_path / folder).mkdir()
    (tmp_path / "featmap" / "x.py").write_text("a = 1\n")
    first = rf.code_digest(tmp_path)
    (tmp_path / "configs" / "d.yaml").write_text("k: 1\n")
    second = rf.code_digest(tmp_path)
    (tmp_path / "featmap" / "x.py").write_text("a = 2\n")
    assert len({first, second, rf.code_digest(tmp_path)}) == 3
