"""A content-keyed cache of per-scan extraction results (sensor-frame segments).

An entry's key is a hash of everything the result depends on: the scan's points (their bytes, shape
and type), the extractor's name and version, its config section and the source code of its module and
of the modules every extractor shares (``extraction/base.py``, ``geometry.py``). A re-simulated drive, a
changed scan, another extractor setting or any edit of the extractor's code therefore never meets a
stale entry (a version number alone missed edits made without raising it); poses
and calibration are not in the key because entries are in the sensor frame (the pipeline moves them to
the world frame afterwards). Each entry also records its own key: an entry that does not match, is
truncated or unreadable is discarded (and re-made by the caller) instead of being served.

Layout: ``ROOT/<first two hex digits>/<key>.npz``; writes are atomic (a crash never leaves half an entry).
An entry's modification time is its last use (set when it is written or served), so :meth:`SegmentStore.prune`
removes the entries used least recently first: those of old extractor code and of deleted drives, which no
run asks for again, go first.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import sys
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.errors import FeatmapError
from featmap.extraction.base import Extractor, ScanSegments
from featmap.io.atomic import atomic_path


class CacheError(FeatmapError):
    """The cache folder cannot be used (not a folder, not writable)."""


SHARED_SOURCES = (Path(__file__).resolve().parents[1] / "extraction" / "base.py",
                  Path(__file__).resolve().parents[1] / "geometry.py")
"""Modules every extractor builds on: their source is part of every key."""


@functools.lru_cache(maxsize=None)
def _source_digest(module_file: str) -> str:
    """Hash of an extractor module's source and of ``SHARED_SOURCES`` (read once per process)."""
    h = hashlib.blake2b(digest_size=16)
    for path in (Path(module_file), *SHARED_SOURCES):
        h.update(path.read_bytes())
    return h.hexdigest()


def extractor_source(extractor: Extractor) -> str:
    """The source digest of ``extractor``: its ``extract`` function's module and the shared modules."""
    module = sys.modules.get(extractor.extract.__module__)
    where = getattr(module, "__file__", None)
    return _source_digest(where) if where else ""


def scan_key(points: np.ndarray, extractor: Extractor, section) -> str:
    """The content key of one scan's extraction: points x extractor (name, version, source) x config (hex,
    40 chars)."""
    h = hashlib.sha256()           # (SHA-256 has CPU instructions: a scan's 2 MB hash in a third of BLAKE2b's time)
    pts = np.ascontiguousarray(points)
    h.update(f"{pts.dtype.str}{pts.shape}".encode())
    if pts.size:                                  # (a scan with no return hashes its dtype and shape alone)
        h.update(memoryview(pts).cast("B"))
    h.update(json.dumps({"extractor": extractor.name, "version": extractor.version,
                         "source": extractor_source(extractor), "config": section.model_dump(mode="json")},
                        sort_keys=True).encode())
    return h.hexdigest()[:40]


ENTRY_NAME = re.compile(r"[0-9a-f]{40}\.npz")
"""The file name of a cache entry (its key and ``.npz``)."""
LEFTOVER_NAME = re.compile(r"\.[0-9a-f]{40}\.npz\.[A-Za-z0-9_]+\.tmp")
"""The name of the hidden temporary twin an entry is written through (:func:`featmap.io.atomic.atomic_path`),
left behind only by a process killed while writing. Nothing but entries and these is ever removed."""
LEFTOVER_AGE_S = 3600.0
"""A temporary twin older than this (seconds) belongs to no write still going on."""


@dataclass(frozen=True)
class CacheEntry:
    """One entry on disk: its file, size in bytes and last use (seconds since the epoch)."""
    path: Path
    size: int
    last_use: float


@dataclass(frozen=True)
class PruneResult:
    """What :meth:`SegmentStore.prune` removed (or would remove, in a dry run) and what it kept; leftovers:
    the temporary files of killed writes it removed."""
    removed_entries: int
    removed_bytes: int
    kept_entries: int
    kept_bytes: int
    removed_leftovers: int = 0
    leftover_bytes: int = 0


class SegmentStore:
    """Per-scan extraction results on disk, by content key (``root=None``: a store that keeps nothing).

    Args:
        root: cache folder; created when missing.
        writable: False for a cache that must exist already (listing or pruning it, `featmap cache`): it is
            then never created, nor checked for writing (a failed removal is an ``OSError`` naming the file).
    Raises:
        CacheError: when ``root`` is a file or cannot be written (checked here, before any work), or
            (``writable=False``) is no folder.
    """

    def __init__(self, root: str | Path | None, writable: bool = True):
        self.root = None if root is None else Path(root)
        self.discarded: list[str] = []
        if self.root is not None:
            if self.root.exists() and not self.root.is_dir():
                raise CacheError(f"--cache-dir {self.root}: exists and is not a folder")
            if not writable:
                if not self.root.is_dir():
                    raise CacheError(f"--cache-dir {self.root}: no such folder")
                return
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise CacheError(f"--cache-dir {self.root}: cannot create it ({exc.strerror})") from None
            if not os.access(self.root, os.W_OK | os.X_OK):
                raise CacheError(f"--cache-dir {self.root}: not writable")

    def path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.npz"

    def get(self, key: str) -> ScanSegments | None:
        """The entry of ``key``, or None when there is none (a corrupt or mismatched one is deleted)."""
        if self.root is None:
            return None
        path = self.path(key)
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["key"]) != key:
                    raise ValueError("entry made from other inputs")
                segments = ScanSegments.from_arrays({k: data[k] for k in data.files if k != "key"})
        except FileNotFoundError:          # none (or pruned meanwhile by `featmap cache`): a plain miss
            return None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            self.discarded.append(f"{path}: {type(exc).__name__}: {exc}")
            path.unlink(missing_ok=True)
            return None
        try:
            os.utime(path)                  # its last use, for prune (a read-only cache still serves)
        except OSError:
            pass
        return segments

    def put(self, key: str, segments: ScanSegments) -> None:
        if self.root is None:
            return
        path = self.path(key)
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, key=np.array(key), **segments.arrays())
        except OSError as exc:
            raise CacheError(f"{path}: cannot write the segment cache ({exc.strerror})") from None

    def _files(self, name: re.Pattern) -> list[CacheEntry]:
        """The files of the two-digit subfolders whose name matches ``name`` (and starts, past a leading
        dot, with their subfolder's digits), least recently modified first."""
        if self.root is None:
            return []
        found = []
        for sub in sorted(self.root.iterdir()):
            if not (len(sub.name) == 2 and sub.is_dir()):
                continue
            for path in sub.iterdir():
                if name.fullmatch(path.name) and path.name.lstrip(".").startswith(sub.name):
                    try:
                        stat = path.stat()
                    except FileNotFoundError:           # removed meanwhile by another process
                        continue
                    found.append(CacheEntry(path, stat.st_size, stat.st_mtime))
        return sorted(found, key=lambda entry: (entry.last_use, entry.path.name))

    def entries(self) -> list[CacheEntry]:
        """Every entry in the cache folder (files named ``<key>.npz`` in its two-digit subfolders), least
        recently used first; [] for a store that keeps nothing."""
        return self._files(ENTRY_NAME)

    def leftovers(self, now: float | None = None) -> list[CacheEntry]:
        """The temporary files of writes killed half-way (older than :data:`LEFTOVER_AGE_S`)."""
        now = time.time() if now is None else now
        return [f for f in self._files(LEFTOVER_NAME) if now - f.last_use > LEFTOVER_AGE_S]

    def prune(self, max_bytes: int | None = None, unused_for_s: float | None = None, now: float | None = None,
              dry_run: bool = False) -> PruneResult:
        """Remove the entries unused for more than ``unused_for_s`` seconds, then the least recently used
        ones until the rest take at most ``max_bytes`` (with neither, no entry), and the :meth:`leftovers`
        of killed writes. ``now``: the time to measure from (seconds since the epoch; default the clock).
        ``dry_run``: only count what would go."""
        if max_bytes is not None and max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        if unused_for_s is not None and unused_for_s < 0:
            raise ValueError(f"unused_for_s must be >= 0, got {unused_for_s}")
        entries = self.entries()
        now = time.time() if now is None else now
        total = sum(entry.size for entry in entries)
        removed, removed_bytes = 0, 0
        for entry in entries:             # least recently used first: what goes is a prefix of them
            too_old = unused_for_s is not None and now - entry.last_use > unused_for_s
            too_big = max_bytes is not None and total - removed_bytes > max_bytes
            if not (too_old or too_big):
                break
            if not dry_run:
                try:
                    if entry.path.stat().st_mtime != entry.last_use:
                        continue                         # a run used it since it was listed: keep it
                    entry.path.unlink()
                except FileNotFoundError:            # removed meanwhile (another prune)
                    continue
            removed += 1
            removed_bytes += entry.size
        leftovers = self.leftovers(now)
        if not dry_run:
            for leftover in leftovers:
                leftover.path.unlink(missing_ok=True)
        return PruneResult(removed, removed_bytes, len(entries) - removed, total - removed_bytes, len(leftovers),
                           sum(leftover.size for leftover in leftovers))
