"""The run folder: written whole or not at all, by one run at a time; and read back.

A run writes into a temporary sibling (``.NAME.partial-PID``) and swaps it in place of ``--out`` at the
end, so a crash, a full disk or Ctrl-C leaves the previous run folder as it was (never a mix of two
runs). A lock file beside it (``.NAME.lock``, removed when the run ends) makes a second run into the same folder
fail at once. An ``--out`` that is a symbolic link is written where it points.
Opening checks that the folder can be written, and that it is empty or a folder this command wrote
before (it holds the ``marker`` file) with nothing added since (its ``MANIFEST`` lists what the run
wrote): a run never replaces a folder of other files (the input log beside it, a user's notes) nor the
current folder, so a bad ``--out`` fails before any work.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from featmap.errors import FeatmapError
from featmap.io.atomic import file_in_the_way, is_staging_folder


class RunFolderError(FeatmapError):
    """The run folder cannot be written (a file in the way, read-only, full disk, another run)."""


MANIFEST = ".featmap-files"
"""A run folder's list of the entries its run wrote (one name per line): anything else found there later is
a user's, and a new run into the folder refuses to delete it."""
DERIVED = ("figures", "batch.json")
"""Entries made from a run after it (``featmap figures``' default folder, a batch's record of the drive):
stale once the run is redone, so a new run replaces them."""


def is_leftover(entry: str) -> bool:
    """``entry`` (a name in a folder) is a run folder's lock file or temporary twin (``.NAME.lock``,
    ``.NAME.partial-PID``, ``.NAME.old-PID``), what RunFolder writes beside ``--out``, or a staging folder of
    ``atomic_file_set`` (a figures or sweep folder's, left by a killed process): not a user's file."""
    return entry.startswith(".") and (entry.endswith(".lock") or ".partial-" in entry or ".old-" in entry
                                      or is_staging_folder(entry))


def check_folder_path(out: str | Path, what: str = "--out") -> None:
    """Fail (one line naming ``what``) when ``out`` or a folder above it exists but is a file."""
    blocker = file_in_the_way(out)
    if blocker is not None:
        raise RunFolderError(f"{what} {out}: {blocker} exists and is not a folder")


class RunFolder:
    """``with RunFolder(out) as folder:`` write into ``folder.tmp``, then ``folder.commit()``.

    Leaving the block without ``commit`` (an error) removes the temporary folder and keeps ``out`` as it was.
    ``inputs``: files or folders the run reads; an ``out`` that holds one is refused (the swap would delete it).
    """

    def __init__(self, out: str | Path, marker: str = "metrics.json", inputs: Iterable[str | Path] = ()):
        self.out = Path(out)
        self.marker = marker
        self.inputs = [Path(p) for p in inputs]
        self.tmp: Path | None = None
        self._lock_fd: int | None = None
        self._lock_path: Path | None = None

    def __enter__(self) -> "RunFolder":
        if self.out.is_symlink():     # write where the link points: the swap must not replace the link itself
            self.out = Path(os.path.realpath(self.out))
        out = self.out
        if out.exists() and not out.is_dir():
            raise RunFolderError(f"--out {out}: exists and is not a folder")
        if out.is_dir():
            resolved, here = out.resolve(), Path.cwd().resolve()
            if resolved == here or resolved in here.parents:
                raise RunFolderError(f"--out {out}: is the current folder (or holds it); a run replaces its "
                                     "--out folder whole: give a new or empty folder")
            for path in self.inputs:
                inside = path.absolute().resolve()
                if inside == resolved or resolved in inside.parents:
                    raise RunFolderError(f"--out {out}: holds {path}, an input of this run; a run replaces its "
                                         "--out folder whole: give another folder")
            if any(out.iterdir()) and not (out / self.marker).is_file():
                raise RunFolderError(f"--out {out}: holds other files and is not a featmap output folder (no "
                                     f"{self.marker}); a run replaces its --out folder whole: give a new or empty folder")
            foreign = self.foreign_entries(out)
            if foreign:
                raise RunFolderError(f"--out {out}: holds {foreign[0]}, which the run that made the folder did not write; "
                                     "a run replaces its --out folder whole: move it out first or give another folder")
        parent = out.parent if str(out.parent) else Path(".")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise RunFolderError(f"--out {out}: {file_in_the_way(parent) or parent} is a file, not a folder") from None
        except OSError as exc:
            raise RunFolderError(f"--out {out}: cannot create {parent} ({exc.strerror})") from None
        self._lock(parent / f".{out.name}.lock")
        self.tmp = parent / f".{out.name}.partial-{os.getpid()}"
        try:
            self._remove_leftovers(parent, out.name)
            self.tmp.mkdir()
        except OSError as exc:
            self._release()
            raise RunFolderError(f"--out {out}: cannot write in {parent} ({exc.strerror})") from None
        return self

    @staticmethod
    def _remove_leftovers(parent: Path, name: str) -> None:
        """Temporary twins left by runs that were killed (we hold the lock, so no other run is writing)."""
        for leftover in list(parent.glob(f".{name}.partial-*")) + list(parent.glob(f".{name}.old-*")):
            shutil.rmtree(leftover, ignore_errors=True)

    @staticmethod
    def foreign_entries(out: Path) -> list[str]:
        """Names in the run folder ``out`` that its run did not write (a user's notes, a sweep's results), by the
        list of entries the run left there (``MANIFEST``; none for folders made before it: nothing is foreign).
        ``DERIVED`` entries (figures made from the run) are replaced with it and never foreign."""
        try:
            written = set((out / MANIFEST).read_text(encoding="utf-8").splitlines())
        except (OSError, UnicodeDecodeError):
            return []
        return sorted(p.name for p in out.iterdir() if p.name not in written | {MANIFEST, *DERIVED})

    def commit(self) -> None:
        """Replace ``out`` by the temporary folder (the previous contents are removed)."""
        (self.tmp / MANIFEST).write_text("".join(f"{p.name}\n" for p in sorted(self.tmp.iterdir())), encoding="utf-8")
        old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
        try:
            if self.out.exists():
                os.replace(self.out, old)
            os.replace(self.tmp, self.out)
        except OSError as exc:
            if old.exists() and not self.out.exists():
                os.replace(old, self.out)
            raise RunFolderError(f"--out {self.out}: cannot move the finished run into place ({exc.strerror})") from None
        shutil.rmtree(old, ignore_errors=True)
        self.tmp = None

    def _lock(self, lock: Path) -> None:
        """Hold ``lock`` (flock) for the run; removed again when the run ends. A run that opened the file just
        before the previous holder removed it locks a deleted file: it sees that and opens the new one."""
        while True:
            try:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise RunFolderError(f"--out {self.out}: cannot write in {lock.parent} ({exc.strerror})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise RunFolderError(f"--out {self.out}: another featmap run is writing to it; wait for it or "
                                     "choose another --out") from None
            try:
                same = os.stat(lock).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self._lock_fd, self._lock_path = fd, lock
                return
            os.close(fd)

    def _release(self) -> None:
        if self._lock_fd is not None:
            try:
                os.unlink(self._lock_path)        # while still holding it: see _lock
            except OSError:
                pass
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if self.tmp is not None and self.tmp.exists():
                shutil.rmtree(self.tmp, ignore_errors=True)
        finally:
            self._release()
        if isinstance(exc, OSError) and not isinstance(exc, FeatmapError):
            where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
            raise RunFolderError(f"--out {self.out}: writing the run failed{where}: {exc.strerror or exc}; "
                                 "the previous contents are unchanged") from None


# --- reading a run back ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class RunData:
    """What ``featmap run`` wrote, in the run's local metric frame.

    Attributes:
        path: the run folder.
        metrics: its metrics.json (typed).
        config: its config.yaml (a FeatmapConfig).
        segments: the extracted segments (segments.csv).
        fused: method -> (segments (M, 4), support (M,)).
        trajectory: (F, 2) sensor positions.
        truth: the ground truth it was scored against (simulator truth or footprints), or None when that
            reference is gone.
    """

    path: Path
    metrics: Any
    config: Any
    segments: Any
    fused: dict
    trajectory: np.ndarray
    truth: Any

    @property
    def frame(self):
        return self.metrics.geo_frame.frame() if self.metrics.geo_frame is not None else None


def load_run(run_dir: str | Path, config=None) -> RunData:
    """Read a run folder back (its config, or ``config`` when given, e.g. with ``--set`` overrides)."""
    from featmap.evaluation.references import footprints_truth, load_simulator_truth
    from featmap.io.pose_csv import read_trajectory_xy
    from featmap.io.run_metrics import read_run_metrics
    from featmap.io.segments_csv import read_fused_csv, read_segments_csv
    from featmap.pipeline.config import load_config

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunFolderError(f"{run_dir}: not a folder (give a featmap run folder, e.g. runs/residential)")
    metrics = read_run_metrics(run_dir / "metrics.json")
    config = config if config is not None else load_config(run_dir / "config.yaml")
    segments = read_segments_csv(run_dir / "segments.csv")
    fused = {name: read_fused_csv(run_dir / f"fused_{name}.csv") for name in metrics.methods}
    traj_path = run_dir / "trajectory.csv"
    trajectory = read_trajectory_xy(traj_path) if traj_path.exists() else np.zeros((0, 2))
    frame = metrics.geo_frame.frame() if metrics.geo_frame is not None else None
    truth = None
    truth_dir = metrics.reference_path("truth", run_dir)
    footprints = metrics.reference_path("footprints", run_dir)
    if truth_dir is not None and truth_dir.exists():
        truth = load_simulator_truth(truth_dir, frame, metrics.source.frames_processed)
    elif footprints is not None and footprints.exists() and frame is not None:
        truth = footprints_truth(footprints, frame, run_dir)
    return RunData(run_dir, metrics, config, segments, fused, trajectory, truth)
