"""Output plug-ins: what each writes, and that WGS84 outputs are skipped for a run without a geo origin."""

import numpy as np

from featmap.fusion import fuse
from featmap.geo import GeoFrame
from featmap.io.run_metrics import MethodRecord, RunMetrics, ScanCounts, SourceRecord
from featmap.io.segments_csv import SegmentTable, read_fused_csv, read_segments_csv
from featmap.outputs import OUTPUTS, OutputConfig, RunProducts, write_outputs
from featmap.outputs.maps import distinct_scans
from featmap.simulation.segments import observe_walls


def _products(geo_frame, output=OutputConfig(plots=False)):
    rng = np.random.default_rng(0)
    segs, scan = observe_walls(np.array([[0, 0, 20, 0], [20, 0, 20, 10]], float), 6, 0.02, rng,
                               first_scan=np.array([0, 0]))
    table = SegmentTable(scan=scan, segments=segs, extra={"n_points": np.full(len(segs), 50.0)})
    results = {"proposed": fuse("proposed", segs, scan)}
    poses = np.tile(np.eye(4), (6, 1, 1))
    poses[:, 0, 3] = np.arange(6)
    metrics = RunMetrics(featmap_version="x", source=SourceRecord(kind="k", name="n", location="/x", dimension=3,
                                                                  frames=list(range(6)), frames_processed=list(range(6))),
                         scans=ScanCounts(total=6, processed=6, extracted_now=6, from_cache=0), segments=len(segs),
                         timings_s={}, methods={"proposed": MethodRecord(count=len(results["proposed"]), seconds=0.01)})
    return RunProducts(table=table, results=results, frames=list(range(6)), poses=poses, geo_frame=geo_frame,
                       truth=None, config_yaml="x: 1\n", metrics=metrics, output=output)


def test_a_run_with_a_geo_origin_gets_every_enabled_output(tmp_path):
    files = write_outputs(_products(GeoFrame(49.0, 8.4)), tmp_path)
    assert sorted(files) == sorted(p.name for p in tmp_path.iterdir())
    assert {"segments.csv", "fused_proposed.csv", "trajectory.csv", "fused_proposed.geojson", "segments.geojson",
            "trajectory.geojson", "map.kml", "map.html", "comparison.csv", "comparison.md"} == set(files)
    fused, support = read_fused_csv(tmp_path / "fused_proposed.csv")
    assert len(fused) == 2 and support.tolist() == [6, 6]
    assert len(read_segments_csv(tmp_path / "segments.csv")) == 12
    assert (tmp_path / "trajectory.csv").read_text().splitlines()[2] == "1,1.0000,0.0000,0.0000,0.000000"


def test_without_a_geo_origin_no_wgs84_output_is_written(tmp_path):
    files = write_outputs(_products(None, OutputConfig(plots=True)), tmp_path)
    assert set(files) == {"segments.csv", "fused_proposed.csv", "trajectory.csv", "map_overview.png",
                          "comparison.csv", "comparison.md"}
    assert sorted(files) == sorted(p.name for p in tmp_path.iterdir())


def test_switched_off_outputs_are_not_written(tmp_path):
    off = OutputConfig(geojson=False, kml=False, html=False, plots=False)
    assert set(write_outputs(_products(GeoFrame(49.0, 8.4), off), tmp_path)) == \
        {"segments.csv", "fused_proposed.csv", "trajectory.csv", "comparison.csv", "comparison.md"}
    assert all(hasattr(o, "needs_geo") and hasattr(o, "enabled") for o in OUTPUTS)


def test_distinct_scans_per_feature():
    labels = np.array([0, 0, 0, 1, -1, 1])
    scan = np.array([3, 3, 4, 7, 8, 9])
    assert distinct_scans(labels, scan, 2).tolist() == [2, 2]


def test_a_refined_run_writes_its_refined_trajectory_and_the_corrections(tmp_path):
    from dataclasses import replace

    from featmap.refinement import apply_corrections

    base = _products(GeoFrame(49.0, 8.4))
    corrections = np.zeros((6, 3))
    corrections[2] = [0.5, -0.25, np.deg2rad(2.0)]
    products = replace(base, poses=apply_corrections(base.poses, corrections), source_poses=base.poses,
                       corrections=corrections)
    files = write_outputs(products, tmp_path)
    assert {"trajectory_refined.csv", "pose_corrections.csv", "trajectory_refined.geojson"} <= set(files)
    assert (tmp_path / "trajectory.csv").read_text().splitlines()[3] == "2,2.0000,0.0000,0.0000,0.000000"
    assert (tmp_path / "trajectory_refined.csv").read_text().splitlines()[3] == "2,2.5000,-0.2500,0.0000,0.034907"
    assert (tmp_path / "pose_corrections.csv").read_text().splitlines()[:4] == [
        "frame,dx_m,dy_m,dyaw_deg", "0,0.0000,0.0000,0.00000", "1,0.0000,0.0000,0.00000", "2,0.5000,-0.2500,2.00000"]
    import json
    fc = json.loads((tmp_path / "trajectory_refined.geojson").read_text())
    assert len(fc["features"]) == 5 and fc["features"][1]["properties"]["dx_m"] == 0.5
    # without a refinement (corrections None) none of them is written
    assert not {"trajectory_refined.csv", "pose_corrections.csv"} & set(write_outputs(base, tmp_path / "plain"))
