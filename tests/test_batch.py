"""featmap batch: drives as Dask tasks, identical to featmap run, resumable, failures contained, one merged map."""

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from tests.conftest import SIGINT_IGNORED_AT_START, untimed_metrics
from featmap.io.batch_records import read_batch_summary, read_drive_key, read_merged_record
from featmap.io.segments_csv import read_fused_csv, read_segments_csv

pytest.importorskip("distributed")

from featmap.batch import drive_provenance, plan_batch, run_batch  # noqa: E402
from featmap.reporting import RecordingReporter  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()
QUIET = ["output.plots=false"]          # no basemap tiles (no network in tests)
METHODS = ["proposed", "density"]


def write_batch(path: Path, worlds: Path, sim_root: Path, cache: Path, drives: str | None = None, extra: str = "") -> Path:
    drives = drives or (f"  - world: {worlds / 'tiny.yaml'}\n  - world: {worlds / 'tiny_b.yaml'}\n"
                        f"  - world: {worlds / 'tiny_c.yaml'}\n    set: [fusion.proposed.eta_m=0.4]\n")
    path.write_text(f"set: {json.dumps(QUIET)}\nmethods: {json.dumps(METHODS)}\nsim_root: {sim_root}\n"
                    f"cache_dir: {cache}\n{extra}drives:\n{drives}")
    return path


def same_run(a: Path, b: Path) -> None:
    """Two run folders hold the same files with the same contents, timings (and the HTML map's random ids) aside."""
    skip = {"batch.json", "metrics.json", "comparison.csv", "comparison.md", "map.html"}
    names_a = {p.name for p in a.iterdir()} - {"batch.json"}
    assert names_a == {p.name for p in b.iterdir()} - {"batch.json"}
    for name in sorted(names_a - skip):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name

    assert untimed_metrics(a) == untimed_metrics(b)


@pytest.fixture(scope="module")
def first_batch(tiny_worlds, dask_client, tmp_path_factory):
    """The three tiny drives as a batch on the 2-worker LocalCluster, simulated on first use into a fresh root."""
    tmp = tmp_path_factory.mktemp("batch")
    path = write_batch(tmp / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp / "cache")
    plan = plan_batch(path, tmp / "out")
    reporter = RecordingReporter()
    result = run_batch(plan, dask_client, reporter)
    return tmp, plan, result, reporter


def test_a_batch_gives_what_featmap_run_gives_for_each_drive(first_batch, tiny_worlds, monkeypatch):
    tmp, plan, result, reporter = first_batch
    assert [d.status for d in result.summary.drives] == ["done"] * 3
    assert any("simulating the tiny_b drive" in line for line in reporter.infos)   # simulated on first use
    monkeypatch.chdir(tmp)                                                           # featmap run's data/sim
    for name, extra in (("tiny", []), ("tiny_b", []), ("tiny_c", ["--set", "fusion.proposed.eta_m=0.4"])):
        res = runner.invoke(app, ["run", "--world", str(tiny_worlds / f"{name}.yaml"), "--method", ",".join(METHODS),
                                  "--set", QUIET[0], *extra, "--out", str(tmp / "alone" / name),
                                  "--cache-dir", str(tmp / "cache_alone"), "--workers", "1"])
        assert res.exit_code == 0, res.output
        same_run(tmp / "out" / name, tmp / "alone" / name)
        for method in METHODS:   # the fused CSVs, explicitly
            a = (tmp / "out" / name / f"fused_{method}.csv").read_bytes()
            assert a == (tmp / "alone" / name / f"fused_{method}.csv").read_bytes()
    # the per-drive override reached only its drive
    assert "eta_m: 0.4" in (tmp / "out" / "tiny_c" / "config.yaml").read_text()
    assert "eta_m: 0.4" not in (tmp / "out" / "tiny" / "config.yaml").read_text()
    # both workers ran drives; the summary was written and reported
    summary = read_batch_summary(tmp / "out" / "summary.json")
    assert summary.workers == 2 and len({d.worker for d in summary.drives}) == 2
    assert summary.critical_path_seconds <= summary.work_seconds
    assert reporter.tables[0][0].startswith("featmap batch: 3 drives")
    assert reporter.tables[0][2][-1][0] == "total"


def test_the_merged_map_fuses_walls_seen_by_several_drives_into_one(first_batch):
    tmp, plan, result, _ = first_batch
    merged = read_merged_record(tmp / "out" / "merged" / "merged.json")
    assert result.merged == merged
    assert [d.name for d in merged.drives] == ["tiny", "tiny_b", "tiny_c"]
    # three different local origins (each drive's first pose); the merged frame is the first drive's
    origins = {(d.geo_frame.lat0_deg, d.geo_frame.lon0_deg) for d in merged.drives}
    assert len(origins) == 3 and (merged.geo_frame.lat0_deg, merged.geo_frame.lon0_deg) == \
        (merged.drives[0].geo_frame.lat0_deg, merged.drives[0].geo_frame.lon0_deg)
    # scan ids stay unique across drives
    seg = np.loadtxt(tmp / "out" / "merged" / "segments.csv", delimiter=",", skiprows=1)
    header = next(csv.reader(open(tmp / "out" / "merged" / "segments.csv")))
    drive_col = header.index("drive")
    assert "rms" in header                  # every drive's fit rms goes along (the clean-view support rule)
    for d in range(3):
        for e in range(d + 1, 3):
            assert not set(seg[seg[:, drive_col] == d, 0]) & set(seg[seg[:, drive_col] == e, 0])
    for method in METHODS:
        scores = merged.scores[method]
        alone = merged.drive_scores[method]
        # moved into one frame, the drives' walls coincide: one feature per wall, nothing lost
        assert scores["precision"] > 0.95
        assert scores["redundancy"] <= 1.05
        assert scores["recall"] >= max(s["recall"] for s in alone.values()) - 1e-9
        assert merged.counts[method] <= max(r.counts[method] for r in result.summary.drives) + 1
        rows = list(csv.DictReader(open(tmp / "out" / "merged" / f"fused_{method}.csv")))
        assert len(rows) == merged.counts[method]
        assert all(r["drives"] and int(r["n_drives"]) == len(r["drives"].split(";")) for r in rows)
        # every drive saw the south wall of A (y = 6, x -5..15): one feature, three drives
        south_a = [r for r in rows if abs(float(r["y1"]) - 6) < 0.2 and abs(float(r["y2"]) - 6) < 0.2
                   and min(float(r["x1"]), float(r["x2"])) < 0]
        assert len(south_a) == 1 and south_a[0]["drives"] == "tiny;tiny_b;tiny_c"
        fc = json.loads((tmp / "out" / "merged" / f"fused_{method}.geojson").read_text())
        assert {tuple(f["properties"]["drives"]) for f in fc["features"]} >= {("tiny", "tiny_b", "tiny_c")}
        segments, support = read_fused_csv(tmp / "out" / "merged" / f"fused_{method}.csv")   # readable back
        assert len(segments) == len(rows)
    assert merged.multi_drive["proposed"] >= 3
    assert {"map.kml", "map.html", "config.yaml", "segments.csv"} <= {p.name for p in (tmp / "out" / "merged").iterdir()}


def _moved_copy(run: Path, out: Path, motion: np.ndarray, about: np.ndarray) -> Path:
    """A copy of run folder ``run`` whose segments, fused maps and trajectory are moved as a whole by the
    planar ``motion`` (dx, dy, dyaw) about ``about``: a drive whose GPS was off by that much."""
    from featmap.io.segments_csv import write_fused_csv, write_segments_csv
    from featmap.refinement.base import correct_points, correct_segments

    shutil.copytree(run, out)
    move = lambda seg: correct_segments(seg, np.zeros(len(seg), int), about[None], motion[None])  # noqa: E731
    table = read_segments_csv(run / "segments.csv")
    write_segments_csv(out / "segments.csv", replace(table, segments=move(table.segments)))
    for method in METHODS:
        segments, support = read_fused_csv(run / f"fused_{method}.csv")
        write_fused_csv(out / f"fused_{method}.csv", move(segments), support)
    traj = np.loadtxt(run / "trajectory.csv", delimiter=",", skiprows=1, ndmin=2)
    traj[:, 1:3] = correct_points(traj[:, 1:3], np.zeros(len(traj), int), about[None], motion[None])
    np.savetxt(out / "trajectory.csv", traj, delimiter=",", header="frame,x,y,z,yaw", comments="", fmt="%.6f")
    return out


def test_a_drive_off_as_a_whole_is_aligned_to_the_others_before_merging(first_batch, tmp_path):
    """A drive whose poses are off by 0.6 m and 1.5 deg as a whole (GPS of another day) is moved back onto
    the first drive before the merged map is fused: one feature per wall instead of two."""
    from featmap.batch import merge_task
    from featmap.io.segments_csv import read_segments_csv

    tmp, plan, result, _ = first_batch
    tiny = tmp / "out" / "tiny"
    segments = read_segments_csv(tiny / "segments.csv").segments
    about = 0.5 * (segments[:, :2] + segments[:, 2:]).mean(axis=0)
    motion = np.array([0.6, -0.4, np.deg2rad(1.5)])
    off = _moved_copy(tiny, tmp_path / "tiny_off", motion, about)
    drives = [("tiny", str(tiny)), ("tiny_off", str(off))]
    alone = {r.name: r.counts for r in result.summary.drives}["tiny"]

    merged = merge_task(drives, str(tmp_path / "merged"), tuple(METHODS), plan.merge_config)
    assert merged.alignment["applied"] and merged.drives[0].correction == [0.0, 0.0, 0.0]
    assert np.hypot(*merged.drives[1].correction[:2]) > 0.3 and abs(merged.drives[1].correction[2] + 1.5) < 0.05
    table = read_segments_csv(tmp_path / "merged" / "segments.csv")
    moved_back = table.segments[table.extra["drive"] == 1]
    assert np.abs(moved_back - segments).max() < 0.03            # every segment back within 3 cm
    for method in METHODS:
        assert merged.counts[method] <= alone[method] + 1       # one feature per wall ...
        assert merged.scores[method]["precision"] > 0.95 and merged.scores[method]["redundancy"] <= 1.05
    from featmap.sweep import run_sweep_file                     # a sweep of it aligns the drives the same way

    spec = tmp_path / "s.yaml"
    spec.write_text(f"batch: {tmp_path}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.5]\n")
    rows, _ = run_sweep_file(spec, tmp_path / "sweep")
    assert rows[0]["count"] == merged.counts["proposed"]
    assert rows[0]["precision"] == pytest.approx(merged.scores["proposed"]["precision"])

    config = {**plan.merge_config, "refinement": {**plan.merge_config["refinement"], "drives": {"enabled": False}}}
    unaligned = merge_task(drives, str(tmp_path / "unaligned"), tuple(METHODS), config)
    assert unaligned.alignment is None and unaligned.drives[1].correction is None
    assert all(unaligned.counts[m] >= 1.5 * alone[m] for m in METHODS)   # ... instead of two


def test_provenance_lists_the_drives_of_each_feature():
    labels = np.array([0, 0, 1, -1, 1, 2])
    drive = np.array([0, 1, 1, 0, 1, 2])
    assert drive_provenance(labels, drive, 4) == [[0, 1], [1], [2], []]


def test_a_rerun_resumes_skipping_finished_drives(first_batch, dask_client, tmp_path):
    tmp, plan, result, _ = first_batch
    out = tmp_path / "out"
    shutil.copytree(tmp / "out", out)                  # a moved batch folder resumes too (keys name no output path)
    batch_file = tmp_path / "b.yaml"
    shutil.copy(plan.path, batch_file)
    stamp = {n: (out / n / "segments.csv").stat().st_mtime_ns for n in ("tiny", "tiny_b", "tiny_c")}
    again = run_batch(plan_batch(batch_file, out), dask_client, RecordingReporter())
    assert [d.status for d in again.summary.drives] == ["skipped"] * 3
    assert {n: (out / n / "segments.csv").stat().st_mtime_ns for n in stamp} == stamp
    assert [d.counts for d in again.summary.drives] == [d.counts for d in result.summary.drives]
    # a changed override, a run folder lost and a key never written (killed after the swap): only those re-run
    batch_file.write_text(batch_file.read_text().replace("eta_m=0.4", "eta_m=0.45"))
    shutil.rmtree(out / "tiny_b")
    (out / "tiny" / "batch.json").unlink()
    third = run_batch(plan_batch(batch_file, out), dask_client, RecordingReporter())
    assert [d.status for d in third.summary.drives] == ["done", "done", "done"]
    assert "eta_m: 0.45" in (out / "tiny_c" / "config.yaml").read_text()
    # the drives' alignment is the merge's business: changing it runs no drive again
    batch_file.write_text(batch_file.read_text().replace("set: [", "set: [\"refinement.drives.min_improvement=2\", ", 1))
    fourth = run_batch(plan_batch(batch_file, out), dask_client, RecordingReporter())
    assert [d.status for d in fourth.summary.drives] == ["skipped"] * 3
    assert "min_improvement: 2" in (out / "merged" / "config.yaml").read_text()
    key = read_drive_key(out / "tiny_c" / "batch.json")
    assert key.source["kind"] == "simulated" and key.source["data"]["files"] > 30
    # re-simulated (or edited) data of a drive makes a new key: that drive runs again
    scan = next((tmp / "data" / "sim" / "tiny_b").rglob("0000000003.bin"))
    os.utime(scan, ns=(time.time_ns(), time.time_ns()))
    fifth = run_batch(plan_batch(batch_file, out), dask_client, RecordingReporter())
    assert [d.status for d in fifth.summary.drives] == ["skipped", "done", "skipped"]


def test_a_drive_folder_missing_a_file_the_merge_reads_is_run_again(first_batch, dask_client, tmp_path):
    """A drive's folder with its key but without a file the merge reads (half deleted, copied in part) is
    not up to date: the drive runs again, and the merge finds what it needs."""
    from featmap.batch import _is_up_to_date, merge_reads

    tmp, plan, _, _ = first_batch
    out = tmp_path / "out"
    shutil.copytree(tmp / "out", out)
    tiny = out / "tiny"
    key = read_drive_key(tiny / "batch.json")
    needed = merge_reads(tiny, key.methods)
    assert {"segments.csv", "metrics.json", "config.yaml", "trajectory.csv", "pose_corrections.csv",
            "fused_proposed.csv", "fused_density.csv", "batch.json"} == set(needed)    # the drives refined their poses
    assert _is_up_to_date(tiny, key)
    for name in needed:
        (tiny / name).rename(tmp_path / name)
        assert not _is_up_to_date(tiny, key), name
        (tmp_path / name).rename(tiny / name)
    (tiny / "metrics.json").write_text("{")                       # unreadable: run again, not a failed drive
    assert not _is_up_to_date(tiny, key)
    shutil.copy(tmp / "out" / "tiny" / "metrics.json", tiny / "metrics.json")

    (tiny / "segments.csv").unlink()
    (out / "tiny_b" / "fused_density.csv").unlink()
    result = run_batch(plan_batch(plan.path, out), dask_client, RecordingReporter())
    assert [d.status for d in result.summary.drives] == ["done", "done", "skipped"]
    assert (tiny / "segments.csv").is_file() and (out / "tiny_b" / "fused_density.csv").is_file()
    assert [d.name for d in result.merged.drives] == ["tiny", "tiny_b", "tiny_c"]


def test_a_merge_that_fails_is_one_line_after_the_summary(first_batch, dask_client, tmp_path):
    """A FeatmapError of the merge task comes back as one line (no worker traceback): the summary is written
    and reported, then the CLI prints the error on one line and exits 2."""
    tmp, plan, _, _ = first_batch
    out = tmp_path / "out"
    shutil.copytree(tmp / "out", out)
    (out / "merged" / "notes.txt").write_text("mine")             # a file the merge would delete
    (out / "summary.json").unlink()
    res = runner.invoke(app, ["batch", str(plan.path), "--out", str(out), "--scheduler", dask_client.scheduler.address])
    assert res.exit_code == 2, res.output
    errors = [line for line in res.output.splitlines() if line.startswith("featmap: error:")]
    assert len(errors) == 1 and "Traceback" not in res.output
    assert errors[0].startswith(f"featmap: error: merged map: --out {out / 'merged'}: holds notes.txt")
    assert "summary.json are written)" in " ".join(res.output.split())
    summary = read_batch_summary(out / "summary.json")
    assert len(summary.drives) == 3 and not any(d.status == "failed" for d in summary.drives)   # (an earlier
    assert summary.merged is None                                  # test touches tiny_b's data: it may run again)
    assert (out / "merged" / "notes.txt").read_text() == "mine" and not (out / "errors.txt").exists()


def test_the_merge_task_returns_its_errors(first_batch, tmp_path, monkeypatch):
    """As a drive task: a known error in one line; an unexpected one with its traceback (for errors.txt)."""
    import featmap.batch as batch

    tmp, plan, _, _ = first_batch
    outcome = batch.merge_outcome_task([("gone", str(tmp_path / "gone"))], str(tmp_path / "merged"), ("proposed",),
                                       plan.merge_config)
    assert outcome.record is None and outcome.known and outcome.detail is None
    assert outcome.error == f"{tmp_path / 'gone' / 'metrics.json'}: not found: is this a featmap run folder? " \
                            "(featmap run writes it)"

    def bug(*args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(batch, "merge_task", bug)
    outcome = batch.merge_outcome_task([("tiny", str(tmp / "out" / "tiny"))], str(tmp_path / "merged"), ("proposed",),
                                       plan.merge_config)
    assert outcome.error == "ZeroDivisionError: a bug" and not outcome.known
    assert "Traceback" in outcome.detail and "ZeroDivisionError" in outcome.detail


def test_outputs_of_an_earlier_batch_are_not_passed_off_as_this_ones(first_batch, dask_client, tmp_path):
    """A batch that writes no merged map warns that OUT/merged is an earlier batch's; an earlier batch's
    errors.txt goes when this one has no traceback to report."""
    tmp, plan, _, _ = first_batch
    out = tmp_path / "out"
    shutil.copytree(tmp / "out", out)
    (out / "errors.txt").write_text("== tiny\nTraceback (an earlier batch)\n")
    batch_file = tmp_path / "b.yaml"
    batch_file.write_text(plan.path.read_text() + "merge: false\n")
    reporter = RecordingReporter()
    result = run_batch(plan_batch(batch_file, out), dask_client, reporter)
    assert result.merged is None and (out / "merged" / "merged.json").exists()
    assert any("merged map of an earlier batch" in w for w in reporter.warnings)
    assert not (out / "errors.txt").exists()


def test_a_failing_drive_is_reported_and_the_others_finish(first_batch, dask_client, tiny_worlds, tmp_path):
    tmp = first_batch[0]
    # a KITTI raw copy of the simulated tiny drive with one scan cut short
    kitti = tmp_path / "kitti"
    shutil.copytree(tmp / "data" / "sim" / "tiny", kitti)
    broken = next(kitti.rglob("0000000005.bin"))
    broken.write_bytes(broken.read_bytes()[:-6])
    drives = (f"  - world: {tiny_worlds / 'tiny.yaml'}\n  - kitti: 2000_01_01_drive_0001\n    data_dir: {kitti}\n"
              f"    name: broken\n")
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp / "cache", drives)
    res = runner.invoke(app, ["batch", str(path), "--out", str(tmp_path / "out"), "--scheduler",
                              dask_client.scheduler.address])
    assert res.exit_code == 1, res.output
    assert "1 of 2 drive(s) failed" in res.output
    assert "wrote 1 run folder, 1 failed, summary.json, merged/" in " ".join(res.output.split())
    summary = read_batch_summary(tmp_path / "out" / "summary.json")
    tiny, bad = summary.drives
    assert tiny.status == "done" and bad.status == "failed"
    assert "0000000005.bin: truncated scan" in bad.error
    assert not (tmp_path / "out" / "broken").exists()
    merged = read_merged_record(tmp_path / "out" / "merged" / "merged.json")
    assert [d.name for d in merged.drives] == ["tiny"]
    # skipping bad scans (a per-drive option) makes it pass; the good drive is not run again
    path.write_text(path.read_text().replace("    name: broken\n", "    name: broken\n    skip_bad_scans: true\n"))
    res = runner.invoke(app, ["batch", str(path), "--out", str(tmp_path / "out"), "--scheduler",
                              dask_client.scheduler.address])
    assert res.exit_code == 0, res.output
    assert [d.status for d in read_batch_summary(tmp_path / "out" / "summary.json").drives] == ["skipped", "done"]
    assert "wrote 1 run folder, 1 kept (up to date), summary.json" in " ".join(res.output.split())


def test_scans_as_tasks_of_their_own_give_the_same_run(first_batch, dask_client, tiny_worlds, tmp_path):
    tmp = first_batch[0]
    drives = f"  - world: {tiny_worlds / 'tiny_b.yaml'}\n"
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp_path / "cache", drives,
                       extra="scan_tasks: true\nmerge: false\n")
    result = run_batch(plan_batch(path, tmp_path / "out"), dask_client, RecordingReporter())
    assert result.summary.drives[0].status == "done" and result.merged is None
    assert not (tmp_path / "out" / "merged").exists()
    same_run(tmp_path / "out" / "tiny_b", tmp / "out" / "tiny_b")


def test_local_workers_keep_the_adaptive_malloc_thresholds(dask_client):
    """Dask's nanny default MALLOC_TRIM_THRESHOLD_=65536 makes every large numpy array a fresh mmap (a
    drive took a third longer in page faults); featmap's LocalCluster starts its workers without it."""
    import os

    seen = dask_client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
    assert len(seen) == 2 and set(seen.values()) == {None}
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") is None          # nor is it left in the client's process


def _sigint_is_ignored() -> bool:
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_local_workers_ignore_ctrl_c_and_keep_the_configured_preloads(dask_client):
    seen = dask_client.run(_sigint_is_ignored)
    assert len(seen) == 2 and set(seen.values()) == {True}
    # The client's process still stops on Ctrl-C (unless it was started with Ctrl-C ignored: a background job).
    assert _sigint_is_ignored() == SIGINT_IGNORED_AT_START
    # The tests' own guard (a preload would be dropped if featmap's replaced the configured ones; here it
    # comes in by sitecustomize): the workers refuse to look up any other host.
    refused = dask_client.run(_looks_up_a_reserved_name)
    assert set(refused.values()) == {"refused: the tests do not look up example.invalid"}


def _looks_up_a_reserved_name() -> str:
    try:
        socket.getaddrinfo("example.invalid", 80)
    except OSError as exc:
        return f"refused: {exc.strerror or exc}"
    return "looked up"


def test_local_cluster_runs_the_configured_worker_preloads_before_its_own(tmp_path, dask_client):
    """... and a second LocalCluster (the session's ``dask_client`` is one) finds no port of the first taken."""
    import warnings

    import dask

    from featmap.batch import local_cluster

    marker = tmp_path / "marker_preload.py"
    marker.write_text("import os\n\ndef dask_setup(worker):\n    os.environ['FEATMAP_TEST_PRELOADED'] = '1'\n")
    with dask.config.set({"distributed.worker.preload": [str(marker)]}), warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        cluster = local_cluster(1)
    assert not [w for w in seen if "already in use" in str(w.message)]
    try:
        from distributed import Client

        with Client(cluster) as client:
            seen = client.run(lambda: (os.environ.get("FEATMAP_TEST_PRELOADED"), _sigint_is_ignored()))
    finally:
        cluster.close()
    assert list(seen.values()) == [("1", True)]


def test_ctrl_c_in_the_terminal_during_a_batch_prints_one_line_and_leaves_no_process(tiny_worlds, tmp_path):
    """A terminal's Ctrl-C reaches the batch and its LocalCluster's worker processes (one process group):
    featmap's one line, exit 130, no worker's KeyboardInterrupt traceback, every worker process gone."""
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp_path / "sim", tmp_path / "cache")
    process = subprocess.Popen([sys.executable, "-m", "featmap.cli", "batch", str(path), "--out", str(tmp_path / "out"),
                                "--workers", "2"], cwd=tmp_path, start_new_session=True, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as from a terminal
    try:
        line = process.stdout.readline()                             # printed once the workers are up
        assert line.startswith("Dask scheduler tcp://127.0.0.1:"), line + process.stderr.read()
        os.killpg(process.pid, signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, err
    assert err.strip().splitlines() == ["featmap: interrupted; finished files are complete, nothing half-written was kept."]
    deadline = time.time() + 10
    while (left := subprocess.run(["ps", "-o", "pid=,args=", "-g", str(process.pid)], capture_output=True,
                                  text=True).stdout.strip()) and time.time() < deadline:
        time.sleep(0.2)
    assert left == ""


def test_the_example_batch_names_two_builtin_drives_over_shared_streets():
    from featmap.simulation.worlds import load_world

    plan = plan_batch(ROOT / "configs" / "batch_example.yaml")
    assert [d.name for d in plan.drives] == ["residential", "residential_cross"] and plan.merge
    assert plan.out.parts[-3:] == ("runs", "batch", "example")
    routes = [np.asarray(load_world(d.name).route.waypoints) for d in plan.drives]
    # two of the cross route's legs run along the default route's streets (x = 170 and y = 110)
    shared = [leg for leg in zip(routes[1][:-1], routes[1][1:])
              if any(np.allclose(sorted(map(tuple, leg)), sorted(map(tuple, other)))
                     for other in zip(routes[0][:-1], routes[0][1:]))]
    assert len(shared) == 2


def test_sweep_over_a_batch_on_the_dask_client_matches_local(first_batch, dask_client, tmp_path):
    from featmap.pipeline.executor import DaskExecutor, SerialExecutor
    from featmap.sweep import run_sweep_file

    tmp = first_batch[0]
    spec = tmp_path / "s.yaml"
    spec.write_text(f"batch: {tmp / 'out'}\nmethods: [proposed]\n"
                    "grid:\n  fusion.proposed.eta_m: [0.2, 0.5]\n  fusion.proposed.min_support: [2, 4]\n")
    rows_dask, best = run_sweep_file(spec, tmp_path / "dask", DaskExecutor(dask_client))
    rows_local, _ = run_sweep_file(spec, tmp_path / "local", SerialExecutor())
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(rows_dask) == strip(rows_local) and len(rows_dask) == 4
    assert all(r["recall"] is not None for r in rows_dask) and best is not None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def real_cluster(tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 (random free ports, no dashboard)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    address = f"tcp://127.0.0.1:{_free_port()}"
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
                               address.rsplit(":", 1)[1], "--no-dashboard", "--dashboard-address", "127.0.0.1:0"],
                              env=env, cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    for k in range(2):
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--host", "127.0.0.1",
                                       "--nthreads", "1", "--no-dashboard", "--no-nanny", "--name", f"w{k}",
                                       "--local-directory", str(tmp_path / f"w{k}")], env=env, cwd=tmp_path,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    try:
        from distributed import Client

        deadline = time.time() + 60
        while True:
            try:
                with Client(address, timeout="2s") as client:
                    client.wait_for_workers(2, timeout=max(1, deadline - time.time()))
                    workers = set(client.scheduler_info()["workers"])
                break
            except OSError:
                if time.time() > deadline or any(p.poll() is not None for p in procs):
                    raise
                time.sleep(0.5)
        yield address, workers
    finally:
        for p in reversed(procs):
            p.send_signal(signal.SIGINT)          # dask's processes close at once on Ctrl-C
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_a_batch_on_a_real_scheduler_and_workers(first_batch, tiny_worlds, real_cluster, tmp_path):
    address, workers = real_cluster
    tmp = first_batch[0]
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp_path / "cache",
                       extra="scheduler: tcp://127.0.0.1:1\n")   # --scheduler overrides the file's
    res = runner.invoke(app, ["batch", str(path), "--out", str(tmp_path / "out"), "--scheduler", address])
    assert res.exit_code == 0, res.output
    summary = read_batch_summary(tmp_path / "out" / "summary.json")
    assert summary.scheduler == address and summary.workers == 2
    assert [d.status for d in summary.drives] == ["done"] * 3
    assert {d.worker for d in summary.drives} <= workers
    for name in ("tiny", "tiny_b", "tiny_c"):
        same_run(tmp_path / "out" / name, tmp / "out" / name)
    for method in METHODS:
        assert (tmp_path / "out" / "merged" / f"fused_{method}.csv").read_bytes() == \
            (tmp / "out" / "merged" / f"fused_{method}.csv").read_bytes()
    # a sweep over the batch on the same cluster
    spec = tmp_path / "s.yaml"
    spec.write_text(f"batch: {tmp_path / 'out'}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.3, 0.6]\n")
    res = runner.invoke(app, ["sweep", str(spec), "--out", str(tmp_path / "sweep"), "--scheduler", address])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(open(tmp_path / "sweep" / "sweep.csv")))
    assert len(rows) == 2 and all(float(r["recall"]) > 0.9 for r in rows)


def test_drives_without_a_geo_origin_merge_only_within_one_log(first_batch, dask_client, tiny_worlds, tmp_path):
    """Two halves of one indoor log share its frame; among drives with a geo origin it cannot be placed."""
    from tests.conftest import write_room_log

    tmp = first_batch[0]
    log = tmp_path / "room.log"
    write_room_log(log, np.random.default_rng(0))
    halves = (f"  - dataset: carmen\n    location: {log}\n    frames: '0:30'\n    name: room_a\n"
              f"  - dataset: carmen\n    location: {log}\n    frames: '30:60'\n    name: room_b\n")
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp / "cache", halves)
    result = run_batch(plan_batch(path, tmp_path / "out"), dask_client, RecordingReporter())
    merged = result.merged
    assert [d.name for d in merged.drives] == ["room_a", "room_b"] and merged.geo_frame is None
    assert merged.counts["proposed"] >= 5 and merged.multi_drive["proposed"] >= 3   # the room's walls, seen by both
    plan = plan_batch(path)
    assert plan.merge_config == plan.drives[0].config            # fused with the drives' common preset (indoor_2d)
    with_geo = write_batch(tmp_path / "c.yaml", tiny_worlds, tmp / "data" / "sim", tmp / "cache",
                           f"  - world: {tiny_worlds / 'tiny.yaml'}\n" + halves)
    result = run_batch(plan_batch(with_geo, tmp_path / "out2"), dask_client, RecordingReporter())
    assert [d.name for d in result.merged.drives] == ["tiny"]
    assert set(result.merged.left_out) == {"room_a", "room_b"}
    assert "no geo origin" in result.merged.left_out["room_a"]


def test_a_merged_map_without_truth_is_scored_against_the_drives_scan_points(first_batch, dask_client, tiny_worlds,
                                                                              tmp_path):
    """Two halves of an indoor log (no simulator truth): the merged map gets the truth-free metric against
    both halves' scan points, the same points a run over the whole log scores against; a drive whose scans
    are gone leaves the merged map written but unscored, saying why."""
    from featmap.batch import merge_task
    from featmap.io.run_metrics import read_run_metrics
    from tests.conftest import write_room_log

    tmp = first_batch[0]
    log = write_room_log(tmp_path / "room.log", np.random.default_rng(1))
    halves = (f"  - dataset: carmen\n    location: {log}\n    frames: '0:30'\n    name: room_a\n"
              f"  - dataset: carmen\n    location: {log}\n    frames: '30:60'\n    name: room_b\n")
    path = write_batch(tmp_path / "b.yaml", tiny_worlds, tmp / "data" / "sim", tmp / "cache", halves)
    reporter = RecordingReporter()
    merged = run_batch(plan_batch(path, tmp_path / "out"), dask_client, reporter).merged
    assert merged.evaluator == "map" and merged.reference == "scan points" and merged.unscored is None
    whole = runner.invoke(app, ["run", "--carmen", str(log), "--out", str(tmp_path / "whole"), "--method", "proposed",
                                "--cache-dir", str(tmp / "cache")])
    assert whole.exit_code == 0, whole.output
    alone = read_run_metrics(tmp_path / "whole" / "metrics.json").primary_scores("proposed")
    score = merged.scores["proposed"]
    assert score["points"] == alone["points"] and score["raw_count"] == alone["raw_count"]   # every scan, once
    assert score["precision"] >= 0.97 and score["recall"] >= 0.95 and score["redundancy"] <= 0.05
    halves_recall = [merged.drive_scores["proposed"][d]["recall"] for d in ("room_a", "room_b")]
    assert score["recall"] >= max(halves_recall) + 0.05    # the two halves' views together
    assert any("scan points" in str(t) for t in reporter.tables)
    # a sweep of the batch starts from the config the merged map was fused with and scores as it was scored
    from featmap.sweep import run_sweep_file

    spec = tmp_path / "s.yaml"
    spec.write_text(f"batch: {tmp_path / 'out'}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.2]\n")
    rows, _ = run_sweep_file(spec, tmp_path / "sweep", cache_dir=str(tmp / "cache"))
    assert rows[0]["count"] == merged.counts["proposed"]
    assert rows[0]["recall"] == pytest.approx(score["recall"]) and rows[0]["precision"] == pytest.approx(score["precision"])

    def merge_again():
        return merge_task([("room_a", str(tmp_path / "out" / "room_a")), ("room_b", str(tmp_path / "out" / "room_b"))],
                          str(tmp_path / "merged_again"), ("proposed",), plan_batch(path).merge_config, str(tmp / "cache"))

    (tmp_path / "out" / "room_b" / "pose_corrections.csv").unlink()   # refined, but its corrections are gone
    record = merge_again()
    assert record.scores == {} and record.counts["proposed"] == merged.counts["proposed"]
    assert record.unscored.startswith("not scored: ") and "room_b/pose_corrections.csv" in record.unscored
    key = tmp_path / "out" / "room_b" / "batch.json"              # a hand-edited key: written, not scored
    original = key.read_text()
    edited = json.loads(original)
    del edited["source"]["kind"]
    key.write_text(json.dumps(edited))
    record = merge_again()
    assert record.scores == {} and "room_b/batch.json: its source has no kind or location" in record.unscored
    key.write_text(original)
    log.rename(tmp_path / "moved.log")                     # the scans are gone: written, not scored
    record = merge_again()
    assert record.scores == {} and "room.log" in record.unscored
    assert (tmp_path / "merged_again" / "fused_proposed.csv").exists()


def test_the_merged_segments_carry_where_each_scan_was_taken_in_the_merged_frame(first_batch):
    """The sensor_x / sensor_y columns (the visibility clause's) move into the merged frame with the segments:
    each drive's lie on its own trajectory there, though the drives' local origins differ."""
    from featmap.batch import merged_inputs

    tmp, _, _, _ = first_batch
    merged = read_merged_record(tmp / "out" / "merged" / "merged.json")
    inputs = merged_inputs([(d.name, d.run_dir) for d in merged.drives])
    table = inputs.table
    sensor = np.column_stack([table.extra["sensor_x"], table.extra["sensor_y"]])
    for k, name in enumerate(inputs.names):
        path = inputs.trajectories[name]
        mine = sensor[table.extra["drive"] == k]
        nearest = np.hypot(*(mine[:, None, :] - path[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        assert len(mine) and nearest.max() < 0.5, name          # (the refined poses differ by centimetres)
        own = read_segments_csv(Path(inputs.drives[k].run_dir) / "segments.csv").extra
        assert k == 0 or np.abs(mine[:, 0] - own["sensor_x"]).max() > 1.0       # another origin: moved


def test_footprints_score_the_merged_map_on_what_the_drives_saw(first_batch, tmp_path, monkeypatch):
    """Scored against building footprints, the merged map counts the walls the drives' scan points lie on
    (as the drives' united simulator truths do), not every wall of the footprints file."""
    from featmap.batch import merged_inputs, merged_reference
    from featmap.evaluation import EvaluationConfig
    from featmap.evaluation.references import truth_from_footprints
    from featmap.evaluation.truth_metrics import truth_metrics

    tmp, plan, _, _ = first_batch
    merged = read_merged_record(tmp / "out" / "merged" / "merged.json")
    inputs = merged_inputs([(d.name, d.run_dir) for d in merged.drives])
    united = merged_reference(inputs)[1].data
    footprints = Path(merged.drives[0].truth) / "footprints.geojson"      # the others drive the same streets
    without_truth = replace(inputs, drives=[d.model_copy(update={"truth": None}) for d in inputs.drives])
    evaluator, reference = merged_reference(without_truth, EvaluationConfig(footprints=str(footprints)), tmp / "cache")
    assert evaluator.name == "footprints"
    fused, _ = read_fused_csv(tmp / "out" / "merged" / "fused_proposed.csv")
    observed, truth = truth_metrics(fused, reference.data), truth_metrics(fused, united)
    whole = truth_metrics(fused, truth_from_footprints(footprints, inputs.frame))
    assert observed["observable_walls"] == truth["observable_walls"] < whole["observable_walls"]
    assert observed["recall"] == pytest.approx(truth["recall"], abs=0.02)
    assert whole["recall"] < observed["recall"] - 0.3
    # the merged folder keeps that record, and evaluate reads it back
    from featmap import batch

    monkeypatch.setattr(batch, "merged_reference", lambda *args: (evaluator, reference))
    batch.merge_task([(d.name, d.run_dir) for d in merged.drives], str(tmp_path / "merged"), ("proposed",),
                     plan.merge_config, str(tmp / "cache"))
    res = runner.invoke(app, ["evaluate", str(tmp_path / "merged" / "fused_proposed.csv"), "--truth", str(footprints),
                              "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "m.json").read_text())["recall"] == pytest.approx(observed["recall"], abs=1e-6)
    monkeypatch.undo()
    # drives whose runs were scored against the footprints: their records, united, without reading any scan
    from featmap.batch import drive_points
    from featmap.evaluation.references import observation_record, observed_footprints
    from featmap.io.run_metrics import read_run_metrics, write_run_metrics
    from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE, write_walls_csv

    scored = []
    for d in merged.drives:
        run = tmp_path / "scored" / d.name
        shutil.copytree(d.run_dir, run)
        meta = read_run_metrics(run / "metrics.json")
        write_run_metrics(run / "metrics.json", meta.model_copy(update={"references": {**meta.references,
                                                                                          "footprints": str(footprints)}}))
        points, frames = drive_points(run, tmp / "cache")
        write_walls_csv(run / FOOTPRINT_WALLS_FILE, observation_record(
            observed_footprints(truth_from_footprints(footprints, meta.geo_frame.frame()), points, frames), footprints))
        scored.append((d.name, str(run)))
    scored_inputs = merged_inputs(scored)
    scored_inputs = replace(scored_inputs, drives=[d.model_copy(update={"truth": None}) for d in scored_inputs.drives])
    evaluator, united = merged_reference(scored_inputs, EvaluationConfig(footprints=str(footprints)))   # no cache
    assert evaluator.name == "footprints"
    assert truth_metrics(fused, united.data)["observable_walls"] == observed["observable_walls"]
    assert truth_metrics(fused, united.data)["recall"] == pytest.approx(observed["recall"], abs=0.005)
    # a drive without a record, and one the alignment moved, observe the footprints anew with their points
    # (placed as their segments are); the others' records stand
    from featmap.refinement.drives import DriveAlignment

    read_again = []
    real = batch.merged_drive_points
    monkeypatch.setattr(batch, "merged_drive_points", lambda inputs, k, cache: read_again.append(k) or real(inputs, k, cache))
    (Path(scored[2][1]) / FOOTPRINT_WALLS_FILE).unlink()
    moved = DriveAlignment(np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 0.0]]), np.zeros((3, 2)), True, {})
    batch.merged_footprints(replace(scored_inputs, alignment=moved), footprints, tmp / "cache")
    assert read_again == [1, 2]
    assert batch.merged_footprints(scored_inputs, footprints) is None                       # drive 2: no cache
    unmoved = batch.merged_footprints(scored_inputs, footprints, tmp / "cache")
    assert truth_metrics(fused, unmoved)["recall"] == pytest.approx(observed["recall"], abs=0.005)


def test_a_drive_tasks_warnings_go_to_its_own_reporter_one_line_each():
    # on a Dask worker they were printed to its stderr in Python's two-line format (file, line, source)
    import threading
    import warnings

    from featmap.batch import EventReporter, _warnings_to
    from featmap.plotting.basemap import BasemapWarning

    shown = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda message, *rest: shown.append(str(message))
        reporters = {name: EventReporter(None, name) for name in ("a", "b")}
        both_inside = threading.Barrier(2)

        def task(name):
            with _warnings_to(reporters[name]):
                both_inside.wait()                   # the two tasks' blocks overlap in time
                warnings.warn(f"tiles unreachable for {name}", BasemapWarning)
                warnings.warn(f"overflow in {name}", RuntimeWarning)
                both_inside.wait()

        threads = [threading.Thread(target=task, args=(name,)) for name in reporters]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        warnings.warn("outside any task", UserWarning)
    for name, reporter in reporters.items():
        assert reporter.warnings == [f"tiles unreachable for {name}", f"RuntimeWarning: overflow in {name}"]
    assert shown == ["outside any task"]            # what no task raised goes to the hook that was there
