"""``featmap download`` against an HTTP server on 127.0.0.1 that speaks Range requests."""

import shutil
import threading
import zipfile
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import pytest

from featmap.datasets import KittiRawDataset
from featmap.datasets.kitti_download import download_drive, fetch
from featmap.errors import DownloadError

DRIVE = "2000_01_01_drive_0001"


class RangeHandler(SimpleHTTPRequestHandler):
    ranges: list = []

    def log_message(self, *args):
        pass

    def send_head(self):
        header = self.headers.get("Range")
        path = self.translate_path(self.path)
        if header is None:
            return super().send_head()
        try:
            f = open(path, "rb")
        except OSError:
            self.send_error(404)
            return None
        size = f.seek(0, 2)
        start = int(header.split("=")[1].split("-")[0])
        RangeHandler.ranges.append(start)
        if start >= size:
            self.send_error(416)
            f.close()
            return None
        f.seek(start)
        self.send_response(206)
        self.send_header("Content-Length", str(size - start))
        self.send_header("Content-Range", f"bytes {start}-{size - 1}/{size}")
        self.end_headers()
        return f


@pytest.fixture
def server(case1_drive, tmp_path):
    site = tmp_path / "site"
    (site / DRIVE).mkdir(parents=True)
    root = case1_drive.root
    with zipfile.ZipFile(site / DRIVE / f"{DRIVE}_sync.zip", "w") as zf:
        for p in sorted((root / "2000_01_01" / f"{DRIVE}_sync").rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(root))
    with zipfile.ZipFile(site / "2000_01_01_calib.zip", "w") as zf:
        for p in sorted((root / "2000_01_01").glob("calib_*.txt")):
            zf.write(p, p.relative_to(root))
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), partial(RangeHandler, directory=str(site)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", site
    httpd.shutdown()


def test_download_unpacks_a_loadable_drive(server, tmp_path):
    url, _ = server
    download_drive(DRIVE, tmp_path / "kitti", base_url=url)
    ds = KittiRawDataset(tmp_path / "kitti", DRIVE)
    assert len(ds) == 40 and not (tmp_path / "kitti" / "zips").exists()


def test_a_second_download_fetches_only_what_is_no_longer_unpacked(server, tmp_path):
    url, site = server
    download_drive(DRIVE, tmp_path / "kitti", base_url=url)
    hidden = tmp_path / "hidden"
    shutil.move(site, hidden)                          # the server now answers 404 to everything
    assert download_drive(DRIVE, tmp_path / "kitti", base_url=url) == []
    scan = next((tmp_path / "kitti").rglob("0000000007.bin"))
    size = scan.stat().st_size
    scan.unlink()                                      # a file of the drive's zip is gone: that zip is fetched again
    with pytest.raises(DownloadError, match=f"{DRIVE}_sync.zip: HTTP 404"):
        download_drive(DRIVE, tmp_path / "kitti", base_url=url)
    shutil.move(hidden, site)
    fetched = download_drive(DRIVE, tmp_path / "kitti", base_url=url)
    assert [p.name for p in fetched] == [f"{DRIVE}_sync.zip"] and scan.stat().st_size == size
    assert len(KittiRawDataset(tmp_path / "kitti", DRIVE)) == 40


def test_download_resumes_from_a_partial_file(server, tmp_path):
    url, site = server
    src = site / DRIVE / f"{DRIVE}_sync.zip"
    dest = tmp_path / "dl" / src.name
    dest.parent.mkdir()
    data = src.read_bytes()
    (dest.parent / (src.name + ".part")).write_bytes(data[: len(data) // 2])
    RangeHandler.ranges.clear()
    seen = []
    fetch(f"{url}/{DRIVE}/{src.name}", dest, progress=lambda done, total: seen.append((done, total)))
    assert RangeHandler.ranges == [len(data) // 2]
    assert dest.read_bytes() == data
    assert seen[-1] == (len(data), len(data))


def test_corrupt_and_missing_downloads_fail_clearly(server, tmp_path):
    url, site = server
    zpath = site / DRIVE / f"{DRIVE}_sync.zip"
    raw = bytearray(zpath.read_bytes())
    raw[200:260] = b"x" * 60                      # damage a member's data: its CRC no longer matches
    zpath.write_bytes(bytes(raw))
    with pytest.raises(DownloadError, match="corrupt member|not a valid zip"):
        download_drive(DRIVE, tmp_path / "k1", base_url=url)
    with pytest.raises(DownloadError, match=r"2000_01_01_drive_0002_sync.zip: HTTP 404"):
        download_drive("2000_01_01_drive_0002", tmp_path / "k2", base_url=url)
    with pytest.raises(DownloadError, match="cannot connect"):
        download_drive(DRIVE, tmp_path / "k3", base_url="http://127.0.0.1:9")
    shutil.rmtree(tmp_path / "k1", ignore_errors=True)


def test_bad_base_urls_and_data_dirs_fail_before_anything_is_made(tmp_path):
    with pytest.raises(DownloadError, match="--base-url notaurl: not an http:// or https:// address"):
        download_drive(DRIVE, tmp_path / "kitti", base_url="notaurl")
    (tmp_path / "afile").write_text("keep")
    with pytest.raises(DownloadError, match="--data-dir .*afile exists and is not a folder"):
        download_drive(DRIVE, tmp_path / "afile" / "kitti", base_url="http://127.0.0.1:9")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_a_failed_download_leaves_no_empty_folders(tmp_path):
    with pytest.raises(DownloadError, match="cannot connect"):
        download_drive(DRIVE, tmp_path / "new" / "kitti", base_url="http://127.0.0.1:9")
    assert not (tmp_path / "new").exists()
