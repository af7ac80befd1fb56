"""Simulated drives are reused only while they were simulated from the same world and simulator."""

import pandas as pd

from featmap.datasets.simulated import ensure_simulated_drive
from featmap.reporting import RecordingReporter
from tests.conftest import TINY_WORLD


def _walls(data_dir):
    return pd.read_csv(next(data_dir.rglob("truth/walls.csv")))


def test_an_edited_world_file_is_simulated_again(tmp_path):
    world = tmp_path / "w" / "tiny.yaml"
    world.parent.mkdir()
    world.write_text(TINY_WORLD)
    data_dir, _ = ensure_simulated_drive(str(world), tmp_path / "sim")
    stamp = (data_dir / "world.json").stat().st_mtime_ns
    first = _walls(data_dir)
    assert first.query("building == 'A'")[["y1", "y2"]].min().min() == 6

    reporter = RecordingReporter()
    assert ensure_simulated_drive(str(world), tmp_path / "sim", reporter)[0] == data_dir
    assert (data_dir / "world.json").stat().st_mtime_ns == stamp          # unchanged: reused as it is
    assert not any("again" in text for text in reporter.infos)

    world.write_text(TINY_WORLD.replace("[[-5, 6], [15, 6], [15, 16], [-5, 16]]", "[[-5, 20], [15, 20], [15, 30], [-5, 30]]"))
    ensure_simulated_drive(str(world), tmp_path / "sim", reporter)
    assert any("simulating it again" in text for text in reporter.infos)
    assert _walls(data_dir).query("building == 'A'")[["y1", "y2"]].min().min() == 20


def test_another_world_file_of_the_same_name_does_not_get_the_first_ones_drive(tmp_path):
    for folder, y in (("a", 6), ("b", 22)):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "street.yaml").write_text(
            TINY_WORLD.replace("[[-5, 6], [15, 6], [15, 16], [-5, 16]]", f"[[-5, {y}], [15, {y}], [15, {y + 10}], [-5, {y + 10}]]"))
    for folder, y in (("a", 6), ("b", 22), ("a", 6)):
        data_dir, _ = ensure_simulated_drive(str(tmp_path / folder / "street.yaml"), tmp_path / "sim")
        assert _walls(data_dir).query("building == 'A'")[["y1", "y2"]].min().min() == y


def test_the_same_world_read_from_another_path_reuses_the_drive(tmp_path):
    for folder in ("before", "moved"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "street.yaml").write_text(TINY_WORLD)
    data_dir, _ = ensure_simulated_drive(str(tmp_path / "before" / "street.yaml"), tmp_path / "sim")
    stamp = (data_dir / "world.json").stat().st_mtime_ns
    reporter = RecordingReporter()
    assert ensure_simulated_drive(str(tmp_path / "moved" / "street.yaml"), tmp_path / "sim", reporter)[0] == data_dir
    assert (data_dir / "world.json").stat().st_mtime_ns == stamp
    assert not any("again" in text for text in reporter.infos)


def _first_oxts_position(data_dir):
    """The first OXTS record's latitude, longitude (the pose the drive's files hold)."""
    first = sorted(data_dir.rglob("oxts/data/*.txt"))[0]
    return first.read_text().split()[:2]


def test_a_drive_with_pose_noise_has_its_own_folder_and_stamp_and_one_without_a_stamp_is_simulated_again(tmp_path):
    world = tmp_path / "tiny.yaml"
    world.write_text(TINY_WORLD)
    exact, _ = ensure_simulated_drive(str(world), tmp_path / "sim")
    noisy, _ = ensure_simulated_drive(str(world), tmp_path / "sim", pose_noise=(0.5, 1.0), folder="tiny_noisy")
    assert noisy == tmp_path / "sim" / "tiny_noisy" and exact == tmp_path / "sim" / "tiny"
    assert _first_oxts_position(noisy) != _first_oxts_position(exact)                                # the noise is in the poses
    stamps = [(d / "world.json").read_text() for d in (exact, noisy)]
    assert stamps[0] != stamps[1]

    reporter = RecordingReporter()                                         # reused, each with its own settings
    assert ensure_simulated_drive(str(world), tmp_path / "sim", reporter, pose_noise=(0.5, 1.0), folder="tiny_noisy")[0] == noisy
    assert ensure_simulated_drive(str(world), tmp_path / "sim", reporter)[0] == exact
    assert not any("again" in text for text in reporter.infos)

    # a drive another noise (or sensor) was asked for in the same folder is simulated again
    ensure_simulated_drive(str(world), tmp_path / "sim", reporter, pose_noise=(0.1, 0.2), folder="tiny_noisy")
    assert any("the world, its sensor or pose noise, or the simulator changed" in text for text in reporter.infos)

    (exact / "world.json").unlink()                                        # written before stamps existed
    reporter = RecordingReporter()
    ensure_simulated_drive(str(world), tmp_path / "sim", reporter)
    assert any("nothing says what made" in text and "simulating it again" in text for text in reporter.infos)
    assert (exact / "world.json").read_text() == stamps[0]
