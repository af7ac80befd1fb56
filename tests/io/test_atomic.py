"""Atomic writes: all or nothing, and errors name the file asked for, not the hidden temporary one."""

import errno
import os
import tempfile

import pytest

from featmap.io.atomic import atomic_write_text


def test_a_write_replaces_the_file_whole_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "map.geojson"
    target.write_text("old")
    atomic_write_text(target, "new")
    assert target.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["map.geojson"]


def test_a_folder_that_cannot_be_written_is_named_by_the_target(tmp_path, monkeypatch):
    # (the tests run as root, for whom chmod does not deny: the refusal is simulated where it happens)
    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / ".map.geojson.abc.tmp"))

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    with pytest.raises(PermissionError) as caught:
        atomic_write_text(tmp_path / "map.geojson", "new")
    assert caught.value.filename == str(tmp_path / "map.geojson") and caught.value.strerror == "Permission denied"


def test_a_failed_rename_is_named_by_the_target_and_removes_the_temporary(tmp_path, monkeypatch):
    def busy(src, dst):
        raise OSError(errno.EBUSY, "Device or resource busy", src, None, dst)

    monkeypatch.setattr(os, "replace", busy)
    with pytest.raises(OSError) as caught:
        atomic_write_text(tmp_path / "map.geojson", "new")
    assert caught.value.filename == str(tmp_path / "map.geojson")
    assert list(tmp_path.iterdir()) == []
