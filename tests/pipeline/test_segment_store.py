"""The content-keyed segment cache: keys change with what the result depends on; bad entries are re-made."""

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
