"""SIGKILL in the middle of a run or a sweep, then the same command again: the same outputs as without it;
a reader that goes away; a Ctrl-C that lands where Python would drop it."""

import csv
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from featmap.io.run_metrics import read_run_metrics
from tests.faults.conftest import cli, contract_files, featmap_process, run_args


def _kill_when(process, ready, timeout=120.0):
    deadline = time.time() + timeout
    while time.time() < deadline and process.poll() is None:
        if ready():
            process.send_signal(signal.SIGKILL)
            process.wait()
            return True
        time.sleep(0.01)
    process.kill()
    return False


def test_a_killed_run_resumes_to_the_same_outputs(case1_drive, tmp_path):
    reference = run_args(case1_drive, tmp_path / "ref", tmp_path / "cache_ref", "--method", "proposed,density")
    assert cli(*reference).exit_code == 0
    args = run_args(case1_drive, tmp_path / "r", tmp_path / "cache", "--method", "proposed,density")
    process = featmap_process(*args)
    killed = _kill_when(process, lambda: len(list((tmp_path / "cache").rglob("*.npz"))) >= 8)
    assert killed, "the run finished before it could be killed"
    assert not (tmp_path / "r").exists()                          # nothing that looks like a finished run
    assert list(tmp_path.glob(".r.partial-*"))                    # only its temporary twin
    res = cli(*args)
    assert res.exit_code == 0, res.output
    metrics = read_run_metrics(tmp_path / "r" / "metrics.json")
    assert metrics.scans.from_cache >= 8 and metrics.scans.extracted_now <= 32
    assert contract_files(tmp_path / "r") == contract_files(tmp_path / "ref")
    assert not list(tmp_path.glob(".r.partial-*"))                # the killed run's leftovers are gone


def _sweep_table(path: Path) -> list[dict]:
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    for row in rows:
        row.pop("seconds")
    return rows


def test_a_killed_sweep_resumes_to_the_same_results(case1_drive, tmp_path):
    assert cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "cache", "--method", "proposed")).exit_code == 0
    spec = tmp_path / "sweep.yaml"
    spec.write_text(f"input: {tmp_path / 'r' / 'segments.csv'}\nmethods: [proposed, meanshift]\ngrid:\n"
                    "  fusion.proposed.delta_deg: [1, 2, 3, 5, 8, 13]\n  fusion.proposed.eta_m: [0.2, 0.5, 1.0, 2.0]\n"
                    "  fusion.meanshift.center_bandwidth_m: [1, 2, 3, 5, 8]\n")
    assert cli("sweep", spec, "--out", tmp_path / "ref", "--workers", "1").exit_code == 0
    process = featmap_process("sweep", spec, "--out", tmp_path / "s", "--workers", "1")
    log = tmp_path / "s" / "results.jsonl"
    killed = _kill_when(process, lambda: log.exists() and log.read_text().count("\n") >= 6)
    assert killed, "the sweep finished before it could be killed"
    done = log.read_text().count("\n") - 1
    assert 5 <= done < 29
    res = cli("sweep", spec, "--out", tmp_path / "s", "--workers", "1")
    assert res.exit_code == 0, res.output
    assert _sweep_table(tmp_path / "s" / "sweep.csv") == _sweep_table(tmp_path / "ref" / "sweep.csv")
    assert (tmp_path / "s" / "best.yaml").read_bytes() == (tmp_path / "ref" / "best.yaml").read_bytes()


def test_a_reader_that_goes_away_stops_featmap_quietly():
    # `featmap config | head -0`: the reader has closed its end before featmap writes a byte
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        process = subprocess.run([sys.executable, "-m", "featmap.cli", "config"], stdout=write_end,
                                 stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert process.returncode == 141, process.stderr
    assert process.stderr == ""                   # no "Broken pipe" error, no "Exception ignored" at exit


def test_a_broken_pipe_that_is_not_standard_output_is_an_error(monkeypatch):
    # e.g. a download's connection or a worker's pipe: a one-line error, not a silent exit
    import errno

    import featmap.pipeline.config

    def broken():
        raise BrokenPipeError(errno.EPIPE, "Broken pipe", "/tmp/worker.sock")

    monkeypatch.setattr(featmap.pipeline.config, "default_config_yaml", broken)
    result = cli("config")
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == ["featmap: error: /tmp/worker.sock: Broken pipe"]


def _ctrl_c_inside_a_gc_callback(progress: list) -> None:
    """One garbage collection whose callback is interrupted by a SIGINT (handled there, where Python drops
    the KeyboardInterrupt), then a blocking wait of one second; ``progress`` records the steps done."""
    import gc
    import threading

    def callback(phase, info):
        if phase == "start" and not progress:
            progress.append("interrupted")
            signal.raise_signal(signal.SIGINT)      # Python's handler raises KeyboardInterrupt right here

    gc.callbacks.append(callback)
    try:
        gc.collect()
    finally:
        gc.callbacks.remove(callback)
    progress.append("collected")
    threading.Event().wait(1.0)
    progress.append("waited")


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_python_drops_a_ctrl_c_that_lands_in_a_gc_callback():
    # the hazard: Dask's scheduler, in a batch's process, hooks a function into every garbage collection
    progress = []
    _ctrl_c_inside_a_gc_callback(progress)           # no KeyboardInterrupt: printed as "Exception ignored"
    assert progress == ["interrupted", "collected", "waited"]


def test_featmap_commands_raise_a_ctrl_c_that_lands_in_a_gc_callback_again(capsys):
    from featmap.cli import _ctrl_c_never_dropped

    previous, progress = sys.unraisablehook, []
    with pytest.raises(KeyboardInterrupt), _ctrl_c_never_dropped():
        _ctrl_c_inside_a_gc_callback(progress)
    assert progress[0] == "interrupted" and "waited" not in progress   # raised again, within the wait at the latest
    assert sys.unraisablehook is previous
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_ctrl_c_that_ended_a_string_exec_still_exits_130_under_python_m(tmp_path):
    # CPython marks a KeyboardInterrupt that ends a string exec (a dataclass's generated methods, say) and,
    # under `python -m`, exits by SIGINT at the end whatever exit code was asked for (-2, not 130)
    (tmp_path / "interrupted_in_exec.py").write_text(
        "from featmap import cli\n\n\n"
        "@cli.command\n"
        "def interrupted():\n"
        "    exec('raise KeyboardInterrupt', {})\n\n\n"
        "cli.main()\n")
    process = subprocess.run([sys.executable, "-m", "interrupted_in_exec", "interrupted"], cwd=tmp_path,
                             capture_output=True, text=True, timeout=120)
    assert process.returncode == 130, process.stderr
    assert process.stderr.splitlines() == ["featmap: interrupted; finished files are complete, nothing half-written was kept."]
