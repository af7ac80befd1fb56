"""Output folders that are files, read-only, full, or busy with another run: one line, nothing half-written."""

import json
import shutil

import numpy as np

from featmap.io.segments_csv import SegmentTable, write_segments_csv
from featmap.pipeline.run_folder import RunFolder
from featmap.simulation.segments import observe_walls
from tests.faults.conftest import cli, contract_files, featmap_process, one_line_error, run_args


def _segments(tmp_path):
    rng = np.random.default_rng(0)
    segs, scan = observe_walls(np.array([[0, 0, 30, 0], [0, 15, 30, 15]], float), 10, 0.03, rng,
                               first_scan=np.array([0, 0]))
    return write_segments_csv(tmp_path / "segments.csv", SegmentTable(scan=scan, segments=segs))


def test_out_is_a_file_for_every_command(case1_drive, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    seg = _segments(tmp_path)
    one_line_error(cli(*run_args(case1_drive, afile, tmp_path / "c")), "--out")
    assert not list((tmp_path / "c").rglob("*.npz"))                # failed before any extraction
    one_line_error(cli(*run_args(case1_drive, afile / "run", tmp_path / "c")), "is a file, not a folder")
    one_line_error(cli("fuse", seg, "--out", afile), "exists and is not a folder")
    one_line_error(cli("simulate", "--world", "prescan_case1", "--out", afile, "--frames", "3"), "exists and is not a folder")
    one_line_error(cli("evaluate", tmp_path / "x.csv", "--truth", case1_drive.drive_dir / "truth", "--out", tmp_path),
                   "x.csv")
    assert afile.read_text() == "keep me"


def test_figures_and_evaluate_outputs_that_cannot_be_written(case1_drive, tmp_path):
    assert cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--method", "proposed", "--frames", "0:10")).exit_code == 0
    (tmp_path / "afile").write_text("x")
    one_line_error(cli("figures", tmp_path / "r", "--out", tmp_path / "afile"), f"--out {tmp_path / 'afile'}: {tmp_path / 'afile'} exists and is not a folder")
    truth = case1_drive.drive_dir / "truth"
    one_line_error(cli("evaluate", tmp_path / "r" / "fused_proposed.csv", "--truth", truth, "--out", tmp_path),
                   "is a folder; give a .json file path")


def test_a_read_only_output_folder(case1_drive, tmp_path, small_disk):
    ro = small_disk("1m", ro=True)
    one_line_error(cli(*run_args(case1_drive, ro / "run", tmp_path / "c")), f"--out {ro / 'run'}")
    assert not list((tmp_path / "c").rglob("*.npz"))                # before any extraction
    one_line_error(cli("fuse", _segments(tmp_path), "--out", ro / "f"), "Read-only file system")
    one_line_error(cli("simulate", "--world", "prescan_case1", "--out", ro / "sim", "--frames", "3"), "Read-only file system")


def test_a_full_disk_mid_run_keeps_the_previous_run_whole(case1_drive, tmp_path, small_disk):
    disk = small_disk("400k")
    out = disk / "run"
    args = run_args(case1_drive, out, tmp_path / "c", "--method", "proposed", "--frames", "0:6")
    assert cli(*args).exit_code == 0
    before = contract_files(out)
    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\0" * max(0, free - 20_000))        # leave less than a run needs
    res = cli(*run_args(case1_drive, out, tmp_path / "c", "--method", "proposed,density", "--frames", "0:40"))
    one_line_error(res, "No space left on device")
    assert contract_files(out) == before                               # the previous run, not a mix of two
    assert sorted(p.name for p in disk.iterdir()) == ["filler", "run"]


def test_a_full_disk_for_fuse_writes_nothing_half(tmp_path, small_disk):
    disk = small_disk("64k")
    seg = _segments(tmp_path)
    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\0" * max(0, free - 4096))
    one_line_error(cli("fuse", seg, "--out", disk / "f", "--method", "all"), "No space left on device")
    assert not list(disk.rglob("*.tmp"))                            # no half-written file left behind
    assert all(p.stat().st_size > 0 for p in disk.rglob("*.csv"))


def test_two_runs_into_one_folder_at_once(case1_drive, tmp_path):
    """A run into a folder another process is still writing fails at once and leaves that run's work alone.

    The other run is this test process holding the folder as a run does (a real second ``featmap run``
    started beside a first one could find the first already finished: the test would race)."""
    out = tmp_path / "r"
    args = run_args(case1_drive, out, tmp_path / "c", "--method", "proposed", "--frames", "0:6")
    with RunFolder(out) as writing:
        (writing.tmp / "metrics.json").write_text('{"writer": "the first run"}')
        second = featmap_process(*args)
        _, err2 = second.communicate(timeout=120)
        writing.commit()
    assert second.returncode == 2 and "another featmap run is writing to it" in err2
    assert len([line for line in err2.splitlines() if line.startswith("featmap: error")]) == 1
    assert json.loads((out / "metrics.json").read_text()) == {"writer": "the first run"}
    assert not list(tmp_path.glob(".r.partial-*")) and not list((tmp_path / "c").rglob("*.npz"))
    third = featmap_process(*args)                                # the folder is free again
    _, err3 = third.communicate(timeout=300)
    assert third.returncode == 0, err3[-2000:]
    assert json.loads((out / "metrics.json").read_text())["scans"]["processed"] == 6


def test_a_simulation_that_fails_midway_leaves_no_partial_drive(tmp_path, small_disk):
    disk = small_disk("2m")
    one_line_error(cli("simulate", "--world", "prescan_case1", "--out", disk, "--frames", "40"), "No space left on device")
    assert not list(disk.rglob("*.partial")) and not list(disk.rglob("*_sync"))


def test_an_out_folder_that_holds_the_runs_input_is_refused(tmp_path):
    from tests.conftest import write_room_log

    out = tmp_path / "r"
    log = write_room_log(tmp_path / "room.log", np.random.default_rng(0), n_scans=8)
    assert cli("run", "--carmen", log, "--out", out, "--cache-dir", tmp_path / "c", "--method", "proposed",
               "--set", "output.plots=false").exit_code == 0
    inside = shutil.copy(log, out / "room.log")
    one_line_error(cli("run", "--carmen", inside, "--out", out, "--cache-dir", tmp_path / "c", "--method", "proposed",
                       "--set", "output.plots=false"), "an input of this run")
    assert (out / "room.log").is_file() and (out / "metrics.json").is_file()


def test_a_rerun_refuses_to_delete_files_added_to_its_folder(case1_drive, tmp_path):
    """A re-run replaces its own outputs and the figures made from them, never a file someone added."""
    args = run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--method", "proposed", "--frames", "0:10")
    assert cli(*args).exit_code == 0
    (tmp_path / "r" / "figures").mkdir()                       # `featmap figures` writes here by default
    (tmp_path / "r" / "figures" / "fig.png").write_bytes(b"x")
    (tmp_path / "r" / "notes.txt").write_text("mine")
    one_line_error(cli(*args), "holds notes.txt, which the run that made the folder did not write")
    assert (tmp_path / "r" / "notes.txt").read_text() == "mine"
    (tmp_path / "r" / "notes.txt").unlink()
    assert cli(*args).exit_code == 0
    assert not (tmp_path / "r" / "figures").exists()          # stale figures go with the run they were made from


def test_a_full_disk_at_the_sweep_logs_header_leaves_no_log_that_refuses_the_next_sweep(tmp_path, small_disk):
    """The log's header is written whole or not at all: a header cut short by a full disk would make every
    later sweep into the folder fail as 'another sweep's'."""
    spec = tmp_path / "s.yaml"
    spec.write_text(f"input: {_segments(tmp_path)}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.2, 0.5]\n")
    disk = small_disk("64k")
    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\0" * max(0, free - 6000))         # one page left; the header needs two
    one_line_error(cli("sweep", spec, "--out", disk / "sweep", "--workers", "1"), "No space left on device")
    assert not list(disk.rglob("results.jsonl")) and not list(disk.rglob("*.tmp"))
    (disk / "filler").unlink()
    assert cli("sweep", spec, "--out", disk / "sweep", "--workers", "1").exit_code == 0
    log = (disk / "sweep" / "results.jsonl").read_text().splitlines()
    assert "sweep" in json.loads(log[0]) and len(log) == 3
