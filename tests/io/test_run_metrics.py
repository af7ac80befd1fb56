"""metrics.json: typed, round-trips, and a wrong file is one line naming what is wrong."""

import json

import pytest

from featmap.errors import InputFileError
from featmap.io.run_metrics import (GeoRecord, MethodRecord, RunMetrics, ScanCounts, SourceRecord, read_run_metrics,
                                    write_run_metrics)


def _metrics():
    return RunMetrics(featmap_version="x", source=SourceRecord(kind="kitti_raw", name="d", location="/data/d",
                                                               dimension=3, frames=[0, 1, 2], frames_processed=[0, 2],
                                                               skipped={"1": "bad"}),
                      geo_frame=GeoRecord(lat0_deg=49.0, lon0_deg=8.4), references={"truth": "truth_rel"},
                      primary="truth", scans=ScanCounts(total=3, processed=2, extracted_now=2, from_cache=0),
                      segments=10, timings_s={"total": 1.0},
                      methods={"proposed": MethodRecord(count=3, seconds=0.1,
                                                        scores={"truth": {"precision": 0.9, "vertex_error_sum_m": {"a": 0.1, "b": None}}})})


def test_round_trip_and_helpers(tmp_path):
    path = write_run_metrics(tmp_path / "metrics.json", _metrics())
    back = read_run_metrics(path)
    assert back == _metrics()
    assert back.primary_scores("proposed")["precision"] == 0.9
    assert back.reference_path("truth", tmp_path) == tmp_path / "truth_rel"     # relative: to the run folder
    assert back.geo_frame.frame().lat0_deg == 49.0


@pytest.mark.parametrize("edit,match", [
    (lambda d: d.pop("methods"), r"'methods' field required"),
    (lambda d: d["methods"]["proposed"].update(count="many"), r"'methods.proposed.count' input should be a valid integer"),
    (lambda d: d.update(schema_version=1), r"written by another featmap version \(schema 1"),
    (lambda d: d.update(extra=1), r"'extra' extra inputs are not permitted"),
])
def test_wrong_files_fail_in_one_line(tmp_path, edit, match):
    data = _metrics().model_dump(mode="json")
    edit(data)
    (tmp_path / "metrics.json").write_text(json.dumps(data))
    with pytest.raises(InputFileError, match=match):
        read_run_metrics(tmp_path / "metrics.json")
    (tmp_path / "metrics.json").write_text("[1, 2]")
    with pytest.raises(InputFileError, match="expected a JSON object"):
        read_run_metrics(tmp_path / "metrics.json")
