"""Helpers for the fault-injection suite: run the CLI, check a one-line error, mount a small or read-only disk."""

import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from typer.testing import CliRunner

from featmap.cli import app
from tests.conftest import untimed_metrics

RUNNER = CliRunner()
QUIET = ["--set", "output.plots=false", "--set", "output.html=false", "--set", "output.kml=false"]


def cli(*args):
    return RUNNER.invoke(app, [str(a) for a in args])


def one_line_error(result, needle: str) -> str:
    """Assert exit status 2 and a single ``featmap: error:`` line containing ``needle``; return it."""
    lines = [line for line in result.output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("featmap: error:")]
    assert result.exit_code == 2, result.output
    assert len(errors) == 1 and needle in errors[0], result.output
    assert "Traceback" not in result.output
    return errors[0]


@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size="200k", ro=False) -> Path`` of a tmpfs; skips where mounting is not allowed."""
    mounts = []

    def mount(size="200k", ro=False):
        point = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
        point.mkdir()
        opts = f"size={size}" + (",ro" if ro else "")
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(point)], capture_output=True)
        if res.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here ({res.stderr.decode().strip()[:80]})")
        mounts.append(point)
        return point

    yield mount
    for point in mounts:
        subprocess.run(["umount", "-l", str(point)], capture_output=True)


def featmap_process(*args, cwd=None):
    """``featmap ARGS`` as a separate process (for kills and concurrency)."""
    return subprocess.Popen([sys.executable, "-m", "featmap.cli", *map(str, args)], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def run_args(drive, out, cache, *extra):
    return ["run", "--drive", drive.drive, "--data-dir", drive.root, "--out", out, "--cache-dir", cache,
            "--workers", "1", *QUIET, *extra]


def contract_files(folder: Path) -> dict[str, bytes]:
    """The files of a run folder that must not depend on timing (everything but metrics.json's timings,
    comparison's seconds column and the HTML map's random element ids)."""
    import json

    out = {}
    for path in sorted(folder.iterdir()):
        if path.name in ("metrics.json", "comparison.csv", "comparison.md", "map.html"):
            continue
        out[path.name] = path.read_bytes()
    out["metrics.json (without timings)"] = json.dumps(untimed_metrics(folder), sort_keys=True).encode()
    return out
