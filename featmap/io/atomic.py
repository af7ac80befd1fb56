"""Atomic file writes: a crash or Ctrl-C never leaves a half-written output file behind.

``atomic_path`` and ``atomic_write_*`` write one file through a hidden temporary twin beside it
(``.NAME.XXXXXXXX.tmp``); ``atomic_file_set`` writes a set of files into a folder (a command's figures,
a sweep's plots) through a hidden staging folder inside it (``.staging-PID-XXXXXXXX.tmp``), so a crash or
Ctrl-C half-way leaves the folder with the earlier call's whole set, never a mix of two calls.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:   # name the file the user asked for, not the hidden temporary one
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
    try:
        yield tmp_path
        try:
            os.replace(tmp_path, path)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def file_in_the_way(path: str | Path) -> Path | None:
    """The first of ``path`` and the folders above it that exists and is not a folder (None: none is)."""
    path = Path(path)
    for p in (path, *path.parents):
        if p.exists():
            return None if p.is_dir() else p
    return None


def missing_folders(path: str | Path) -> list[Path]:
    """``path`` and the folders above it that do not exist yet, innermost first (what making it would make)."""
    path = Path(path)
    return [p for p in (path, *path.parents) if not p.exists()]


def remove_empty_folders(folders: list[Path]) -> None:
    """Remove ``folders`` (innermost first) while they are empty: what a failed step made and left unused."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


def remove_unwritten(folder: str | Path, names: Iterable[str], written: Iterable[str | Path]) -> None:
    """Remove the files of ``names`` in ``folder`` that are not among ``written`` (paths or names): what an
    earlier call into the same folder wrote and this one did not. Files outside ``names`` are never touched."""
    kept = {Path(p).name for p in written}
    for name in set(names) - kept:
        path = Path(folder) / name
        if path.is_file():
            path.unlink()


STAGING_PREFIX = ".staging-"
"""The start of the name of ``atomic_file_set``'s staging folder, ``.staging-PID-XXXXXXXX.tmp`` (PID: the
process writing into it), made inside the folder the set goes to."""
_STAGING = re.compile(re.escape(STAGING_PREFIX) + r"(\d+)-[^/]*\.tmp")
_ACTIVE: set[Path] = set()          # this process's staging folders in use (a PID may be reused: a container's)


def is_staging_folder(entry: str) -> bool:
    """``entry`` (a name in a folder) is a staging folder of ``atomic_file_set``: its own while a set is being
    written, or one left by a process that was killed (SIGKILL, power loss) before it could remove it."""
    return _STAGING.fullmatch(entry) is not None


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:             # PermissionError: it exists, as another user's process
        return True
    return True


def remove_stale_staging(folder: str | Path) -> list[Path]:
    """Remove the staging folders in ``folder`` of processes that no longer run (a killed ``atomic_file_set``);
    returns them. A live process's (another call writing into the same folder) is left alone."""
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for entry in entries:
        match = _STAGING.fullmatch(entry.name)
        if match is None or not entry.is_dir() or entry.is_symlink() or entry.resolve() in _ACTIVE:
            continue
        pid = int(match.group(1))
        if pid == os.getpid() or not _process_alive(pid):    # ours but not in use: an earlier process's PID
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


@contextlib.contextmanager
def atomic_file_set(folder: str | Path, names: Iterable[str]) -> Iterator[Path]:
    """Write a set of files into ``folder`` all at once: ``with atomic_file_set(out, NAMES) as stage:`` write
    the files (named from ``names``) into ``stage``, a hidden staging folder inside ``folder``.

    When the block ends normally every file written into ``stage`` is moved into ``folder`` (``os.replace``:
    each file atomic, the whole set in milliseconds), then the files of ``names`` in ``folder`` that this block
    did not write (an earlier call's) are removed, as ``remove_unwritten`` does, and ``stage`` is removed.
    When the block raises (KeyboardInterrupt too) ``stage`` is removed and ``folder`` is left exactly as it
    was (folders made for it are removed again), then the exception goes on: the earlier call's whole set
    stays. Files of ``folder`` outside ``names`` are never touched; a file written into ``stage`` under a
    name not among ``names`` fails the set (ValueError) before anything is moved.

    Staging folders left by killed processes are removed when the next set is written into ``folder``
    (``remove_stale_staging``). Errors name the target (``folder``, or the file being moved into it); only an
    error in the moves themselves (a disk failing within those milliseconds) can leave part of the set moved.
    """
    folder = Path(folder)
    names = set(names)
    made = missing_folders(folder)
    folder.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(folder)
    try:
        stage = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", suffix=".tmp", dir=folder))
    except OSError as exc:      # name the folder asked for, not the hidden staging one
        remove_empty_folders(made)
        raise OSError(exc.errno, exc.strerror, str(folder)) from None
    _ACTIVE.add(stage.resolve())
    done = moved = False
    try:
        yield stage
        written = sorted(p.name for p in stage.iterdir())
        for name in written:
            if name not in names:
                raise ValueError(f"{folder / name}: not one of the files this set may hold ({', '.join(sorted(names))})")
        for name in written:
            try:
                os.replace(stage / name, folder / name)
            except OSError as exc:
                raise OSError(exc.errno, exc.strerror, str(folder / name)) from None
            moved = True
        remove_unwritten(folder, names, written)
        done = True
    finally:
        _ACTIVE.discard(stage.resolve())
        shutil.rmtree(stage, ignore_errors=True)
        if not done and not moved:
            remove_empty_folders(made)
