"""Malformed files beyond the common cases: damaged truth files, oversized cells, deep nesting, numbers out of
range, and errors that must name where the bad value came from. Each is one line naming the file or flag."""

import json

import numpy as np
import pytest

from featmap.errors import InputFileError, shown
from featmap.io.jsonfile import read_json
from featmap.io.sim_truth import (TruthWalls, coverage_of_frames, read_observations, read_walls_csv,
                                  write_coverage, write_walls_csv)
from tests.faults.conftest import cli, one_line_error
from tests.faults.test_inputs import _fused_run, segments_csv  # noqa: F401  (a fixture)

WALLS = np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 5.0]])


def _coverage(path, **replace):
    """A coverage file for WALLS (two walls of 10 and 5 bins) with arrays replaced by ``replace``."""
    arrays = dict(frame=np.array([0, 0, 1]), bin=np.array([0, 3, 12]), count=np.array([5, 6, 7]),
                  bin_offset=np.array([0, 10, 15]), bin_m=np.float64(1.0), min_bin_returns=np.int64(1))
    np.savez(path, **{**arrays, **replace})
    return path


def test_an_intact_coverage_file_is_read(tmp_path):
    path = tmp_path / "coverage.npz"
    write_coverage(path, [(np.array([0, 0]), np.array([0, 12]), np.array([5, 6]))], np.array([0, 10, 15]))
    observed, n_returns = coverage_of_frames(path, WALLS, [0])
    assert n_returns.tolist() == [5, 6] and len(observed[0]) == len(observed[1]) == 1


@pytest.mark.parametrize("damage,needle", [
    (lambda p: p.write_bytes(_coverage(p).read_bytes()[:500]), "unreadable coverage file (BadZipFile"),
    (lambda p: p.write_bytes(b""), "unreadable coverage file"),
    (lambda p: _coverage(p, bin=np.array([0, -3, 12])), "malformed coverage file"),
    (lambda p: _coverage(p, bin=np.array([0.0, 3.0, 12.0])), "malformed coverage file"),
    (lambda p: _coverage(p, bin=np.array([0, 3, 15])), "malformed coverage file"),        # beyond the last wall
    (lambda p: _coverage(p, count=np.array([5, -6, 7])), "malformed coverage file"),
    (lambda p: _coverage(p, frame=np.array([0, 1])), "malformed coverage file"),          # columns of two lengths
    (lambda p: _coverage(p, bin_offset=np.array([0, 16, 15])), "malformed coverage file"),
    (lambda p: _coverage(p, bin_m=np.float64(0.0)), "malformed coverage file"),
    (lambda p: np.savez(p, frame=np.array(["a"], dtype=object)), "unreadable coverage file"),  # pickled: refused
    (lambda p: _coverage(p, bin_offset=np.int64(15)), "malformed coverage file"),             # 0-d offsets
])
def test_a_damaged_coverage_file_is_one_error_naming_it(tmp_path, damage, needle):
    path = tmp_path / "coverage.npz"
    damage(path)
    with pytest.raises(InputFileError, match="coverage.npz: ") as info:
        coverage_of_frames(path, WALLS, [0, 1])
    assert needle in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("replace", [
    {}, {"wall": np.array([0])}, {"frame": np.int64(0)}, {"interval_offset": np.array([0, 1, 5])},
    {"interval_start": np.array([0.0])},
])
def test_a_damaged_observations_file_is_one_error_naming_it(tmp_path, replace):
    arrays = dict(frame=np.array([0, 1]), wall=np.array([0, 1]), n_hits=np.array([60, 70]),
                  s_min=np.zeros(2), s_max=np.full(2, 3.0), observed_m=np.full(2, 3.0),
                  interval_offset=np.array([0, 1, 2]), interval_start=np.zeros(2), interval_end=np.full(2, 3.0))
    np.savez(tmp_path / "observations.npz", **{**arrays, **replace})
    if not replace:
        assert len(read_observations(tmp_path)) == 2                      # the intact file reads
        (tmp_path / "observations.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(InputFileError, match="observations.npz: not a per-scan observation file"):
        read_observations(tmp_path)


@pytest.fixture
def walls_csv(tmp_path):
    walls = TruthWalls(WALLS, np.array(["A", "A"]), np.array([["a", "b"], ["b", "c"]]), np.array([10, 20]),
                       [[(0.0, 10.0)], [(0.0, 5.0)]])
    path = tmp_path / "walls.csv"
    write_walls_csv(path, walls)
    assert len(read_walls_csv(path).walls) == 2
    return path


def test_a_walls_csv_row_with_too_few_cells(walls_csv):
    lines = walls_csv.read_text().splitlines()
    lines[2] = lines[2].rsplit(",", 1)[0]                   # the second wall loses its observed intervals
    walls_csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputFileError, match=r"walls.csv:3: malformed row: fewer cells than the header's 9"):
        read_walls_csv(walls_csv)


def test_a_short_walls_csv_row_is_named_by_its_own_line(walls_csv):
    header, first, second = walls_csv.read_text().splitlines()
    walls_csv.write_text("\n".join([header, "", first, "", second.rsplit(",", 1)[0]]) + "\n")   # blank lines between
    with pytest.raises(InputFileError, match=r"walls.csv:5: malformed row"):
        read_walls_csv(walls_csv)


def test_a_cell_beyond_the_csv_modules_limit(walls_csv, tmp_path):
    walls_csv.write_text(walls_csv.read_text() + "x" * 200_000 + "\n")
    with pytest.raises(InputFileError, match=r"walls.csv:4: not a readable CSV \(field larger than field limit"):
        read_walls_csv(walls_csv)
    big = tmp_path / "segments.csv"
    big.write_text("scan,x1,y1,x2,y2\n0,1,2,3," + "4" * 200_000 + "\n")
    one_line_error(cli("fuse", big, "--out", tmp_path / "o"), "segments.csv:2: not a readable CSV (field larger")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("text,needle", [
    ("[" * 100_000 + "]" * 100_000, "not valid JSON (nested too deeply)"),
    ('{"segments": ' + "9" * 5000 + "}", "not valid JSON (Exceeds the limit"),
    ('{"precision": 1e400}', "not valid JSON ('1e400' is beyond the range of a number)"),
    ('{"precision": -2e308}', "not valid JSON ('-2e308' is beyond the range of a number)"),
])
def test_json_beyond_what_python_reads_as_numbers(tmp_path, text, needle):
    path = tmp_path / "metrics.json"
    path.write_text(text)
    with pytest.raises(InputFileError, match="metrics.json: ") as info:
        read_json(path)
    assert needle in str(info.value)
    assert read_json(_write(tmp_path / "ok.json", '{"precision": 1e300, "n": 12}')) == {"precision": 1e300, "n": 12}
    one_line_error(cli("compare", tmp_path), needle)


def _write(path, text):
    path.write_text(text)
    return path


def test_a_metrics_files_schema_version_of_another_type(tmp_path):
    _write(tmp_path / "metrics.json", '{"schema_version": "2"}')
    one_line_error(cli("compare", tmp_path), "'schema_version' must be a whole number, got '2'")
    _write(tmp_path / "metrics.json", '{"schema_version": 1}')
    one_line_error(cli("compare", tmp_path), "written by another featmap version (schema 1, expected 2)")


@pytest.mark.parametrize("edit,needle", [
    (lambda m: m.update(primary="nope"), "'primary' names 'nope', not one of the references (truth, map)"),
    (lambda m: m.update(segments=-3), "'segments' input should be greater than or equal to 0"),
    (lambda m: m["scans"].update(processed=-1), "'scans.processed' input should be greater than or equal to 0"),
])
def test_a_metrics_file_that_contradicts_itself(case1_drive, tmp_path, edit, needle):
    run = _fused_run(case1_drive, tmp_path)
    metrics = json.loads((run / "metrics.json").read_text())
    assert cli("compare", run).exit_code == 0                          # as written, it reads
    edit(metrics)
    (run / "metrics.json").write_text(json.dumps(metrics))
    one_line_error(cli("compare", run), "metrics.json: not a featmap metrics file: " + needle)


def test_yaml_nested_too_deeply_or_expanded_by_aliases(tmp_path, segments_csv):  # noqa: F811
    deep = _write(tmp_path / "deep.yaml", "a: " + "[" * 2000 + "]" * 2000 + "\n")
    one_line_error(cli("config", "-c", deep), "deep.yaml: not valid YAML (nested too deeply)")
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--set",
                       "fusion.proposed.delta_deg=" + "[" * 2000 + "]" * 2000), "the value is nested too deeply")
    # eight levels of ten aliases each: a value of 10^8 items, shown cut short
    levels = ["&a0 [" + ", ".join(["x"] * 10) + "]"] + [
        f"&a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, 8)]
    bomb = _write(tmp_path / "bomb.yaml", "fusion: {proposed: {delta_deg: [" + ", ".join(levels) + "]}}\n")
    error = one_line_error(cli("config", "-c", bomb), "bomb.yaml: 'fusion.proposed.delta_deg' input should be")
    assert len(error) < 400 and "...]" in error
    assert not (tmp_path / "o").exists()


def test_shown_cuts_values_short():
    assert shown([0.5, 2]) == "[0.5, 2]" and shown("abc") == "'abc'"
    assert len(shown("x" * 10_000)) < 70 and len(shown(list(range(10_000)))) < 40
    nested = [1]
    for _ in range(1000):
        nested = [nested] * 10
    assert len(shown(nested)) < 200


def test_sweep_files_that_would_hang_or_cannot_be_read(tmp_path, segments_csv):  # noqa: F811
    grid = ("grid:\n  fusion.proposed.gamma: {start: 0, stop: 1, num: 1000}\n"
            "  fusion.proposed.eta_m: {start: 0.1, stop: 1, num: 101}\n")
    many = _write(tmp_path / "many.yaml", f"input: {segments_csv}\nmethods: [proposed]\n{grid}samples: 1000000000\n")
    one_line_error(cli("sweep", many, "--out", tmp_path / "s"), "many.yaml: samples: Input should be less than or "
                                                                "equal to 100000")
    seed = _write(tmp_path / "seed.yaml", f"input: {segments_csv}\nmethods: [proposed]\n"
                                          "grid: {fusion.proposed.gamma: [0.2, 0.3, 0.4]}\nsamples: 2\nseed: -1\n")
    one_line_error(cli("sweep", seed, "--out", tmp_path / "s"), "seed.yaml: seed: Input should be greater than or "
                                                                "equal to 0")
    assert not (tmp_path / "s").exists()
    ok = _write(tmp_path / "ok.yaml", f"input: {segments_csv}\nmethods: [proposed]\n"
                                      "grid: {fusion.proposed.gamma: [0.2, 0.3]}\n")
    assert cli("sweep", ok, "--out", tmp_path / "s", "-j", "1").exit_code == 0
    (tmp_path / "s" / "results.jsonl").write_bytes(b"\xff\xfe\x00\x01")
    one_line_error(cli("sweep", ok, "--out", tmp_path / "s", "-j", "1"),
                   f"--out {tmp_path / 's'}: cannot read its results.jsonl")


def test_a_sweep_range_of_infinite_ends(tmp_path, segments_csv):  # noqa: F811
    spec = _write(tmp_path / "inf.yaml", f"input: {segments_csv}\nmethods: [proposed]\n"
                                         "grid: {fusion.proposed.gamma: {start: -.inf, stop: .inf, num: 3}}\n")
    result = cli("sweep", spec, "--out", tmp_path / "s")
    one_line_error(result, "inf.yaml: grid key 'fusion.proposed.gamma': start Input should be a finite number")
    assert "RuntimeWarning" not in result.output and not (tmp_path / "s").exists()


def test_a_sweep_files_frames_are_blamed_on_the_file(tmp_path):
    frames = _write(tmp_path / "frames.yaml", "drive: default\nframes: x\nmethods: [proposed]\n"
                                              "grid: {fusion.proposed.gamma: [0.5]}\n")
    one_line_error(cli("sweep", frames, "--out", tmp_path / "s"), f"{frames}: 'frames': 'x': expected integers")


def test_figures_blame_the_flag_that_gave_a_bad_value(case1_drive, tmp_path):
    run = _fused_run(case1_drive, tmp_path)
    one_line_error(cli("figures", run, "--out", tmp_path / "f", "--set", "fusion.proposed.gamma=5"),
                   "--set: 'fusion.proposed.gamma' input should be less than or equal to 1 (got 5)")
    (run / "config.yaml").unlink()
    one_line_error(cli("figures", run, "--out", tmp_path / "f", "--set", "fusion.proposed.gamma=0.5"),
                   f"{run}: no config.yaml to apply --set / --tiles to")
    assert not (tmp_path / "f").exists()


def test_a_trajectory_beyond_any_map(case1_drive, tmp_path):
    run = _fused_run(case1_drive, tmp_path)
    lines = (run / "trajectory.csv").read_text().splitlines()
    frame, _, *rest = lines[3].split(",")
    lines[3] = ",".join([frame, "1e300", *rest])
    (run / "trajectory.csv").write_text("\n".join(lines) + "\n")
    one_line_error(cli("figures", run, "--out", tmp_path / "f"), "trajectory.csv:4: not a trajectory table frame,x,y,"
                                                                 "z,yaw (a value beyond 1e+12: no pose lies that far)")


def test_an_unknown_method_names_the_flag(tmp_path, segments_csv):  # noqa: F811
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--method", "nope"),
                   "--method: unknown method 'nope'; allowed: proposed, meanshift, density or all")
