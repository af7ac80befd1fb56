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
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
import zipfile
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


class SegmentStore:
    """Per-scan extraction results on disk, by content key (``root=None``: a store that keeps nothing).

    Args:
        root: cache folder; created when missing.
    Raises:
        CacheError: when ``root`` is a file or cannot be written (checked here, before any work).
    """

    def __init__(self, root: str | Path | None):
        self.root = None if root is None else Path(root)
        self.discarded: list[str] = []
        if self.root is not None:
            if self.root.exists() and not self.root.is_dir():
                raise CacheError(f"--cache-dir {self.root}: exists and is not a folder")
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
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["key"]) != key:
                    raise ValueError("entry made from other inputs")
                return ScanSegments.from_arrays({k: data[k] for k in data.files if k != "key"})
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            self.discarded.append(f"{path}: {type(exc).__name__}: {exc}")
            path.unlink(missing_ok=True)
            return None

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
