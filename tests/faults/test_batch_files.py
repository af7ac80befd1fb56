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
    ("set: [output.plots=false]\ndrives:\n  - world: WORLDS/tiny.yaml\n    name: summary.json\n",
     "b.yaml: drives[0]: 'summary.json' cannot be a run folder name: the batch writes its own summary.json in "),
    ("set: [output.plots=false]\ndrives:\n  - world: WORLDS/tiny.yaml\n  - world: WORLDS/tiny_b.yaml\n    name: errors.txt\n",
     "b.yaml: drives[1]: 'errors.txt' cannot be a run folder name: the batch writes its own errors.txt in "),
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
    one_line_error(cli("batch", tmp_path / "none.yaml"), "none.yaml: batch file not found")
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


def test_a_batch_files_scheduler_is_blamed_on_the_file(tmp_path, batch):
    path = batch("scheduler: 'foo://x'\ndrives:\n  - world: WORLDS/tiny.yaml\n")
    one_line_error(cli("batch", path, "--out", tmp_path / "out"), f"{path}: scheduler: foo://x: not a scheduler address")
    one_line_error(cli("batch", path, "--out", tmp_path / "out", "--scheduler", "bar://y"),
                   "--scheduler bar://y: not a scheduler address")                   # the flag replaces the file's
    assert not (tmp_path / "out").exists()


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


def fake_run_folder(folder, manifest=True):
    """The files ``featmap run`` leaves (enough to be recognized; nothing reads them here)."""
    folder.mkdir(parents=True)
    names = ["metrics.json", "config.yaml", "segments.csv"]
    for name in names:
        (folder / name).write_text("{}")
    if manifest:
        (folder / ".featmap-files").write_text("".join(f"{n}\n" for n in names))
    return folder


def test_an_out_that_is_a_run_folder_or_holds_other_files(tmp_path, batch):
    path = batch("set: [output.plots=false]\ndrives:\n  - world: WORLDS/tiny.yaml\n")   # (no map tiles, ever)
    run = fake_run_folder(tmp_path / "run")
    old_run = fake_run_folder(tmp_path / "old_run", manifest=False)    # made before run folders listed their files
    before = sorted(p.name for p in run.iterdir())
    one_line_error(cli("batch", path, "--out", run),
                   f"--out {run}: is the output folder of a featmap run (it holds .featmap-files), not of a batch")
    one_line_error(cli("batch", path, "--out", old_run), f"--out {old_run}: is the output folder of a featmap run "
                                                          "(it holds metrics.json)")
    one_line_error(cli("batch", path, "--out", run / "batch"),
                   f"--out {run / 'batch'}: is inside {run}, which is the output folder of a featmap run")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("mine")
    one_line_error(cli("batch", path, "--out", notes), f"--out {notes}: holds other files (such as todo.txt) and is "
                                                       "not a featmap batch output folder (no summary.json)")
    in_file = batch(f"out: {run}\nset: [output.plots=false]\ndrives:\n  - world: WORLDS/tiny.yaml\n")
    one_line_error(cli("batch", in_file), f"b.yaml: out {run}: is the output folder of a featmap run")
    assert sorted(p.name for p in run.iterdir()) == before and not (run / "batch").exists()
    assert [p.name for p in notes.iterdir()] == ["todo.txt"]


def test_an_earlier_batchs_out_is_resumed_into(tmp_path, batch):
    """New, empty, left by killed runs only, or an earlier batch's (with its summary, or stopped before it):
    accepted; a folder holding a run folder that is none of the batch's drives is not."""
    from featmap.batch import plan_batch
    from featmap.errors import ConfigError

    path = batch("drives:\n  - world: WORLDS/tiny.yaml\n")
    empty, leftovers, done, stopped = (tmp_path / n for n in ("empty", "leftovers", "done", "stopped"))
    empty.mkdir()
    leftovers.mkdir()
    (leftovers / ".tiny.lock").write_text("")
    (leftovers / ".tiny.partial-123").mkdir()
    (leftovers / ".staging-123-abcd1234.tmp").mkdir()              # a killed `featmap figures --out` into it
    fake_run_folder(done / "tiny")
    (done / "summary.json").write_text("{}")
    (done / "errors.txt").write_text("")
    fake_run_folder(stopped / "tiny")
    (stopped / "tiny" / "batch.json").write_text("{}")
    fake_run_folder(stopped / "tiny_b")                            # killed before its key was written
    keyless = tmp_path / "keyless"                                  # its only drive killed before its key
    fake_run_folder(keyless / "tiny")
    for out in (tmp_path / "new", empty, leftovers, done, stopped, keyless):
        assert plan_batch(path, out).out == out
    stranger = tmp_path / "stranger"                                # a run folder that is none of its drives
    fake_run_folder(stranger / "other")
    with pytest.raises(ConfigError, match=r"holds other files \(such as other\) and is not a featmap batch output"):
        plan_batch(path, stranger)


@pytest.fixture
def new_children():
    """Worker processes started by the test and still alive (``new_children()``, after waiting a little)."""
    import multiprocessing
    import time

    before = {p.pid for p in multiprocessing.active_children()}

    def alive():
        deadline = time.time() + 5
        while True:
            left = [p for p in multiprocessing.active_children() if p.pid not in before]
            if not left or time.time() > deadline:
                return left
            time.sleep(0.1)

    return alive


def _closed(cluster) -> bool:
    from distributed.core import Status
    from distributed.deploy.spec import SpecCluster

    return (cluster.status == Status.closed and cluster not in SpecCluster._instances
            and all(w.status in (Status.closed, Status.failed) for w in cluster._created))


def test_ctrl_c_while_the_local_cluster_starts_its_workers(monkeypatch, new_children):
    """Ctrl-C while the workers start (a worker process spawning): the workers and the cluster are closed and
    the interrupt goes on; Dask's exit hook finds nothing half-started (it failed with AssertionError: Status.init)."""
    import asyncio
    import time

    import distributed.utils

    from featmap.batch import connect

    real_sync = distributed.utils.sync
    started = []

    def interrupted_sync(loop, func, *args, **kwargs):
        if getattr(func, "__name__", "") != "_correct_state":
            return real_sync(loop, func, *args, **kwargs)
        cluster = func.__self__                     # what sync() does, until Ctrl-C arrives: it cancels and raises

        async def run():
            return await func()

        future = asyncio.run_coroutine_threadsafe(run(), loop.asyncio_loop)
        deadline = time.time() + 5
        while time.time() < deadline and not any(getattr(w, "process", None) is not None for w in cluster._created):
            time.sleep(0.01)
        started.append(cluster)
        future.cancel()
        raise KeyboardInterrupt

    monkeypatch.setattr(distributed.utils, "sync", interrupted_sync)
    with pytest.raises(KeyboardInterrupt):
        connect(None, 1)
    assert len(started) == 1 and started[0]._created and _closed(started[0])
    assert not new_children()


def test_ctrl_c_while_the_client_connects_to_the_new_cluster(monkeypatch, new_children):
    import distributed

    import featmap.batch as batch

    clusters = []

    def local_cluster(workers):
        clusters.append(real_local_cluster(workers))
        return clusters[-1]

    def interrupted_client(*args, **kwargs):
        raise KeyboardInterrupt

    real_local_cluster = batch.local_cluster
    monkeypatch.setattr(batch, "local_cluster", local_cluster)
    monkeypatch.setattr(distributed, "Client", interrupted_client)
    with pytest.raises(KeyboardInterrupt):
        batch.connect(None, 1)
    assert len(clusters) == 1 and _closed(clusters[0])
    assert not new_children()
