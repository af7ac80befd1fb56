"""Fetch a KITTI raw drive and its calibration, resumably, and unpack them into the raw layout.

``{base_url}/{drive}/{drive}_sync.zip`` and ``{base_url}/{date}_calib.zip`` (the layout of KITTI's
raw-data server). Downloads go to ``<name>.part`` and continue with an HTTP Range request when
interrupted; a finished file is verified (size against Content-Length, and the zip's CRCs) before it
is unpacked. Unpacking writes into a hidden folder and moves the drive into place at the end.
"""

from __future__ import annotations

import json
import os
import shutil
import urllib.error
import urllib.parse
import urllib.request
import zipfile
from pathlib import Path
from typing import Callable

from featmap.datasets.kitti_raw import parse_drive
from featmap.errors import DownloadError
from featmap.io.atomic import atomic_write_text, file_in_the_way, missing_folders, remove_empty_folders

KITTI_RAW_BASE_URL = "https://s3.eu-central-1.amazonaws.com/avg-kitti/raw_data"
CHUNK = 1 << 20

Progress = Callable[[int, int | None], None]     # (bytes so far, total bytes or None)


def drive_urls(drive: str, base_url: str = KITTI_RAW_BASE_URL) -> list[str]:
    date, _ = parse_drive(drive)
    base = base_url.rstrip("/")
    return [f"{base}/{drive}/{drive}_sync.zip", f"{base}/{date}_calib.zip"]


def fetch(url: str, dest: Path, progress: Progress | None = None, timeout: float = 30.0) -> Path:
    """Download ``url`` to ``dest``, resuming from ``dest.part``; returns ``dest``."""
    dest = Path(dest)
    if dest.exists():
        return dest
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = dest.with_name(dest.name + ".part")
    have = part.stat().st_size if part.exists() else 0
    request = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        response = urllib.request.urlopen(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:            # the .part is already complete
            os.replace(part, dest)
            return dest
        raise DownloadError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise DownloadError(f"{url}: cannot connect ({getattr(exc, 'reason', exc)}); "
                            "check the network or --base-url") from None
    with response:
        resumed = response.status == 206
        if not resumed:
            have = 0
        length = response.headers.get("Content-Length")
        total = have + int(length) if length is not None else None
        with open(part, "ab" if resumed else "wb") as fh:
            done = have
            while True:
                chunk = response.read(CHUNK)
                if not chunk:
                    break
                fh.write(chunk)
                done += len(chunk)
                if progress:
                    progress(done, total)
    size = part.stat().st_size
    if total is not None and size != total:
        raise DownloadError(f"{url}: incomplete download ({size} of {total} bytes); run the command again to resume")
    os.replace(part, dest)
    return dest


def verify_zip(path: Path) -> None:
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
    except zipfile.BadZipFile:
        path.unlink(missing_ok=True)
        raise DownloadError(f"{path}: not a valid zip file (removed; download again)") from None
    if bad is not None:
        path.unlink(missing_ok=True)
        raise DownloadError(f"{path}: corrupt member {bad} (removed; download again)")


def unpack(path: Path, data_dir: Path) -> dict[str, int]:
    """Unzip into ``data_dir`` through a hidden staging folder; refuses paths that leave ``data_dir``.
    Returns the size of every file unpacked, by its path relative to ``data_dir``."""
    data_dir = Path(data_dir)
    staging = data_dir / f".{path.stem}.unpacking"
    if staging.exists():
        shutil.rmtree(staging)
    with zipfile.ZipFile(path) as zf:
        for name in zf.namelist():
            target = (staging / name).resolve()
            if not str(target).startswith(str(staging.resolve())):
                raise DownloadError(f"{path}: member {name!r} would be written outside {data_dir}")
        zf.extractall(staging)
    sizes = {}
    for top in staging.iterdir():
        for item in sorted(top.rglob("*")) if top.is_dir() else [top]:
            rel = item.relative_to(staging)
            dest = data_dir / rel
            if item.is_dir():
                continue
            dest.parent.mkdir(parents=True, exist_ok=True)
            sizes[rel.as_posix()] = item.stat().st_size
            os.replace(item, dest)
    shutil.rmtree(staging)
    return sizes


UNPACKED = ".unpacked"
"""``DATA_DIR/.unpacked/<zip name>.json``: the files a zip was unpacked into, with their sizes."""


def is_unpacked(zip_name: str, data_dir: Path) -> bool:
    """True when every file ``zip_name`` was unpacked into is still in ``data_dir`` with its size."""
    record = Path(data_dir) / UNPACKED / f"{zip_name}.json"
    try:
        sizes = json.loads(record.read_text())["files"]
        return bool(sizes) and all((Path(data_dir) / rel).stat().st_size == size for rel, size in sizes.items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def download_drive(drive: str, data_dir: str | Path, base_url: str = KITTI_RAW_BASE_URL,
                   progress_factory: Callable[[str], Progress] | None = None, keep_zips: bool = False) -> list[Path]:
    """Fetch, verify and unpack a drive's ``_sync.zip`` and its date's calibration zip into ``data_dir``.

    A zip whose files are all still unpacked (``is_unpacked``) is not fetched again. Returns the zips
    fetched now. Raises DownloadError for a ``base_url`` that is not http(s) or a ``data_dir`` under a file;
    folders it made are removed again when they stay empty (a failed download)."""
    data_dir = Path(data_dir)
    if urllib.parse.urlparse(base_url).scheme not in ("http", "https"):
        raise DownloadError(f"--base-url {base_url}: not an http:// or https:// address")
    blocker = file_in_the_way(data_dir)
    if blocker is not None:
        raise DownloadError(f"--data-dir {data_dir}: {blocker} exists and is not a folder")
    zips = data_dir / "zips"
    made = missing_folders(data_dir)
    try:
        return _download(drive, data_dir, zips, base_url, progress_factory, keep_zips)
    finally:                                 # no empty folders left behind by a failed download
        remove_empty_folders([zips, *made])


def _download(drive: str, data_dir: Path, zips: Path, base_url: str,
              progress_factory: Callable[[str], Progress] | None, keep_zips: bool) -> list[Path]:
    out = []
    for url in drive_urls(drive, base_url):
        dest = zips / url.rsplit("/", 1)[-1]
        if is_unpacked(dest.name, data_dir):
            continue
        fetch(url, dest, progress_factory(dest.name) if progress_factory else None)
        verify_zip(dest)
        sizes = unpack(dest, data_dir)
        (data_dir / UNPACKED).mkdir(exist_ok=True)
        atomic_write_text(data_dir / UNPACKED / f"{dest.name}.json", json.dumps({"url": url, "files": sizes}))
        out.append(dest)
        if not keep_zips:
            dest.unlink()
    return out
