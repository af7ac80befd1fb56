"""The content-keyed segment cache: keys change with what the result depends on; bad entries are re-made."""

import re

import numpy as np
import pytest

from featmap.extraction import ExtractionConfig, ScanSegments, extractor_for
from featmap.extraction.ransac_planes import RansacPlanesConfig
from featmap.pipeline.segment_store import CacheError, SegmentStore, scan_key

EXTRACTOR = extractor_for(3, ExtractionConfig())
POINTS = np.random.default_rng(0).normal(size=(100, 4)).astype(np.float32)
SEGS = ScanSegments(np.array([[0.0, 1.0, 5.0, 1.0]]), np.array([40]), np.array([0.02]), np.array([0.5]),
                    np.array([-1.0]), np.array([2.0]))


def test_the_key_follows_points_config_and_extractor_version():
    key = scan_key(POINTS, EXTRACTOR, RansacPlanesConfig())
    assert key == scan_key(POINTS.copy(), EXTRACTOR, RansacPlanesConfig())
    other = POINTS.copy()
    other[7, 2] += 0.01                                              # one coordinate of one point
    assert scan_key(other, EXTRACTOR, RansacPlanesConfig()) != key
    assert scan_key(POINTS[:, :3].copy(), EXTRACTOR, RansacPlanesConfig()) != key
    assert scan_key(POINTS, EXTRACTOR, RansacPlanesConfig(max_gap_m=2.0)) != key
    from dataclasses import replace

    assert scan_key(POINTS, replace(EXTRACTOR, version=EXTRACTOR.version + 1), RansacPlanesConfig()) != key
    # a scan with no return (every beam at max range) has a key of its own
    empty = scan_key(np.zeros((0, 4), np.float32), EXTRACTOR, RansacPlanesConfig())
    assert empty == scan_key(np.zeros((0, 4), np.float32), EXTRACTOR, RansacPlanesConfig())
    assert empty not in (key, scan_key(np.zeros((0, 3), np.float32), EXTRACTOR, RansacPlanesConfig()))


def test_the_key_follows_the_extractors_source_code(tmp_path, monkeypatch):
    """An edit of the extractor's code without a new version number gets new keys (entries made by the
    old code are never served)."""
    import importlib
    from dataclasses import replace

    from featmap.pipeline import segment_store

    def extractor_from(text: str, name: str):
        (tmp_path / f"{name}.py").write_text(text)
        monkeypatch.syspath_prepend(str(tmp_path))
        module = importlib.import_module(name)
        return replace(EXTRACTOR, extract=module.extract)

    first = extractor_from("def extract(points, config):\n    return None\n", "extractor_a")
    edited = extractor_from("def extract(points, config):\n    return None  # changed\n", "extractor_b")
    same = extractor_from("def extract(points, config):\n    return None\n", "extractor_c")
    keys = [scan_key(POINTS, e, RansacPlanesConfig()) for e in (first, edited, same)]
    assert keys[0] != keys[1] and keys[0] == keys[2]
    assert segment_store.extractor_source(EXTRACTOR) != segment_store.extractor_source(first)


def test_entries_round_trip_and_bad_entries_are_discarded(tmp_path):
    store = SegmentStore(tmp_path / "cache")
    key = scan_key(POINTS, EXTRACTOR, RansacPlanesConfig())
    assert store.get(key) is None
    store.put(key, SEGS)
    back = store.get(key)
    assert all(np.array_equal(getattr(back, k), v) for k, v in SEGS.arrays().items())
    # truncated, empty, or an entry made from other inputs (renamed into place): discarded, not served
    path = store.path(key)
    data = path.read_bytes()
    for damage in (data[: len(data) // 2], b""):
        path.write_bytes(damage)
        assert store.get(key) is None and not path.exists()
        store.put(key, SEGS)
    other = scan_key(POINTS[:50], EXTRACTOR, RansacPlanesConfig())
    store.put(other, SEGS)
    store.path(other).replace(path)
    assert store.get(key) is None
    assert len(store.discarded) == 3 and all(str(path) in d for d in store.discarded)


def test_unusable_cache_folders_fail_before_any_work(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(CacheError, match="exists and is not a folder"):
        SegmentStore(tmp_path / "file")
    with pytest.raises(CacheError, match="cannot create it"):
        SegmentStore(tmp_path / "file" / "sub")
    assert SegmentStore(None).get("abc") is None


def _store_with_entries(root, n: int) -> tuple[SegmentStore, list[str]]:
    """A store holding ``n`` entries last used 1, 2, ... n days ago (the first the most recent)."""
    import os
    import time

    store = SegmentStore(root)
    keys = [scan_key(POINTS[: 10 + i], EXTRACTOR, RansacPlanesConfig()) for i in range(n)]
    now = time.time()
    for days, key in enumerate(keys, start=1):
        store.put(key, SEGS)
        os.utime(store.path(key), (now - days * 86400, now - days * 86400))
    return store, keys


def test_prune_removes_the_least_recently_used_entries_first(tmp_path):
    store, keys = _store_with_entries(tmp_path / "cache", 4)
    assert store.get(keys[3]) is not None              # served now: the most recently used
    size = store.entries()[0].size
    assert [e.path for e in store.entries()] == [store.path(k) for k in (keys[2], keys[1], keys[0], keys[3])]
    (tmp_path / "cache" / keys[0][:2] / "notes.txt").write_text("not an entry")

    dry = store.prune(max_bytes=2 * size, dry_run=True)
    assert (dry.removed_entries, dry.kept_entries, dry.kept_bytes) == (2, 2, 2 * size)
    assert len(store.entries()) == 4                   # a dry run removes nothing

    result = store.prune(max_bytes=2 * size)
    assert result == dry
    assert {e.path for e in store.entries()} == {store.path(keys[0]), store.path(keys[3])}
    assert store.get(keys[3]) is not None and store.get(keys[2]) is None
    assert (tmp_path / "cache" / keys[0][:2] / "notes.txt").exists()     # only entries are removed
    assert store.prune(max_bytes=0).kept_entries == 0


def test_prune_removes_entries_unused_for_longer_than_asked(tmp_path):
    store, keys = _store_with_entries(tmp_path / "cache", 4)
    result = store.prune(unused_for_s=2.5 * 86400)          # used 3 and 4 days ago: removed
    assert (result.removed_entries, result.kept_entries) == (2, 2)
    assert {e.path for e in store.entries()} == {store.path(keys[0]), store.path(keys[1])}
    assert store.prune(unused_for_s=10 * 86400).removed_entries == 0     # nothing that old
    assert store.prune().removed_entries == 0                             # nothing asked: nothing removed
    with pytest.raises(ValueError, match="max_bytes"):
        store.prune(max_bytes=-1)
    assert SegmentStore(None).entries() == []


def test_the_cache_command_shows_and_prunes(tmp_path):
    from typer.testing import CliRunner

    from featmap.cli import app

    store, keys = _store_with_entries(tmp_path / "cache", 3)
    runner = CliRunner()
    shown = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "cache")])
    assert shown.exit_code == 0 and re.search(r"│\s+3\s+│", shown.output)           # the entries' cell
    pruned = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "cache"), "--unused-days", "1.5"])
    assert pruned.exit_code == 0 and "removed" in pruned.output
    assert [e.path for e in store.entries()] == [store.path(keys[0])]
    bad = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "cache"), "--max-size", "lots"])
    assert bad.exit_code == 2 and "--max-size 'lots': not a size" in bad.output
    missing = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "nowhere"), "--max-size", "1GB"])
    assert missing.exit_code == 2 and "no such folder" in missing.output and not (tmp_path / "nowhere").exists()
    negative = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "cache"), "--unused-days", "-1"])
    assert negative.exit_code == 2 and "--unused-days" in negative.output
    dry = runner.invoke(app, ["cache", "--cache-dir", str(tmp_path / "cache"), "--dry-run"])
    assert dry.exit_code == 2 and "--dry-run: give --max-size or --unused-days" in dry.output
    assert len(store.entries()) == 1


def test_sizes_parse_in_decimal_and_binary_units():
    from featmap.cli import parse_size

    assert parse_size("4GB", "--max-size") == 4 * 10**9
    assert parse_size("1.5GiB", "--max-size") == int(1.5 * 2**30)
    assert parse_size("500m", "--max-size") == 500 * 10**6
    assert parse_size("0", "--max-size") == 0


def test_prune_honours_both_limits_together_and_keeps_what_a_run_used_meanwhile(tmp_path):
    store, keys = _store_with_entries(tmp_path / "cache", 4)         # used 1, 2, 3, 4 days ago
    size = store.entries()[0].size
    # the age limit alone would remove two, the size limit alone one: two go
    result = store.prune(max_bytes=3 * size, unused_for_s=2.5 * 86400, dry_run=True)
    assert (result.removed_entries, result.kept_entries) == (2, 2)
    # the age limit alone would remove one, the size limit alone three: three go
    result = store.prune(max_bytes=1 * size, unused_for_s=3.5 * 86400, dry_run=True)
    assert (result.removed_entries, result.kept_entries) == (3, 1)

    listed = store.entries()
    assert store.get(keys[3]) is not None                   # served while a prune was deciding
    store.entries = lambda: listed                           # (that prune's listing, made before the run used it)
    result = store.prune(max_bytes=3 * size)
    assert (result.removed_entries, result.kept_entries) == (1, 3)
    assert store.path(keys[3]).exists() and not store.path(keys[2]).exists()


def test_an_entry_removed_meanwhile_is_a_plain_miss_and_a_read_only_cache_can_be_listed(tmp_path):
    store, keys = _store_with_entries(tmp_path / "cache", 1)
    store.path(keys[0]).unlink()
    assert store.get(keys[0]) is None and store.discarded == []       # not reported as a corrupt entry
    listing = SegmentStore(tmp_path / "cache", writable=False)
    assert listing.entries() == []
    with pytest.raises(CacheError, match="no such folder"):
        SegmentStore(tmp_path / "nowhere", writable=False)
    assert not (tmp_path / "nowhere").exists()


def test_prune_removes_the_temporary_files_of_killed_writes_and_nothing_else(tmp_path):
    import os
    import time

    store, keys = _store_with_entries(tmp_path / "cache", 2)
    folder = store.path(keys[0]).parent
    old_leftover = folder / f".{keys[0]}.npz.ab12cd_3.tmp"             # a write killed two hours ago
    fresh_leftover = folder / f".{keys[0]}.npz.zz99yy00.tmp"           # a write going on now
    other = folder / ".notes.tmp"
    for path in (old_leftover, fresh_leftover, other):
        path.write_bytes(b"x" * 10)
    hours_ago = time.time() - 7200
    os.utime(old_leftover, (hours_ago, hours_ago))
    os.utime(other, (hours_ago, hours_ago))
    assert [leftover.path for leftover in store.leftovers()] == [old_leftover]

    dry = store.prune(dry_run=True)
    assert (dry.removed_entries, dry.removed_leftovers, dry.leftover_bytes) == (0, 1, 10) and old_leftover.exists()
    result = store.prune()
    assert (result.removed_entries, result.kept_entries, result.removed_leftovers) == (0, 2, 1)
    assert not old_leftover.exists() and fresh_leftover.exists() and other.exists()
    assert len(store.entries()) == 2
