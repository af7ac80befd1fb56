"""benchmarks/bench_pose_noise.py: every split can be run, and a seed of another split is refused at once."""

import pytest

from featmap.simulation.splits import SPLITS
from tests.repo_scripts import repo_script


@pytest.fixture(scope="module")
def bench():
    with repo_script("benchmarks/bench_pose_noise.py") as module:
        yield module


@pytest.mark.parametrize("split", list(SPLITS))
def test_a_seed_of_another_split_is_refused_in_one_line_before_anything_runs(bench, tmp_path, capsys, split):
    other = next(seeds[0] for name, seeds in SPLITS.items() if name != split)
    assert bench.main(["--parts", "sim", "--split", split, "--seeds", str(other), "--sim-root", str(tmp_path),
                       "--cache-dir", str(tmp_path / "cache")]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and f"[{other}]" in out and f"not in the {split} split" in out
    assert not any(tmp_path.iterdir())


def test_a_held_out_split_without_a_carmen_log_says_so_and_runs_nothing(bench, tmp_path, capsys):
    assert bench.main(["--parts", "carmen", "--split", "heldout2", "--data-dir", str(tmp_path),
                       "--cache-dir", str(tmp_path / "cache")]) == 0
    assert "no CARMEN log is held out in the heldout2 split" in capsys.readouterr().out
    assert not [path for path in tmp_path.rglob("*") if path.is_file()]   # nothing extracted or cached


def test_an_unknown_split_is_refused_with_the_allowed_ones(bench, capsys):
    with pytest.raises(SystemExit) as exit_:
        bench.main(["--split", "heldout9"])
    assert exit_.value.code == 2
    assert "heldout4" in capsys.readouterr().err
