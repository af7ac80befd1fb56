"""The run folder is replaced whole or not at all, by one run at a time."""

import pytest

from featmap.pipeline.run_folder import MANIFEST, RunFolder, RunFolderError


def test_commit_replaces_the_folder_whole(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old_only.txt").write_text("old")
    (out / "metrics.json").write_text("old")
    with RunFolder(out) as folder:
        (folder.tmp / "metrics.json").write_text("new")
        assert (out / "metrics.json").read_text() == "old"          # nothing changes before the commit
        folder.commit()
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "metrics.json"] and (out / "metrics.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]                 # no lock file left beside it


def test_an_out_that_is_a_link_is_written_where_it_points(tmp_path):
    target = tmp_path / "disk" / "run"
    target.mkdir(parents=True)
    (target / "metrics.json").write_text("old")
    link = tmp_path / "run"
    link.symlink_to(target, target_is_directory=True)
    with RunFolder(link) as folder:
        (folder.tmp / "metrics.json").write_text("new")
        folder.commit()
    assert link.is_symlink() and (target / "metrics.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["disk", "run"]
    assert sorted(p.name for p in target.parent.iterdir()) == ["run"]          # no .run.old-PID, no lock


def test_a_failure_leaves_the_previous_run_untouched(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text("old")
    with pytest.raises(RunFolderError, match=r"writing the run failed .*No space left on device; the previous contents are unchanged"):
        with RunFolder(out) as folder:
            (folder.tmp / "fused_proposed.csv").write_text("new")
            raise OSError(28, "No space left on device", str(folder.tmp / "map.html"))
    assert [p.name for p in out.iterdir()] == ["metrics.json"] and (out / "metrics.json").read_text() == "old"
    assert not list(tmp_path.glob(".run.partial*"))


def test_a_second_run_into_the_same_folder_fails_at_once(tmp_path):
    out = tmp_path / "run"
    with RunFolder(out):
        with pytest.raises(RunFolderError, match="another featmap run is writing to it"):
            with RunFolder(out):
                pass
    with RunFolder(out) as folder:                                  # released afterwards
        folder.commit()
    assert out.is_dir()


def test_a_run_waiting_on_a_removed_lock_file_takes_the_new_one(tmp_path, monkeypatch):
    # the first run removes its lock file as it ends; a run that had opened that file just before must not
    # hold a lock nobody else can see: it opens the lock file again
    import os

    out = tmp_path / "run"
    first = RunFolder(out).__enter__()
    real_open, opened = os.open, []

    def open_then_first_run_ends(path, *args, **kwargs):
        fd = real_open(path, *args, **kwargs)
        if not opened:
            opened.append(path)
            first.__exit__(None, None, None)              # unlinks the file this run has just opened
        return fd

    monkeypatch.setattr(os, "open", open_then_first_run_ends)
    with RunFolder(out) as second:
        monkeypatch.undo()
        assert (tmp_path / ".run.lock").exists()          # the lock it holds is the one a third run would see
        with pytest.raises(RunFolderError, match="another featmap run"):
            with RunFolder(out):
                pass
        second.commit()
    assert out.is_dir()


def test_bad_out_paths(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(RunFolderError, match="exists and is not a folder"):
        with RunFolder(tmp_path / "afile"):
            pass
    with pytest.raises(RunFolderError, match="afile is a file, not a folder"):
        with RunFolder(tmp_path / "afile" / "run"):
            pass
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        import os

        if os.access(ro, os.W_OK):
            pytest.skip("running as a user who can write anywhere")
        with pytest.raises(RunFolderError, match="cannot write in"):
            with RunFolder(ro / "run"):
                pass
    finally:
        ro.chmod(0o755)


def test_a_folder_of_other_files_or_the_current_folder_is_never_replaced(tmp_path, monkeypatch):
    """A run replaces its --out whole: a folder holding anything but an earlier run (the input log, notes)
    or the folder the user stands in is refused before any work, and left as it was."""
    out = tmp_path / "logs"
    out.mkdir()
    (out / "intel.log").write_text("FLASER ...")
    with pytest.raises(RunFolderError, match=r"--out .*logs: holds other files and is not a featmap output folder"):
        with RunFolder(out):
            pass
    assert [p.name for p in out.iterdir()] == ["intel.log"]
    monkeypatch.chdir(out)
    with pytest.raises(RunFolderError, match=r"--out \.: is the current folder"):
        with RunFolder("."):
            pass
    with pytest.raises(RunFolderError, match=r"is the current folder \(or holds it\)"):
        with RunFolder(tmp_path):
            pass
    empty = tmp_path / "empty"
    empty.mkdir()
    with RunFolder(empty) as folder:                                # an empty folder is fine
        (folder.tmp / "metrics.json").write_text("{}")
        folder.commit()
    with pytest.raises(RunFolderError, match=r"no merged.json"):   # a run folder is no batch's merged map
        with RunFolder(empty, marker="merged.json"):
            pass
    with RunFolder(empty) as folder:                                # and a run may replace a run
        folder.commit()
