"""The ``featmap`` command line: one thin function per command.

Commands only parse flags, build the pieces and call into the library; heavy libraries (Open3D,
pykitti, matplotlib, scikit-learn) are imported inside the commands so ``featmap --help`` is instant.
Known errors (:class:`featmap.errors.FeatmapError`) print as one line and exit with status 2.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import List, Optional

import typer

from featmap.errors import FeatmapError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Fuse redundant wall features from LiDAR drives into a compact, accurate line map.")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config (defaults < this file < --set).",
                         exists=False, dir_okay=False)
SetOpt = typer.Option(None, "--set", help="Override one config key, e.g. --set fusion.proposed.delta_deg=5 (repeatable).")
MethodOpt = typer.Option("all", "--method", "-m", help="proposed, meanshift, density, a comma list, or all.")


@app.callback()
def _root() -> None:
    """featmap: one clean line segment per building face."""


def _fail(message: str) -> None:
    typer.echo(f"featmap: error: {message}", err=True)
    raise typer.Exit(code=2)


def command(func):
    """Register ``func`` as a command that turns FeatmapError into a one-line message and exit code 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except FeatmapError as exc:
            _fail(str(exc))
        except KeyboardInterrupt:
            typer.echo("featmap: interrupted; finished files are complete, nothing half-written was kept.", err=True)
            raise typer.Exit(code=130)

    return app.command()(wrapper)


@command
def fuse(
    segments_csv: Path = typer.Argument(..., help="segments.csv with columns scan,x1,y1,x2,y2 (world frame, metres)."),
    method: str = MethodOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for fused_<method>.csv and config.yaml."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Fuse the segments of a segments.csv with one or more methods."""
    from featmap.config import load_config
    from featmap.fusion.registry import resolve_methods
    from featmap.io.segments_csv import read_segments_csv
    from featmap.pipeline import fuse_and_write

    cfg = load_config(config, set_ or [])
    methods = resolve_methods(method)
    table = read_segments_csv(segments_csv)
    fuse_and_write(table, methods, cfg, out)


def ensure_default_drive():
    """The embedded default drive (simulated on first use); see :mod:`featmap.simulation.default`."""
    from featmap.simulation.default import ensure_default_drive as ensure

    return ensure(echo=typer.echo)


@command
def run(
    drive: Optional[str] = typer.Option(None, "--drive", "-d", help="KITTI raw drive YYYY_MM_DD_drive_NNNN (default: the embedded simulated drive)."),
    data_dir: Path = typer.Option(Path("data/kitti"), "--data-dir", help="KITTI raw root holding YYYY_MM_DD/ folders."),
    frames: Optional[str] = typer.Option(None, "--frames", help="start:stop:step selection of frames."),
    method: str = MethodOpt,
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Run folder (default: runs/<drive>)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    workers: int = typer.Option(2, "--workers", "-j", min=1, help="Extraction processes."),
    cache_dir: Path = typer.Option(Path("data/cache"), "--cache-dir", help="Per-drive cache of extracted segments."),
    skip_bad_scans: bool = typer.Option(False, "--skip-bad-scans", help="Skip unreadable scans instead of failing."),
):
    """Turn a LiDAR drive into fused wall maps (the embedded simulated drive when --drive is not given)."""
    from featmap.config import load_config
    from featmap.datasets import KittiRawDataset, parse_frames
    from featmap.fusion.registry import resolve_methods
    from featmap.pipeline import MappingPipeline

    cfg = load_config(config, set_ or [])
    methods = resolve_methods(method)
    selection = parse_frames(frames)
    if drive is None:
        data_dir, drive = ensure_default_drive()
        default_out = Path("runs") / "residential"
    else:
        default_out = Path("runs") / drive
    dataset = KittiRawDataset(data_dir, drive, selection, skip_bad_scans=skip_bad_scans)
    MappingPipeline(dataset, cfg, out or default_out, methods, workers=workers, cache_dir=cache_dir,
                    skip_bad_scans=skip_bad_scans).run()


@command
def sweep(
    sweep_file: Path = typer.Argument(..., help="Sweep YAML (base, input or drive, methods, grid, samples)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default: runs/sweeps/<file stem>)."),
    workers: int = typer.Option(2, "--workers", "-j", min=1, help="Processes evaluating combinations."),
):
    """Sweep fusion parameters on cached segments: sweep.csv, heatmaps, curves, Pareto plot, best.yaml."""
    from rich.console import Console
    from rich.table import Table

    from featmap.progress import track
    from featmap.sweep import load_sweep, run_sweep_file

    spec = load_sweep(sweep_file)
    out = out or Path("runs") / "sweeps" / Path(sweep_file).stem
    rows, best = run_sweep_file(sweep_file, out, workers, progress=lambda it, n: track(it, n, "sweeping"))
    table = Table(title=f"featmap sweep: {len(rows)} combinations")
    for col in ("method", "combinations", "best " + spec.select.metric, "count at best"):
        table.add_column(col, justify="right")
    for method in spec.methods:
        sub = [r for r in rows if r["method"] == method and r.get(spec.select.metric) is not None]
        if sub:
            b = (max if spec.select.goal == "max" else min)(sub, key=lambda r: r[spec.select.metric])
            table.add_row(method, str(len(sub)), f"{b[spec.select.metric]:.4f}", str(b["count"]))
        else:
            table.add_row(method, str(len([r for r in rows if r["method"] == method])), "-", "-")
    Console().print(table)
    typer.echo(f"wrote sweep.csv, plots{', best.yaml' if best else ''} to {out}")


@command
def figures(
    run_dir: Path = typer.Argument(..., help="A featmap run folder."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default: RUN_DIR/figures)."),
    tiles: Optional[str] = typer.Option(None, "--tiles", help="Tile source for Fig. 11: xyzservices name or {z}/{x}/{y} URL."),
):
    """Write the paper's figures (2-3, 6-11, 13-14) and Tables 1-3 for one run."""
    from featmap.io.run_folder import load_run
    from featmap.plotting.figures import make_figures

    run_data = load_run(run_dir)
    if tiles is not None:
        import dataclasses

        cfg = run_data.config.model_copy(update={"output": run_data.config.output.model_copy(update={"tile_source": tiles})})
        run_data = dataclasses.replace(run_data, config=cfg)
    paths = make_figures(run_data, out or Path(run_dir) / "figures")
    for p in paths:
        typer.echo(f"wrote {p}")


@command
def compare(run_dir: Path = typer.Argument(..., help="A featmap run folder (with metrics.json).")):
    """Write comparison.csv and comparison.md (the paper's Tables 1-3 for one run) and print them."""
    from featmap.compare import write_comparison

    _, md = write_comparison(run_dir)
    typer.echo(md)
    typer.echo(f"wrote {run_dir / 'comparison.csv'} and {run_dir / 'comparison.md'}")


@command
def download(
    drive: str = typer.Option(..., "--drive", "-d", help="KITTI raw drive YYYY_MM_DD_drive_NNNN."),
    data_dir: Path = typer.Option(Path("data/kitti"), "--data-dir", help="KITTI raw root to unpack into."),
    base_url: str = typer.Option("https://s3.eu-central-1.amazonaws.com/avg-kitti/raw_data", "--base-url",
                                 help="Server holding <drive>/<drive>_sync.zip and <date>_calib.zip."),
    keep_zips: bool = typer.Option(False, "--keep-zips", help="Keep the downloaded zips in DATA_DIR/zips."),
):
    """Download a KITTI raw drive and its calibration (resumable, verified) into the raw layout."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

    from featmap.datasets.kitti_raw import parse_drive
    from featmap.download import download_drive

    parse_drive(drive)
    with Progress(TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn()) as bar:
        def factory(name):
            task = bar.add_task(name, total=None)
            return lambda done, total: bar.update(task, completed=done, total=total)

        download_drive(drive, data_dir, base_url, factory, keep_zips)
    typer.echo(f"unpacked {drive} into {data_dir}; run it with: featmap run --drive {drive} --data-dir {data_dir}")


@command
def evaluate(
    fused: Path = typer.Argument(..., help="fused_<method>.csv (local frame, next to its metrics.json) or .geojson (WGS84)."),
    truth: Path = typer.Option(..., "--truth", "-t", help="Building footprints (.geojson, WGS84) or a simulated drive's truth/ folder."),
    origin: Optional[str] = typer.Option(None, "--origin", help="LAT,LON of the local frame of a CSV (default: its run's metrics.json)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Also write the metrics to this JSON file."),
):
    """Score any fused map against ground-truth footprints (the metrics of EVALUATION.md)."""
    import json

    from featmap.evaluate_cli import evaluate_file

    metrics = evaluate_file(fused, truth, origin)
    if out is not None:
        from featmap.io.atomic import atomic_write_text

        atomic_write_text(out, json.dumps(metrics, indent=1))
    for key, value in metrics.items():
        typer.echo(f"{key:>20s}  {value}")


def _parse_pose_noise(text: str) -> tuple[float, float]:
    try:
        pos, yaw = (float(v) for v in text.split(","))
    except ValueError:
        _fail(f"--pose-noise {text!r}: expected POS_M,YAW_DEG, e.g. 0.1,0.2")
    return pos, yaw


@command
def simulate(
    world: str = typer.Option("residential", "--world", "-w", help="Built-in world name or a .yaml/.geojson world file."),
    out: Path = typer.Option(..., "--out", "-o", help="KITTI raw root to write the drive into."),
    frames: Optional[int] = typer.Option(None, "--frames", "-n", min=2, help="Number of frames (default: the whole route)."),
    sensor: str = typer.Option("hdl64", "--sensor", help="hdl64 (KITTI), vlp32 (the paper's PreScan sensor), vls128 or vlp16."),
    noise: float = typer.Option(0.02, "--noise", min=0.0, help="Gaussian range noise sigma, metres."),
    pose_noise: str = typer.Option("0,0", "--pose-noise", help="OXTS pose error: position sigma (m), yaw sigma (deg)."),
    dropout: float = typer.Option(0.0, "--dropout", min=0.0, max=0.99, help="Probability that a return is lost."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, byte-identical drive)."),
    drive_id: str = typer.Option("0001", "--drive-id", help="Four-digit drive number of the written drive."),
):
    """Ray-cast a LiDAR drive through a world and write it in the KITTI raw layout with ground truth."""
    import time

    from featmap.progress import track
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import simulate_drive
    from featmap.simulation.worlds import load_world

    if sensor not in SENSORS:
        _fail(f"--sensor {sensor!r}: allowed: {', '.join(SENSORS)}")
    if not (len(drive_id) == 4 and drive_id.isdigit()):
        _fail(f"--drive-id {drive_id!r}: expected four digits, e.g. 0001")
    w = load_world(world)
    start = time.perf_counter()
    drive = simulate_drive(w, out, SENSORS[sensor], frames, noise, dropout, _parse_pose_noise(pose_noise), seed,
                           drive_id, progress=lambda it, n: track(it, n, f"simulating {w.name}"))
    seconds = time.perf_counter() - start
    typer.echo(f"wrote {drive.n_frames} frames of {w.name} ({sensor}) to {drive.drive_dir} "
               f"in {seconds:.1f} s ({drive.n_frames / seconds:.1f} frames/s); ground truth in "
               f"{drive.drive_dir / 'truth'}; run it with: featmap run --drive {drive.drive} --data-dir {out}")


def main() -> None:
    import warnings

    _format = warnings.formatwarning

    def one_line(message, category, filename, lineno, line=None):
        # featmap's own warnings (e.g. unreachable map tiles) are messages for users, not code locations
        if category.__module__.startswith("featmap"):
            return f"featmap: warning: {message}\n"
        return _format(message, category, filename, lineno, line)

    warnings.formatwarning = one_line
    app(prog_name="featmap")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
