"""Atomic file writes: a crash or Ctrl-C never leaves a half-written output file behind."""

from __future__ import annotations

import contextlib
import os
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
