"""Bad batch files and flags: one line naming the file and the key, exit 2, nothing started or written."""

import pytest

from tests.faults.conftest import cli, one_line_error

pytest.importorskip("distributed")


@pytest.fixture
def batch(tmp_path, tiny_worlds):
    def write(text: str):
        path = tmp_path / "b.yaml"
        path.write_text(text.replace("WORLDS", str(tiny_worlds)))
        return path

    return write


@pytest.mark.parametrize("text,needle", [
    ("drives: []\n", "b.yaml: drives: List should have at least 1 item"),
    ("drive:\n  - world: residential\n", "b.yaml: unknown key 'drive'"),
    ("drives:\n  - world: residential\n    frame: '0:10'\n", "b.yaml: unknown key 'drives[0].frame'"),
    ("drives:\n  - world: residential\n    kitti: 2011_09_26_drive_0001\n", "drives[0]: give exactly one of 'world'"),
    ("drives:\n  - dataset: carmen\n", "drives[0]: 'dataset' needs a 'location'"),
    ("drives:\n  - world: residential\n    data_dir: x\n", "drives[0]: 'data_dir' goes with 'kitti'"),
    ("drives:\n  - world: nowhere_world\n", "drives[0]: unknown world 'nowhere_world'"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n  - world: WORLDS/tiny.yaml\n", "a second drive named 'tiny' (drives[0])"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n    name: merged\n", "'merged' cannot be a run folder name"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n  - world: WORLDS/../tiny_worlds_copy/tiny.yaml\n    name: other\n",
     "would both be simulated into"),
    ("drives:\n  - kitti: 2011_09_26_drive_9*\n    data_dir: /nonexistent\n", "drives[0]: kitti '/nonexistent/*/2011_09_26_drive_9*_sync' matches nothing"),
    ("drives:\n  - kitti: drive_0001\n", "drives[0]: "),
    ("drives:\n  - dataset: carmen\n    location: /nonexistent/*.log\n", "location '/nonexistent/*.log' matches nothing"),
    ("drives:\n  - dataset: lidar9000\n    location: x\n", "unknown dataset 'lidar9000'"),
    ("drives:\n  - dataset: simulated\n    location: residential\n", "give a simulated drive as 'world: NAME_OR_FILE'"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n    set: [fusion.proposed.delta=3]\n", "drives[0] (tiny): --set fusion.proposed.delta=3"),
    ("set: [fusion.proposed.gamma=2]\ndrives:\n  - world: WORLDS/tiny.yaml\n", "fusion.proposed.gamma"),
    ("methods: [proposed, fastest]\ndrives:\n  - world: WORLDS/tiny.yaml\n", "b.yaml: methods: unknown method 'fastest'"),
    ("workers: 0\ndrives:\n  - world: WORLDS/tiny.yaml\n", "b.yaml: workers: Input should be greater than or equal to 1"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n    config: /nonexistent.yaml\n", "/nonexistent.yaml: config file not found"),
    ("drives:\n  - world: WORLDS/tiny.yaml\n    frames: 'x:y'\n", "drives[0]: 'frames': 'x:y': expected integers"),
    ("drives:\n  - dataset: carmen\n    location: WORLDS/tiny.yaml\n    skip_bad_scans: true\n",
     "'skip_bad_scans' leaves out unreadable scan files; a CARMEN log is read whole"),
    ("out: WORLDS/tiny.yaml\ndrives:\n  - world: WORLDS/tiny.yaml\n", "b.yaml: out"),
    ("drives: [\n", "b.yaml:2: not valid YAML"),
    ("- world: residential\n", "b.yaml: expected a mapping of sections"),
])
def test_bad_batch_files(batch, tmp_path, tiny_worlds, text, needle):
    copy = tiny_worlds.parent / "tiny_worlds_copy"                # another world file named tiny.yaml
    copy.mkdir(exist_ok=True)
    (copy / "tiny.yaml").write_text((tiny_worlds / "tiny.yaml").read_text().replace("height: 8", "height: 12"))
    res = cli("batch", batch(text), *([] if text.startswith("out:") else ["--out", tmp_path / "out"]))
    one_line_error(res, needle)
    assert not (tmp_path / "out").exists()


def test_a_missing_batch_file_and_a_bad_flag(tmp_path, batch):
    one_line_error(cli("batch", tmp_path / "none.yaml"), "none.yaml: config file not found")
    path = batch("drives:\n  - world: WORLDS/tiny.yaml\n")
    one_line_error(cli("batch", path, "--set", "fusion.nope=1", "--out", tmp_path / "out"), "--set fusion.nope=1")
    one_line_error(cli("batch", path, "--config", tmp_path / "missing.yaml", "--out", tmp_path / "out"), "missing.yaml")
    assert not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_is_one_line():
    from featmap.batch import connect
    from featmap.errors import ConfigError

    with pytest.raises(ConfigError, match=r"--scheduler tcp://127.0.0.1:9: cannot connect"):
        connect("tcp://127.0.0.1:9", timeout_s=1)


@pytest.mark.parametrize("address", ["notanaddress", "http://127.0.0.1:1"])
def test_a_malformed_scheduler_address_is_one_line(address):
    from featmap.batch import connect
    from featmap.errors import ConfigError

    with pytest.raises(ConfigError, match=f"--scheduler {address}: not a scheduler address"):
        connect(address, timeout_s=1)


def test_an_out_that_is_a_file(tmp_path, batch, segments_file):
    (tmp_path / "afile").write_text("keep")
    one_line_error(cli("batch", batch("drives:\n  - world: WORLDS/tiny.yaml\n"), "--out", tmp_path / "afile"),
                   f"--out {tmp_path / 'afile'}: {tmp_path / 'afile'} exists and is not a folder")
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"input: {segments_file}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.3]\n")
    one_line_error(cli("sweep", sweep, "--out", tmp_path / "afile"), "--out")
    assert (tmp_path / "afile").read_text() == "keep"


@pytest.fixture
def segments_file(tmp_path):
    import numpy as np

    from featmap.io.segments_csv import SegmentTable, write_segments_csv

    segs = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 0.02, 10.0, 0.02]])
    return write_segments_csv(tmp_path / "segments.csv", SegmentTable(scan=np.array([0, 1]), segments=segs))


def test_bad_sweep_over_a_batch(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(f"batch: {tmp_path / 'nobatch'}\ngrid:\n  fusion.proposed.eta_m: [0.3]\n")
    one_line_error(cli("sweep", path, "--out", tmp_path / "out"), "merged.json: not found")
