"""Bad input files and flags: one line naming the file or flag, exit 2, nothing written."""

import json
import math
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from featmap.errors import ConfigError
from featmap.geo import GeoFrame
from featmap.io.segments_csv import SegmentTable, read_fused_csv, write_segments_csv
from featmap.simulation.segments import observe_walls
from tests.faults.conftest import cli, one_line_error, run_args


@pytest.fixture
def segments_csv(tmp_path):
    rng = np.random.default_rng(0)
    segs, scan = observe_walls(np.array([[0, 0, 30, 0], [0, 15, 30, 15]], float), 10, 0.03, rng,
                               first_scan=np.array([0, 0]))
    return write_segments_csv(tmp_path / "segments.csv", SegmentTable(scan=scan, segments=segs))


@pytest.mark.parametrize("text,needle", [
    ("", "empty file; expected a header"),
    ("scan,x1,y1,x2\n0,1,2,3\n", "missing column(s) y2"),
    ("scan,x1,y1,x2,y2\n0,1,2,3\n", "segments.csv:2: expected 5 values, found 4"),
    ("scan,x1,y1,x2,y2\n0,1,2,3,4\n0.5,1,2,3,5\n", "segments.csv:3: column 'scan': not an integer"),
    ("scan,x1,y1,x2,y2\n0,1,2,inf,4\n", "segments.csv:2: column 'x2': inf is not a finite number"),
    ("scan,x1,y1,x2,y2\n0,1,2,abc,4\n", "segments.csv:2: column 'x2': not a number"),
    ("scan,x1,y1,x2,y2,n_points\n0,1,2,3,4,-3\n", "segments.csv:2: column 'n_points': -3 is negative"),
])
def test_malformed_segment_csvs(tmp_path, text, needle):
    path = tmp_path / "segments.csv"
    path.write_text(text)
    one_line_error(cli("fuse", path, "--out", tmp_path / "o"), needle)
    assert not (tmp_path / "o").exists()


def test_a_csv_that_is_not_text_or_is_missing(tmp_path):
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00\x01" * 10)
    one_line_error(cli("fuse", tmp_path / "bin.csv", "--out", tmp_path / "o"), "bin.csv: cannot read")
    one_line_error(cli("fuse", tmp_path / "none.csv", "--out", tmp_path / "o"), "none.csv: file not found")


def test_a_bom_in_the_header_is_fine(tmp_path, segments_csv):
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + segments_csv.read_bytes())
    res = cli("fuse", bom, "--out", tmp_path / "o", "--method", "proposed")
    assert res.exit_code == 0, res.output
    assert len(read_fused_csv(tmp_path / "o" / "fused_proposed.csv")[0]) == 2


def test_duplicate_rows_do_not_inflate_support(tmp_path, segments_csv):
    lines = segments_csv.read_text().splitlines()
    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join(lines + lines[1:6]) + "\n")
    res = cli("fuse", dup, "--out", tmp_path / "o", "--method", "proposed")
    assert res.exit_code == 0 and "skipped 5 duplicate row(s)" in res.output
    assert sorted(read_fused_csv(tmp_path / "o" / "fused_proposed.csv")[1].tolist()) == [10, 10]


def test_coordinates_far_from_the_origin_fuse_like_near_it(tmp_path, segments_csv):
    """UTM-like northings (1e9 m): every method works and returns the same map, translated."""
    lines = segments_csv.read_text().splitlines()
    far = [lines[0]] + [",".join([r.split(",")[0], *(f"{float(v) + (5e8 if k % 2 else 3e5):.6f}"
                                                      for k, v in enumerate(r.split(",")[1:5]))]) for r in lines[1:]]
    (tmp_path / "far.csv").write_text("\n".join(far) + "\n")
    assert cli("fuse", segments_csv, "--out", tmp_path / "near", "--method", "all").exit_code == 0
    res = cli("fuse", tmp_path / "far.csv", "--out", tmp_path / "far", "--method", "all")
    assert res.exit_code == 0, res.output
    for method in ("proposed", "meanshift", "density"):
        near, _ = read_fused_csv(tmp_path / "near" / f"fused_{method}.csv")
        far_segs, _ = read_fused_csv(tmp_path / "far" / f"fused_{method}.csv")
        assert len(near) == len(far_segs)
        assert np.abs(far_segs - [3e5, 5e8, 3e5, 5e8] - near).max() < 1e-3, method


@pytest.mark.parametrize("override,needle", [
    ("fusion.proposed.delta_deg=0", "'fusion.proposed.delta_deg' input should be greater than 0"),
    ("fusion.proposed.min_support=true", "'fusion.proposed.min_support' input should be a valid integer (got True)"),
    ("fusion.proposed.gama=0.2", "unknown key 'fusion.proposed.gama' (did you mean 'fusion.proposed.gamma'?)"),
    ("fusion.corners.mode=sharp", "'fusion.corners.mode' must be one of"),
    ("refinement.method=icp", "'refinement.method' must be one of"),
    ("refinement.pose_graph.gates_m=[0.5,0]", "every gate must be positive"),
    ("refinement.pose_graph.motion_sigma_m=-1", "'refinement.pose_graph.motion_sigma_m' input should be greater than or equal to 0"),
    ("novalue", "expected KEY=VALUE"),
])
def test_bad_settings(tmp_path, segments_csv, override, needle):
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--set", override), needle)
    assert not (tmp_path / "o").exists()


def test_bad_config_files(tmp_path, segments_csv):
    latin = tmp_path / "latin.yaml"
    latin.write_bytes("fusion:\n  proposed: {delta_deg: 5}  # d\xe9j\xe0\n".encode("latin-1"))
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--config", latin), "latin.yaml: not UTF-8 text")
    broken = tmp_path / "broken.yaml"
    broken.write_text("fusion: [1, 2\n")
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--config", broken), "broken.yaml:2: not valid YAML")
    one_line_error(cli("fuse", segments_csv, "--out", tmp_path / "o", "--config", tmp_path / "none.yaml"),
                   "none.yaml: config file not found")


def test_a_csv_with_a_header_and_no_rows_fuses_to_empty_maps_with_a_warning(tmp_path):
    path = tmp_path / "header.csv"
    path.write_text("scan,x1,y1,x2,y2\n")
    res = cli("fuse", path, "--out", tmp_path / "o", "--method", "proposed")
    assert res.exit_code == 0 and f"{path}: no segment to fuse" in " ".join(res.output.split())
    assert (tmp_path / "o" / "fused_proposed.csv").read_text().count("\n") == 1      # the header only


def test_a_method_that_keeps_nothing_warns(tmp_path, segments_csv):
    res = cli("fuse", segments_csv, "--out", tmp_path / "o", "--method", "proposed", "--set",
              "fusion.proposed.min_support=1000", "--set", "fusion.proposed.min_support_length_m=null")
    assert res.exit_code == 0 and "proposed: no feature from 20 segments" in res.output


def test_bad_drive_flags(case1_drive, tmp_path):
    for flag in ("--world", "--drive", "--dataset"):          # an empty --world ran the whole default drive
        one_line_error(cli("run", flag, "", "--out", tmp_path / "r"), f"{flag} '': give a value")
    one_line_error(cli("run", "--drive", "drive18", "--out", tmp_path / "r"), "expected YYYY_MM_DD_drive_NNNN")
    one_line_error(cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--frames", "25:100")),
                   "--frames 25:100: 2000_01_01_drive_0001 has 40 frames (0..39)")
    one_line_error(cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--frames", "a:b")), "expected integers")
    one_line_error(cli("run", "--dataset", "pcap", "--source", tmp_path, "--out", tmp_path / "r"), "unknown format")
    (tmp_path / "tiny.yaml").write_text("name: x\n")
    one_line_error(cli("run", "--dataset", "kitti_raw", "--source", tmp_path / "tiny.yaml", "--out", tmp_path / "r"),
                   "tiny.yaml: not a KITTI raw drive folder")
    one_line_error(cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--method", "kmeans")), "unknown method 'kmeans'")
    assert not (tmp_path / "r").exists()


def test_a_truncated_oxts_packet_and_a_truncated_scan(drive_copy, tmp_path):
    root, drive = drive_copy
    d = root / drive[:10] / f"{drive}_sync"
    (d / "oxts" / "data" / "0000000004.txt").write_text("49.0 8.4 100\n")
    args = ["run", "--drive", drive, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c"]
    one_line_error(cli(*args), "0000000004.txt: OXTS packet has 3 fields, expected 30")
    res = cli(*args, "--skip-bad-scans", "--workers", "1", "--set", "output.plots=false")
    assert res.exit_code == 0 and "skipped 1 bad scan" in res.output


def _fused_run(case1_drive, tmp_path):
    assert cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "c", "--method", "proposed", "--frames", "0:10")).exit_code == 0
    return tmp_path / "r"


@pytest.mark.parametrize("features,needle", [
    ([{"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [[["8.42", "49.01"], [8.43, 49.01], [8.43, 49.02]]]}}],
     "a position must be [lon, lat] numbers"),
    ([{"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [[[8.42, 49.01], [None, 49.01], [8.43, 49.02]]]}}],
     "fp.geojson: not valid JSON (NaN is not a finite number)"),                 # read_json refuses NaN
    ([], "no building Polygon in the FeatureCollection"),
])
def test_evaluate_against_bad_footprints(case1_drive, tmp_path, features, needle):
    run = _fused_run(case1_drive, tmp_path)
    fp = tmp_path / "fp.geojson"
    fp.write_text(json.dumps({"type": "FeatureCollection", "features": features}).replace("null", "NaN"))
    one_line_error(cli("evaluate", run / "fused_proposed.csv", "--truth", fp), needle)


def test_evaluate_and_compare_with_wrong_files(case1_drive, tmp_path):
    run = _fused_run(case1_drive, tmp_path)
    one_line_error(cli("evaluate", run / "fused_proposed.csv", "--truth", tmp_path / "nothing"), "ground truth not found")
    one_line_error(cli("evaluate", run / "fused_proposed.csv", "--truth", tmp_path), "not a simulated drive's truth/ folder")
    one_line_error(cli("evaluate", run / "fused_proposed.csv", "--truth", case1_drive.drive_dir / "truth", "--origin", "north"),
                   "--origin 'north': expected LAT,LON")
    (run / "metrics.json").write_text(json.dumps({"schema_version": 2, "methods": [1, 2]}))
    one_line_error(cli("compare", run), "metrics.json: not a featmap metrics file")
    one_line_error(cli("figures", run), "metrics.json: not a featmap metrics file")
    one_line_error(cli("compare", tmp_path / "nowhere"), "metrics.json: not found")
    one_line_error(cli("figures", tmp_path / "nowhere"), "not a folder")


@pytest.mark.parametrize("args,needle", [
    (("run", "-j", "0"), "Invalid value for '--workers' / '-j'"),
    (("simulate", "--world", "residential", "--out", "x", "--noise", "-1"), "Invalid value for '--noise'"),
    (("simulate", "--world", "residential", "--out", "x", "--dropout", "1"), "--dropout"),
    (("run", "--frames"), "Option '--frames' requires an argument"),
    (("fuse",), "Missing argument"),
    (("nonsense",), "No such command 'nonsense'"),
])
def test_bad_flags_are_one_line_like_every_other_error(args, needle):
    one_line_error(cli(*args), needle)


def test_figures_of_a_run_with_a_damaged_trajectory(case1_drive, tmp_path):
    run = _fused_run(case1_drive, tmp_path)
    text = (run / "trajectory.csv").read_text()
    (run / "trajectory.csv").write_text(text[:100])                   # cut in the middle of a row
    error = one_line_error(cli("figures", run), "not a trajectory table")
    assert f"trajectory.csv:{text[:100].count(chr(10)) + 1}: " in error          # the line that was cut


def test_bad_sweep_files(tmp_path, segments_csv):
    one_line_error(cli("sweep", tmp_path / "none.yaml"), "none.yaml: sweep file not found")
    bad_drive = tmp_path / "drive.yaml"
    bad_drive.write_text("drive: bogus\nmethods: [proposed]\ngrid: {fusion.proposed.gamma: [0.5]}\n")
    one_line_error(cli("sweep", bad_drive, "--out", tmp_path / "s"),        # the file's key, not a --drive flag
                   f"{bad_drive}: drive: 'bogus': expected YYYY_MM_DD_drive_NNNN")
    huge = tmp_path / "huge.yaml"
    grid = "".join(f"  fusion.proposed.{k}: {{start: 0, stop: 1, num: 10000}}\n" for k in ("gamma", "eta_m"))
    grid += "  fusion.proposed.delta_deg: {start: 1, stop: 90, num: 10000}\n"
    huge.write_text(f"input: {segments_csv}\nmethods: [proposed]\ngrid:\n{grid}")
    one_line_error(cli("sweep", huge, "--out", tmp_path / "s"), "1,000,000,000,000 combinations")
    assert not (tmp_path / "s").exists()


def test_simulate_flags(tmp_path):
    one_line_error(cli("simulate", "--world", "nowhere", "--out", tmp_path / "s"), "nowhere")
    one_line_error(cli("simulate", "--world", "", "--out", tmp_path / "s"), "--world '': give a built-in")
    one_line_error(cli("simulate", "--out", tmp_path / "s", "--sensor", "hdl32"), "--sensor 'hdl32'")
    one_line_error(cli("simulate", "--out", tmp_path / "s", "--pose-noise", "big"), "--pose-noise 'big'")
    assert not (tmp_path / "s").exists()


def test_segments_spanning_more_than_any_map_of_the_earth(tmp_path, segments_csv):
    """One row a billion metres off: a one-line error naming the row, not a fusion that needs 30 GB."""
    lines = segments_csv.read_text().splitlines()
    scan, x1, y1, x2, y2 = lines[3].split(",")[:5]
    lines[3] = ",".join([scan, str(float(x1) + 1e9), y1, str(float(x2) + 1e9), y2])
    (tmp_path / "wide.csv").write_text("\n".join(lines) + "\n")
    one_line_error(cli("fuse", tmp_path / "wide.csv", "--out", tmp_path / "o"), "the farthest from the others is data row 3")
    assert not (tmp_path / "o").exists()


def test_oxts_positions_off_the_earth(drive_copy, tmp_path):
    root, drive = drive_copy
    packet = root / drive[:10] / f"{drive}_sync" / "oxts" / "data" / "0000000004.txt"
    fields = packet.read_text().split()
    args = ["run", "--drive", drive, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c"]
    for k, value, needle in ((0, "95", "latitude 95"), (1, "500", "longitude 500")):
        packet.write_text(" ".join(fields[:k] + [value] + fields[k + 1:]) + "\n")
        one_line_error(cli(*args), f"0000000004.txt: OXTS {needle}" if k == 0 else "out of range")
    assert not (tmp_path / "r").exists()


def test_a_text_file_named_like_a_scan(drive_copy, tmp_path):
    root, drive = drive_copy
    scan = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000003.bin"
    scan.write_bytes(b"this is not a velodyne scan!!!!!")           # 32 bytes: two 'points' of text
    one_line_error(cli("run", "--drive", drive, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir",
                       tmp_path / "c"), "0000000003.bin: 2 point(s) farther than 10000 m")


def test_a_data_dir_without_a_drive(tmp_path):
    one_line_error(cli("run", "--data-dir", tmp_path, "--out", tmp_path / "r"), "--data-dir")
    assert not (tmp_path / "r").exists()


def test_skip_bad_scans_on_a_carmen_log_is_refused(tmp_path):
    from tests.conftest import write_room_log

    log = write_room_log(tmp_path / "room.log", np.random.default_rng(0), n_scans=8)
    one_line_error(cli("run", "--carmen", log, "--out", tmp_path / "r", "--skip-bad-scans"), "a CARMEN log is read whole")


def test_carmen_poses_beyond_any_map(tmp_path):
    from tests.conftest import write_room_log

    log = write_room_log(tmp_path / "room.log", np.random.default_rng(0), n_scans=8)
    lines = log.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("FLASER"))
    tokens = lines[k].split()
    n = int(tokens[1])
    for value, needle in (("1e30", f"room.log:{k + 1}: FLASER: pose coordinate 1e+30 m is beyond"),
                          ("1e9", "frame 0: pose at")):
        tokens[2 + n] = value
        lines[k] = " ".join(tokens)
        log.write_text("\n".join(lines) + "\n")
        one_line_error(cli("run", "--carmen", log, "--out", tmp_path / "r", "--set", "output.plots=false"), needle)
    assert not (tmp_path / "r").exists()


def test_figures_take_presets_and_refuse_an_unknown_tile_source(case1_drive, tmp_path):
    run = _fused_run(case1_drive, tmp_path)
    one_line_error(cli("figures", run, "--tiles", "notaurl", "--out", tmp_path / "f"), "--tiles notaurl: unknown tile source")
    assert not (tmp_path / "f").exists()
    res = cli("figures", run, "--config", "paper", "--set", "output.tile_source=http://127.0.0.1:9/{z}/{x}/{y}.png",
              "--set", "output.tile_timeout_s=0.5", "--out", tmp_path / "f")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "f" / "fig06_cluster_fusion.png").exists()


def test_a_yaml_file_with_a_nul_byte_is_one_line(tmp_path, segments_csv):
    (tmp_path / "nul.yaml").write_bytes(b"fusion:\x00\n")
    res = cli("fuse", segments_csv, "--config", tmp_path / "nul.yaml", "--out", tmp_path / "o")
    one_line_error(res, "not valid YAML")
    assert len([line for line in res.output.splitlines() if line.strip()]) == 1, res.output


def test_an_interrupted_simulation_leaves_no_folders(tmp_path):
    """Ctrl-C while ray casting (after the drive's folders were made): no partial drive, no empty folders."""
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import simulate_drive
    from featmap.simulation.worlds import load_world

    def interrupted(frames, n):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        simulate_drive(load_world("prescan_case1"), tmp_path / "sim", SENSORS["hdl64"], 3, progress=interrupted)
    assert not (tmp_path / "sim").exists()


def _line_map(path, frame: GeoFrame):
    """A one-segment map (GeoJSON, WGS84) 10 m east of ``frame``'s origin."""
    lat, lon = frame.to_wgs84([0.0, 10.0], [0.0, 0.0])
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {},
        "geometry": {"type": "LineString", "coordinates": [[float(lon[0]), float(lat[0])], [float(lon[1]), float(lat[1])]]}}]}))
    return path


@pytest.mark.parametrize("edit,needle", [
    (lambda sim: sim.pop("geo_origin"), "simulation.json: missing or malformed 'geo_origin'"),
    (lambda sim: sim.update(geo_origin=None), "simulation.json: missing or malformed 'geo_origin'"),
    (lambda sim: sim.update(geo_origin={"lat": 49.0, "lon": 8.4}), "simulation.json: missing or malformed 'geo_origin'"),
    (lambda sim: sim.update(geo_origin={"lat0_deg": "49", "lon0_deg": 8.4}), "simulation.json: malformed 'geo_origin' "
                                                                                "(geo origin lat0_deg '49' is not a number)"),
    (lambda sim: sim.update(geo_origin={"lat0_deg": 95, "lon0_deg": 8.4}), "simulation.json: malformed 'geo_origin' "
                                                                              "(geo origin latitude 95 is outside"),
    (lambda sim: sim["geo_origin"].update(lat0_deg=math.nan), "simulation.json: not valid JSON (NaN is not a finite number)"),
])
def test_evaluate_against_a_truth_folder_with_a_bad_geo_origin(case1_drive, tmp_path, edit, needle):
    truth = shutil.copytree(case1_drive.drive_dir / "truth", tmp_path / "truth")
    sim = json.loads((truth / "simulation.json").read_text())
    fused = _line_map(tmp_path / "map.geojson", GeoFrame(**sim["geo_origin"]))
    assert cli("evaluate", fused, "--truth", truth).exit_code == 0              # the intact folder scores
    edit(sim)
    (truth / "simulation.json").write_text(json.dumps(sim))
    one_line_error(cli("evaluate", fused, "--truth", truth), needle)
    (tmp_path / "fused_proposed.csv").write_text("x1,y1,x2,y2,support\n0,0,10,0,3\n")
    one_line_error(cli("evaluate", tmp_path / "fused_proposed.csv", "--truth", truth, "--origin", "49.0,8.4"), needle)


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_json_inputs_with_non_finite_numbers_are_one_line(tmp_path, constant):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text(f'{{"schema_version": 2, "geo_frame": {{"lat0_deg": {constant}, "lon0_deg": 8.4}}}}')
    needle = f"metrics.json: not valid JSON ({constant} is not a finite number)"
    one_line_error(cli("compare", run), needle)
    one_line_error(cli("figures", run, "--out", tmp_path / "f"), needle)
    assert not (tmp_path / "f").exists()
    footprints = _line_map(tmp_path / "fp.geojson", GeoFrame(49.0, 8.4))
    (run / "fused_proposed.csv").write_text("x1,y1,x2,y2,support\n0,0,10,0,3\n")     # its frame: from metrics.json
    one_line_error(cli("evaluate", run / "fused_proposed.csv", "--truth", footprints, "--out", tmp_path / "m.json"), needle)
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("args,needle", [
    ((math.nan, 8.4), "lat0_deg nan is not a finite number"),
    ((49.0, math.inf), "lon0_deg inf is not a finite number"),
    ((49.0, 8.4, -math.inf), "alt0_m -inf is not a finite number"),
    (("49", 8.4), "lat0_deg '49' is not a number"),
    ((True, 8.4), "lat0_deg True is not a number"),
    ((90.0, 8.4), "latitude 90 is outside -90 < lat < 90 degrees"),
    ((49.0, -180.5), "longitude -180.5 is outside -180 <= lon <= 180 degrees"),
])
def test_a_geo_frame_off_the_earth_is_refused(args, needle):
    with pytest.raises(ConfigError, match=f"^geo origin {needle}"):
        GeoFrame(*args)
    assert GeoFrame(np.float64(-89.9), np.float32(180.0), -10).lon0_deg == 180.0      # numpy and the range's edges


@pytest.mark.parametrize("lat,lon", [(95.0, 8.4), (-90.0, 8.4), (49.0, 180.5), (math.nan, 8.4), (49.0, math.inf)])
def test_a_metrics_files_geo_frame_is_checked_where_it_is_read(lat, lon):
    """metrics.json's geo_frame record has GeoFrame's checks, so a bad one fails validation, which
    read_run_metrics reports naming the file (as for every invalid record), not later in GeoFrame."""
    from pydantic import ValidationError

    from featmap.io.run_metrics import GeoRecord

    with pytest.raises(ValidationError, match="lat0_deg|lon0_deg"):
        GeoRecord(lat0_deg=lat, lon0_deg=lon)


def test_a_drive_whose_camera_calibration_is_all_zero_maps_without_warnings(drive_copy, tmp_path):
    # featmap uses no camera; pykitti divides by the rectified projections and numpy printed four warnings
    root, drive = drive_copy
    calib = root / drive[:10] / "calib_cam_to_cam.txt"
    calib.write_text("".join(f"{line.split(':')[0]}: {' '.join(['0'] * len(line.split(':')[1].split()))}\n"
                             if line.startswith(("P_rect_", "R_rect_")) else line + "\n"
                             for line in calib.read_text().splitlines()))
    res = cli(*run_args(SimpleNamespace(drive=drive, root=root), tmp_path / "r", tmp_path / "c",
                        "--frames", "0:3", "--method", "proposed"))
    assert res.exit_code == 0, res.output
    assert "RuntimeWarning" not in res.output
