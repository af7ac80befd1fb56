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


# --- a set of files into a folder, all at once ----------------------------------------------------------

NAMES = ("a.png", "b.png", "c.csv")


def _snapshot(folder):
    """Every entry under ``folder`` (hidden ones too) with its bytes (None: a folder)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


def _earlier_set(folder):
    folder.mkdir()
    (folder / "a.png").write_bytes(b"old a")
    (folder / "b.png").write_bytes(b"old b")
    (folder / "notes.txt").write_text("mine")                   # a user's file, not among the names
    return _snapshot(folder)


@pytest.mark.parametrize("error", [RuntimeError("figure failed"), KeyboardInterrupt()])
def test_a_set_that_fails_half_way_leaves_the_folder_as_it_was(tmp_path, error):
    from featmap.io.atomic import atomic_file_set

    out = tmp_path / "figures"
    before = _earlier_set(out)
    with pytest.raises(type(error)):
        with atomic_file_set(out, NAMES) as stage:
            (stage / "a.png").write_bytes(b"new a")
            (stage / "c.csv").write_bytes(b"new c")
            raise error
    assert _snapshot(out) == before                             # old files, no new ones, no staging folder


def test_a_set_that_fails_into_a_new_folder_leaves_no_folder(tmp_path):
    from featmap.io.atomic import atomic_file_set

    with pytest.raises(RuntimeError):
        with atomic_file_set(tmp_path / "new" / "figures", NAMES) as stage:
            (stage / "a.png").write_bytes(b"new a")
            raise RuntimeError("figure failed")
    assert list(tmp_path.iterdir()) == []


def test_a_finished_set_moves_in_and_removes_the_earlier_calls_other_names_only(tmp_path):
    from featmap.io.atomic import atomic_file_set, is_staging_folder

    out = tmp_path / "figures"
    _earlier_set(out)
    with atomic_file_set(out, NAMES) as stage:
        assert stage.parent == out and is_staging_folder(stage.name) and stage.name.startswith(f".staging-{os.getpid()}-")
        (stage / "a.png").write_bytes(b"new a")
        (stage / "c.csv").write_bytes(b"new c")
        assert not (out / "c.csv").exists()                     # nothing moves before the block ends
    assert _snapshot(out) == {"a.png": b"new a", "c.csv": b"new c", "notes.txt": b"mine"}   # b.png: the earlier call's


def test_a_file_outside_the_names_fails_the_set_before_anything_moves(tmp_path):
    from featmap.io.atomic import atomic_file_set

    out = tmp_path / "figures"
    before = _earlier_set(out)
    with pytest.raises(ValueError, match="notes.txt: not one of the files"):
        with atomic_file_set(out, NAMES) as stage:
            (stage / "a.png").write_bytes(b"new a")
            (stage / "notes.txt").write_text("would overwrite the user's")
    assert _snapshot(out) == before


def test_a_failed_move_is_named_by_the_target_and_leaves_no_staging_folder(tmp_path, monkeypatch):
    from featmap.io.atomic import atomic_file_set

    def busy(src, dst):
        raise OSError(errno.EBUSY, "Device or resource busy", str(src), None, str(dst))

    out = tmp_path / "figures"
    before = _earlier_set(out)
    with pytest.raises(OSError) as caught:
        with atomic_file_set(out, NAMES) as stage:
            (stage / "a.png").write_bytes(b"new a")
            monkeypatch.setattr(os, "replace", busy)
    assert caught.value.filename == str(out / "a.png")
    assert _snapshot(out) == before


def test_staging_folders_of_killed_processes_are_removed_and_a_live_ones_kept(tmp_path):
    import subprocess
    import sys

    from featmap.io.atomic import atomic_file_set

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    out = tmp_path / "figures"
    out.mkdir()
    for pid in (int(dead.stdout), os.getpid()):                 # a killed process's; this PID's, not in use (reused)
        (out / f".staging-{pid}-abcd1234.tmp").mkdir()
        (out / f".staging-{pid}-abcd1234.tmp" / "a.png").write_bytes(b"half")
    live = out / f".staging-{os.getppid()}-live0000.tmp"       # another call writing into the folder right now
    live.mkdir()
    with atomic_file_set(out, NAMES) as stage:
        (stage / "b.png").write_bytes(b"new b")
    assert sorted(p.name for p in out.iterdir()) == sorted(["b.png", live.name])
