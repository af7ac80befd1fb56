"""Tile overlays against a tile server on 127.0.0.1, the fallback without it, and every figure."""

import io
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from featmap.geo import GeoFrame
from featmap.plotting.basemap import BasemapWarning, Tiles, add_basemap


class TileHandler(BaseHTTPRequestHandler):
    requests: list = []

    def log_message(self, *args):
        pass

    def do_GET(self):
        from PIL import Image

        TileHandler.requests.append(self.path)
        buf = io.BytesIO()
        Image.new("RGB", (256, 256), (30, 160, 60)).save(buf, format="PNG")
        data = buf.getvalue()
        self.send_response(200)
        self.send_header("Content-Type", "image/png")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)


@pytest.fixture
def tile_server():
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), TileHandler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    TileHandler.requests.clear()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/{{z}}/{{x}}/{{y}}.png"
    httpd.shutdown()


def _axes():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.set_xlim(-50, 50)
    ax.set_ylim(-50, 50)
    return fig, ax


def test_tiles_come_from_the_local_server_and_land_in_place(tile_server, tmp_path):
    fig, ax = _axes()
    assert add_basemap(ax, GeoFrame(49.011, 8.424), Tiles(tile_server, str(tmp_path / "tiles"), 5))
    assert TileHandler.requests and all(r.endswith(".png") for r in TileHandler.requests)
    assert len(ax.images) == 1
    left, right, bottom, top = ax.images[0].get_extent()
    assert left <= -50 and right >= 50 and bottom <= -50 and top >= 50      # tiles cover the view
    assert ax.get_xlim() == (-50, 50)
    # the cache serves the second plot without asking the server again
    n = len(TileHandler.requests)
    fig2, ax2 = _axes()
    assert add_basemap(ax2, GeoFrame(49.011, 8.424), Tiles(tile_server, str(tmp_path / "tiles"), 5))
    assert len(TileHandler.requests) == n


def test_unreachable_tiles_warn_and_the_plot_goes_on():
    fig, ax = _axes()
    with pytest.warns(BasemapWarning, match="basemap unavailable"):
        assert not add_basemap(ax, GeoFrame(49.011, 8.424), Tiles("http://127.0.0.1:9/{z}/{x}/{y}.png", None, 1))
    assert len(ax.images) == 0


def test_figures_of_a_small_run(case1_drive, tmp_path, tile_server):
    from PIL import Image
    from typer.testing import CliRunner

    from featmap.cli import app
    from featmap.datasets import KittiRawDataset
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config

    ds = KittiRawDataset(case1_drive.root, case1_drive.drive)
    cfg = load_config(None, [f"output.tile_source={tile_server}", f"output.tile_cache_dir={tmp_path / 'tiles'}"])
    MappingPipeline(cfg, ["proposed", "meanshift", "density"], SegmentStore(tmp_path / "c")).run(ds, tmp_path / "run")
    for name in ("map.kml", "map.html", "map_overview.png", "segments.geojson", "trajectory.geojson", "truth.geojson"):
        assert (tmp_path / "run" / name).stat().st_size > 100, name
    res = CliRunner().invoke(app, ["figures", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    out = tmp_path / "run" / "figures"
    expected = {"fig02_feature_circles_one_scan.png": (1000, 800), "fig03_feature_circles_two_scans.png": (1000, 800),
                "fig06_cluster_fusion.png": (1000, 800), "fig07_corner_optimisation.png": (1400, 700),
                "fig08_global_map.png": (1600, 800), "fig09_local_maps_3d.png": None, "fig10_local_maps_2d.png": None,
                "fig11_local_maps_tiles.png": (1300, 1300), "fig13_14_truth_vs_fused.png": (1600, 900)}
    for name, size in expected.items():
        img = Image.open(out / name)
        assert img.size[0] > 500 and img.size[1] > 400, name
        if size:
            assert img.size == size, name
        assert np.asarray(img.convert("L")).std() > 5, f"{name} looks blank"
    counts = (out / "fig10_counts.csv").read_text().splitlines()
    assert counts[0] == "map,proposed,meanshift,density" and counts[-1].startswith("global map,")
    # Tables 1-3 are the run's comparison: counts, vertex error sums of the labelled vertices, times
    comparison = (tmp_path / "run" / "comparison.md").read_text()
    assert "vertex_a_m" in comparison and "seconds" in comparison and "| proposed |" in comparison
    assert any("/" in r for r in TileHandler.requests)          # Fig. 11 used the local tile server


def test_figures_without_tiles_still_appear(case1_drive, tmp_path):
    from featmap.datasets import KittiRawDataset
    from featmap.fusion import fuse
    from featmap.outputs import tiles_of
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config
    from featmap.pipeline.run_folder import load_run
    from featmap.plotting.figures import FigureInputs, fig_tile_overlays, local_map_centres

    ds = KittiRawDataset(case1_drive.root, case1_drive.drive, slice(0, 20))
    cfg = load_config(None, ["output.tile_source=http://127.0.0.1:9/{z}/{x}/{y}.png", "output.tile_timeout_s=1"])
    with pytest.warns(BasemapWarning):
        MappingPipeline(cfg, ["proposed"], SegmentStore(tmp_path / "c")).run(ds, tmp_path / "run")
    run = load_run(tmp_path / "run")
    inputs = FigureInputs(run.segments, ["proposed"], run.config.fusion, run.trajectory, run.frame, run.truth,
                          tiles_of(run.config.output))
    results = {"proposed": fuse("proposed", run.segments.segments, run.segments.scan, run.config.fusion)}
    with pytest.warns(BasemapWarning):
        path = fig_tile_overlays(inputs, results, local_map_centres(inputs, results), tmp_path)
    assert path.stat().st_size > 10_000


@pytest.mark.parametrize("frames", [slice(0, 3), slice(38, 40)])
def test_figures_of_runs_with_few_scans_or_no_segments(case1_drive, tmp_path, frames):
    """Fewer scans than local maps (3 scans), and a run without a single segment (an extraction that asks
    for more returns than any wall has): every figure is still drawn (empty where there is nothing)."""
    from typer.testing import CliRunner

    from featmap.cli import app
    from featmap.datasets import KittiRawDataset
    from featmap.io.segments_csv import read_segments_csv
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config

    ds = KittiRawDataset(case1_drive.root, case1_drive.drive, frames)
    cfg = load_config(None, ["output.tile_source=http://127.0.0.1:9/{z}/{x}/{y}.png", "output.tile_timeout_s=1",
                             "extraction.vertical_structure.min_points=100000"] if frames.start else
                      ["output.tile_source=http://127.0.0.1:9/{z}/{x}/{y}.png", "output.tile_timeout_s=1"])
    with pytest.warns(BasemapWarning):
        MappingPipeline(cfg, ["proposed", "density"], SegmentStore(tmp_path / "c")).run(ds, tmp_path / "run")
    if frames.start:
        assert len(read_segments_csv(tmp_path / "run" / "segments.csv")) == 0
    res = CliRunner().invoke(app, ["figures", str(tmp_path / "run"), "--set", "output.tile_timeout_s=1"])
    assert res.exit_code == 0, res.output
    out = tmp_path / "run" / "figures"
    for name in ("fig02_feature_circles_one_scan.png", "fig08_global_map.png", "fig10_local_maps_2d.png",
                 "fig13_14_truth_vs_fused.png"):
        assert (out / name).stat().st_size > 5000, name


def test_the_basemap_warning_keeps_the_gist_of_a_long_error():
    from featmap.plotting.basemap import _short

    long = ("HTTPSConnectionPool(host='tile.example.org', port=443): Max retries exceeded with url: /18/1/2.png "
            "(Caused by NameResolutionError(\"<urllib3.connection.HTTPSConnection object>: Failed to resolve\"))")
    assert _short(RuntimeError(long)) == ("HTTPSConnectionPool(host='tile.example.org', port=443): Max retries "
                                          "exceeded with url: /18/1/2.png")
    assert _short(RuntimeError("word " * 60)).endswith("word ...")


def _small_run(monkeypatch, drawn: list):
    """Three walls seen from six scans, with a ground truth; the figures are drawn, not rendered (fast): each
    figure file holds ``png <n>``, n the number of ``make_figures`` calls begun (``drawn`` lists the names)."""
    from matplotlib.figure import Figure

    import featmap.plotting.figures as figures
    from featmap.evaluation.truth_metrics import GroundTruth
    from featmap.io.atomic import atomic_write_bytes
    from featmap.io.segments_csv import SegmentTable
    from featmap.pipeline import load_config
    from featmap.plotting.figures import FigureInputs
    from featmap.simulation.segments import observe_walls

    calls = []
    make = figures.make_figures

    def counted(*args, **kwargs):
        calls.append(1)
        return make(*args, **kwargs)

    def save_png(fig, path):
        import matplotlib.pyplot as plt

        plt.close(fig)
        drawn.append(path.name)
        return atomic_write_bytes(path, f"png {len(calls)}".encode())

    monkeypatch.setattr(figures, "make_figures", counted)
    monkeypatch.setattr(figures, "save_png", save_png)
    monkeypatch.setattr(Figure, "tight_layout", lambda self, *args, **kwargs: None)
    walls = np.array([[0, 0, 20, 0], [20, 0, 20, 12], [20, 12, 0, 12]], float)
    segs, scan = observe_walls(walls, 6, 0.03, np.random.default_rng(0), first_scan=np.zeros(3, int))
    truth = GroundTruth(walls, np.zeros(3, int), np.array([["a", "b"], ["b", "c"], ["c", "d"]]),
                        [[(0.0, 20.0)], [(0.0, 12.0)], [(0.0, 20.0)]], np.full(3, 100))
    trajectory = np.column_stack([np.linspace(2, 18, 6), np.full(6, 6.0)])
    return FigureInputs(SegmentTable(scan=scan, segments=segs), ["proposed"], load_config(None).fusion,
                        trajectory, None, truth, Tiles(cache_dir=None))


def test_figures_again_into_the_same_folder_leave_none_of_the_earlier_call(tmp_path, monkeypatch):
    """A second ``make_figures`` that makes fewer figures (no proposed method: no Figs. 6-7; no truth: no
    Figs. 13-14) removes the earlier call's, and only featmap's figure names: a user's files stay."""
    from dataclasses import replace

    import featmap.plotting.figures as figures
    from featmap.plotting.figures import FIGURE_FILES

    run = _small_run(monkeypatch, [])
    out = tmp_path / "figures"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "fig99_my_own.png").write_bytes(b"x")
    assert {p.name for p in figures.make_figures(run, out)} == set(FIGURE_FILES)
    second = {p.name for p in figures.make_figures(replace(run, methods=["density"], truth=None), out)}
    assert {"fig06_cluster_fusion.png", "fig07_corner_optimisation.png", "fig13_14_truth_vs_fused.png"}.isdisjoint(second)
    assert sorted(p.name for p in out.iterdir()) == sorted(second | {"notes.txt", "fig99_my_own.png"})
    assert (out / "notes.txt").read_text() == "mine" and (out / "fig99_my_own.png").read_bytes() == b"x"
    assert (out / "fig10_counts.csv").read_text().splitlines()[0] == "map,density"


@pytest.mark.parametrize("error", [RuntimeError("no tiles today"), KeyboardInterrupt()])
def test_figures_that_fail_half_way_leave_the_earlier_calls_figures_whole(tmp_path, monkeypatch, error):
    """An error or Ctrl-C while drawing (here in Fig. 11, after Figs. 2-10 were drawn) leaves the folder as the
    earlier call left it: all of its figures, byte for byte, none of the new call's, and no staging folder."""
    from dataclasses import replace

    import featmap.plotting.figures as figures
    from featmap.plotting.figures import FIGURE_FILES

    drawn = []
    run = _small_run(monkeypatch, drawn)
    out = tmp_path / "figures"
    paths = figures.make_figures(run, out)
    assert sorted(paths) == sorted(out / name for name in FIGURE_FILES)
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert before["fig02_feature_circles_one_scan.png"] == b"png 1"

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(figures, "fig_tile_overlays", fail)
    drawn.clear()
    with pytest.raises(type(error)):
        figures.make_figures(replace(run, methods=["density"]), out)
    assert "fig10_local_maps_2d.png" in drawn                    # the second call drew figures before it failed
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
