"""A helper to run the pipeline on the small simulated drive of tests/conftest.py."""

import pytest

from featmap.datasets import KittiRawDataset
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.pipeline.executor import local_executor
from featmap.reporting import RecordingReporter


@pytest.fixture
def run_case1(case1_drive, tmp_path):
    """``run_case1(overrides=(), methods=..., workers=1, skip=False, out=..., cache=...)`` -> RunResult."""

    def run(overrides=(), methods=("proposed", "density"), workers=1, skip=False, out=None, cache=None, frames=None):
        ds = KittiRawDataset(case1_drive.root, case1_drive.drive, frames, skip_bad_scans=skip)
        cfg = load_config(None, ["output.plots=false", *overrides])   # no basemap fetches in these tests
        with local_executor(workers) as executor:
            pipe = MappingPipeline(cfg, list(methods), SegmentStore(cache or tmp_path / "cache"), executor,
                                   RecordingReporter(), skip_bad_scans=skip)
            return pipe.run(ds, out or tmp_path / "run")

    return run
