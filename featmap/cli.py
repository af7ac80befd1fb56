"""The ``featmap`` command line: one thin function per command.

Commands only parse flags, build the pieces (config, scan source, segment store, executor, reporter)
and call into the library; heavy libraries (Open3D, pykitti, matplotlib, scikit-learn) are imported
inside the commands so ``featmap --help`` is instant. Known errors (:class:`featmap.errors.FeatmapError`)
and errors of the environment (``OSError``: a full disk, a read-only folder) print as one line naming the
file and exit with status 2.
"""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import sys
import warnings
from pathlib import Path
from typing import List, Optional

import typer
from typer.core import TyperGroup

from featmap.errors import FeatmapError

class _OneLineErrors(TyperGroup):
    """A bad flag or value is one line (``featmap: error: ...``, naming the flag) and exit status 2, like every
    other known error, instead of Click's usage box."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        import typer.core

        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        # (typer >= 0.20 carries its own copy of Click; older versions use Click itself)
        errors = (getattr(typer.core, "_click", None) or typer.core.click).exceptions
        abort = getattr(typer.core, "Abort", None) or errors.Abort
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except errors.NoArgsIsHelpError as exc:              # plain `featmap`: the help
            exc.show()
            sys.exit(exc.exit_code)
        except errors.ClickException as exc:
            message = " ".join(exc.format_message().split())
            typer.echo(f"featmap: error: {message}", err=True)
            sys.exit(2 if isinstance(exc, errors.UsageError) else exc.exit_code)
        except abort:
            typer.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(cls=_OneLineErrors, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Fuse redundant wall features from LiDAR drives into a compact, accurate line map.")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config (defaults < this file < --set).",
                         exists=False, dir_okay=False)
SetOpt = typer.Option(None, "--set", help="Override one config key, e.g. --set fusion.proposed.delta_deg=5 (repeatable).")
MethodOpt = typer.Option("all", "--method", "-m", help="proposed, meanshift, density, a comma list, or all.")
WorkersOpt = typer.Option(2, "--workers", "-j", min=1, help="Local worker processes.")
CacheOpt = typer.Option(Path("data/cache"), "--cache-dir", help="Content-keyed cache of extracted segments.")


@app.callback()
def _root() -> None:
    """featmap: one clean line segment per building face."""


def _fail(message: str) -> None:
    typer.echo(f"featmap: error: {message}", err=True)
    raise typer.Exit(code=2)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """featmap's own warnings (e.g. unreachable map tiles) are messages for users: one line each."""
    if category.__module__.startswith("featmap"):
        print(f"featmap: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


def _stdout_is_broken() -> bool:
    """Standard output is a pipe whose reader has gone (poll reports an error on its write end)."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):      # no real file behind stdout (e.g. captured in tests)
        return False


def _quiet_stdout() -> None:
    """Point stdout at /dev/null so that flushing it at exit does not raise a second BrokenPipeError."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


@contextlib.contextmanager
def _ctrl_c_never_dropped():
    """Inside the block, a Ctrl-C that Python would drop is raised again where it can propagate.

    Python prints an exception raised in a garbage collector callback or a ``__del__`` method ("Exception
    ignored in ...") and goes on. Dask's scheduler, which runs in a batch's own process, hooks a function into
    every garbage collection, so a Ctrl-C that arrived while it ran was lost: the batch printed a
    KeyboardInterrupt traceback and ran to its end (1 in about 60 Ctrl-Cs under load). Such a
    KeyboardInterrupt is now sent again to the main thread as a real SIGINT 10 ms later, from a timer (sent at
    once, it would land in the hook itself and be dropped again; a real signal, unlike
    ``_thread.interrupt_main``, also wakes a main thread blocked in a wait); should it land in a callback
    again, it comes back here. Other unraisable exceptions go to the hook there was before.
    """
    import threading

    previous = sys.unraisablehook
    main = threading.main_thread().ident

    def hook(unraisable) -> None:
        if issubclass(unraisable.exc_type, KeyboardInterrupt):
            again = threading.Timer(0.01, signal.pthread_kill, (main, signal.SIGINT))
            again.daemon = True
            again.start()
        else:
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


def _forget_interrupted_string_eval() -> None:
    """Clear CPython's mark of a KeyboardInterrupt that ended a string ``exec``/``eval``.

    CPython sets that mark when a string eval (a dataclass's or namedtuple's generated methods, say) ends
    with a KeyboardInterrupt, even one caught later, and under ``python -m`` exits by SIGINT at the end,
    whatever exit code was asked for (exit status -2 instead of 130: 2 of 45 Ctrl-Cs of a batch under load
    on 2026-12-06). Each string eval clears the mark as it starts: this one does nothing else.
    """
    exec("pass", {})


def command(func):
    """Register ``func`` as a command that turns FeatmapError into a one-line message and exit code 2, and
    a Ctrl-C into one line and exit code 130 (never dropped: :func:`_ctrl_c_never_dropped`)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            with warnings.catch_warnings(), _ctrl_c_never_dropped():
                warnings.showwarning = _show_warning
                return func(*args, **kwargs)
        except FeatmapError as exc:
            _fail(str(exc))
        except BrokenPipeError as exc:
            if _stdout_is_broken():    # `featmap config | head`: the reader has gone; stop quietly, as Unix tools do
                _quiet_stdout()
                raise typer.Exit(code=141)
            _fail(f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc.strerror or exc))
        except OSError as exc:     # the environment, not a bug: a full disk, a read-only folder, a vanished file
            where = f"{exc.filename}: " if exc.filename else ""
            _fail(f"{where}{exc.strerror or exc}")
        except KeyboardInterrupt:
            _forget_interrupted_string_eval()
            typer.echo("featmap: interrupted; finished files are complete, nothing half-written was kept.", err=True)
            raise typer.Exit(code=130)

    return app.command()(wrapper)


def _reporter():
    from featmap.console import RichReporter

    return RichReporter()


@command
def fuse(
    segments_csv: Path = typer.Argument(..., help="segments.csv with columns scan,x1,y1,x2,y2 (world frame, metres)."),
    method: str = MethodOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for fused_<method>.csv, config.yaml and fuse.json (replaced whole)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Fuse the segments of a segments.csv with one or more methods."""
    from featmap.fusion import resolve_methods
    from featmap.io.segments_csv import read_segments_csv
    from featmap.pipeline.config import load_config
    from featmap.pipeline.fuse import fuse_and_write

    cfg = load_config(config, set_ or [])
    methods = resolve_methods(method)
    table = read_segments_csv(segments_csv)
    fuse_and_write(table, methods, cfg, out, _reporter(), source=segments_csv)


def source_spec(drive: str | None, data_dir: Path | None, world: str | None, dataset: str | None, source: str | None,
                carmen: Path | None, frames: str | None, skip_bad_scans: bool):
    """The scan source the flags of ``featmap run`` name (the embedded simulated drive by default)."""
    from featmap.datasets import SourceSpec
    from featmap.datasets.kitti_raw import drive_folder

    empty = [flag for flag, value in (("--drive", drive), ("--world", world), ("--dataset", dataset),
                                      ("--source", source)) if value is not None and not value.strip()]
    if empty:
        _fail(f"{empty[0]} '': give a value (leave the flag out for the default)")
    given = [flag for flag, value in (("--drive", drive), ("--world", world), ("--dataset", dataset),
                                      ("--carmen", carmen)) if value]
    if len(given) > 1:
        _fail(f"{' and '.join(given)}: give one source")
    if data_dir is not None and drive is None:
        _fail(f"--data-dir {data_dir}: give --drive YYYY_MM_DD_drive_NNNN with it (it is where KITTI drives are)")
    if carmen is not None:
        return SourceSpec("carmen", str(carmen), frames, skip_bad_scans)
    if dataset is not None:
        if source is None:
            _fail(f"--dataset {dataset}: give its --source LOCATION")
        return SourceSpec(dataset, source, frames, skip_bad_scans)
    if source is not None:
        _fail("--source: give --dataset NAME with it")
    if drive is not None:
        return SourceSpec("kitti_raw", str(drive_folder(data_dir or Path("data/kitti"), drive)), frames, skip_bad_scans)
    return SourceSpec("simulated", world or "residential", frames, skip_bad_scans)


@command
def run(
    drive: Optional[str] = typer.Option(None, "--drive", "-d", help="KITTI raw drive YYYY_MM_DD_drive_NNNN (with --data-dir)."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="KITTI raw root holding YYYY_MM_DD/ folders (with --drive; default data/kitti)."),
    world: Optional[str] = typer.Option(None, "--world", "-w", help="A simulated world (built-in name or file), simulated on first use; the default is residential."),
    dataset: Optional[str] = typer.Option(None, "--dataset", help="Any registered scan format (see featmap datasets), with --source."),
    source: Optional[str] = typer.Option(None, "--source", help="Location of the --dataset source (a folder or file)."),
    carmen: Optional[Path] = typer.Option(None, "--carmen", help="A CARMEN 2D laser log (.log, .log.gz, .clf, .clf.bz2); uses the indoor_2d preset unless --config is given."),
    frames: Optional[str] = typer.Option(None, "--frames", help="start:stop:step selection of frames."),
    method: str = MethodOpt,
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Run folder (default: runs/<source name>)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    workers: int = WorkersOpt,
    cache_dir: Path = CacheOpt,
    skip_bad_scans: bool = typer.Option(False, "--skip-bad-scans", help="Skip unreadable scans instead of failing."),
    online: Optional[int] = typer.Option(None, "--online", min=1, help="Map online: each scan extracted and fused as it comes (proposed method, poses corrected causally by fixed_lag, no cache), the map made every N scans; online.csv has each scan's times."),
):
    """Turn a scan source into fused wall maps (the embedded simulated drive when no source is given)."""
    from featmap.datasets import DATASETS, open_source
    from featmap.fusion import resolve_methods
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config, local_executor

    spec = source_spec(drive, data_dir, world, dataset, source, carmen, frames, skip_bad_scans)
    preset = DATASETS[spec.kind].preset if spec.kind in DATASETS and config is None else None
    reporter = _reporter()
    overrides = list(set_ or [])
    if online is not None:
        method = "proposed" if method == "all" else method      # the one method that fuses a scan at a time
        from featmap.config import apply_overrides
        from featmap.pipeline import FeatmapConfig
        from featmap.pipeline.online import ONLINE_REFINEMENT

        asked = apply_overrides({}, overrides, FeatmapConfig).get("refinement", {}).get("method")
        if asked is not None and asked not in ONLINE_REFINEMENT:
            _fail(f"--online corrects the poses causally (refinement.method=fixed_lag) or not at all (none), but --set "
                  f"asks for refinement.method={asked} (it needs the whole drive)")
    cfg = load_config(config or preset, overrides)
    if online is not None and cfg.refinement.method not in ONLINE_REFINEMENT:  # a whole-drive method: the causal one
        cfg = load_config(config or preset, overrides + [f"refinement.method={ONLINE_REFINEMENT[0]}"])
    if online is not None and cfg.refinement.method == "fixed_lag":
        reporter.info(f"--online: poses corrected causally (fixed_lag); each scan joins the map "
                      f"{cfg.refinement.fixed_lag.lag_scans} scans after it came")
    methods = resolve_methods(method)
    store = SegmentStore(cache_dir)
    if preset is not None:
        reporter.info(f"{spec.kind} source: using the {preset} preset (configs/{preset}.yaml); --config overrides it")
    scan_source = open_source(spec, reporter)
    with local_executor(workers) as executor:
        pipeline = MappingPipeline(cfg, methods, store, executor, reporter, skip_bad_scans, online_every=online)
        pipeline.run(scan_source, out or Path("runs") / scan_source.name)


def _point(text: str, flag: str) -> tuple[float, float]:
    """``X,Y`` as two finite numbers, or a one-line error naming ``flag``."""
    import math

    try:
        x, y = (float(v) for v in text.split(","))
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError
    except ValueError:
        _fail(f"{flag} {text!r}: expected X,Y in metres, e.g. {flag} 9.5,20.2")
    return x, y


@command
def explain(
    scan: Optional[Path] = typer.Argument(None, help="A KITTI velodyne .bin scan; or name a source with the flags of featmap run, and --frame."),
    frame: Optional[int] = typer.Option(None, "--frame", min=0, help="Which frame of the source (default 0, its first)."),
    at: Optional[str] = typer.Option(None, "--at", help="X,Y (velodyne frame, metres): list the pieces near this point, with the tests each fails."),
    radius: float = typer.Option(2.0, "--radius", min=0.0, help="... within this distance of it (metres)."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Also draw the scan's pieces, coloured by the first test each failed, into this PNG (around --at when given)."),
    drive: Optional[str] = typer.Option(None, "--drive", "-d", help="KITTI raw drive YYYY_MM_DD_drive_NNNN (with --data-dir)."),
    data_dir: Optional[Path] = typer.Option(None, "--data-dir", help="KITTI raw root holding YYYY_MM_DD/ folders (with --drive; default data/kitti)."),
    world: Optional[str] = typer.Option(None, "--world", "-w", help="A simulated world (built-in name or file); the default is residential."),
    dataset: Optional[str] = typer.Option(None, "--dataset", help="Any registered 3D scan format (see featmap datasets), with --source."),
    source: Optional[str] = typer.Option(None, "--source", help="Location of the --dataset source (a folder or file)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Why the wall extraction kept or dropped the pieces of one scan: the tests each piece fails (3D scans,
    extraction.method_3d vertical_structure)."""
    from featmap.extraction.explain import STAGES, explain_scan
    from featmap.pipeline import load_config

    point = None if at is None else _point(at, "--at")
    if plot is not None and plot.suffix.lower() != ".png":
        _fail(f"--plot {plot}: the drawing is a PNG; give a file name ending in .png")
    cfg = load_config(config, set_ or [])
    if cfg.extraction.method_3d != "vertical_structure":
        _fail(f"extraction.method_3d={cfg.extraction.method_3d}: explain names the tests of vertical_structure only")
    reporter = _reporter()
    if scan is not None:
        given = [flag for flag, value in (("--drive", drive), ("--data-dir", data_dir), ("--world", world),
                                          ("--dataset", dataset), ("--source", source), ("--frame", frame))
                 if value is not None]
        if given:
            _fail(f"{scan}: a scan file is one frame of no source; leave out {', '.join(given)}")
        from featmap.io.kitti_raw import read_velo_bin

        points, name = read_velo_bin(scan), str(scan)
    else:
        from featmap.datasets import open_source

        frame = frame or 0
        spec = source_spec(drive, data_dir, world, dataset, source, None, None, False)
        scan_source = open_source(spec, reporter)
        if scan_source.dimension != 3:
            _fail(f"{spec.location}: a {scan_source.dimension}D source; explain covers 3D scans")
        if frame >= len(scan_source):
            _fail(f"--frame {frame}: {scan_source.name} has {len(scan_source)} frames (0-{len(scan_source) - 1})")
        points, name = scan_source[frame].points, f"{scan_source.name} frame {frame}"
    explanation = explain_scan(points, cfg.extraction.vertical_structure)
    reporter.info(f"{name}: {len(points):,} points, {len(explanation.result)} wall segment(s)")
    if plot is not None:
        from featmap.plotting.explain import plot_explanation
        from featmap.plotting.style import new_figure, save_png

        half = None if point is None else max(2 * radius, 5.0)
        fig, ax = new_figure(size=(9, 7))
        plot_explanation(ax, points, explanation,
                         None if point is None else (point[0] - half, point[0] + half, point[1] - half, point[1] + half))
        ax.set_title(f"{name}: why each piece was kept or dropped", fontsize=8)
        reporter.info(f"wrote {save_png(fig, plot)}")
    if not explanation.stages:
        reporter.info("too few returns above the ground for any piece")
        return
    titles = {"height": "height tests, on the pieces of cells",
              "final": "final tests, on the returns of the pieces that passed the height tests"}
    if point is None:
        for stage in STAGES:
            kept = int(explanation.stages[stage].kept.sum())
            reporter.table(f"{titles[stage]}: {len(explanation.stages[stage].a)} piece(s), {kept} kept",
                           ["test", "pieces failing it"],
                           [[test, str(count)] for test, count in explanation.failure_counts(stage).items()])
        return
    near = explanation.near(point, radius)
    for stage in STAGES:
        rows = [[f"{v.distance_m:.2f}", f"{v.segment[0]:.2f}, {v.segment[1]:.2f}", f"{v.segment[2]:.2f}, {v.segment[3]:.2f}",
                 f"{v.length_m:.2f}", ", ".join(v.failed) or "nothing (kept)", v.measured_text()]
                for v in near if v.stage == stage]
        reporter.table(f"{titles[stage]}: {len(rows)} within {radius:g} m of {point[0]:g},{point[1]:g}",
                       ["distance m", "from", "to", "length m", "fails", "measured"], rows)


@command
def datasets():
    """List the scan formats featmap reads (for run --dataset NAME --source LOCATION)."""
    from featmap.datasets import DATASETS

    for fmt in DATASETS.values():
        typer.echo(f"{fmt.name:>12s}  {fmt.location_help}")


@command
def sweep(
    sweep_file: Path = typer.Argument(..., help="Sweep YAML (base, input or drive, methods, grid, samples)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default: runs/sweeps/<file stem>)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
    workers: int = WorkersOpt,
    cache_dir: Path = CacheOpt,
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Run the combinations on this Dask scheduler (tcp://HOST:8786) instead of local processes."),
):
    """Sweep fusion parameters on cached segments: sweep.csv, heatmaps, curves, Pareto plot, best.yaml."""
    from featmap.pipeline import local_executor
    from featmap.sweep import load_sweep, run_sweep_file

    spec = load_sweep(sweep_file)
    out = out or Path("runs") / "sweeps" / Path(sweep_file).stem
    reporter = _reporter()
    if scheduler:
        from featmap.batch import connect
        from featmap.pipeline.executor import DaskExecutor

        client, _ = connect(scheduler)
        try:
            reporter.info(f"Dask scheduler {client.scheduler.address}: {sum(client.nthreads().values())} worker threads")
            rows, best = run_sweep_file(sweep_file, out, DaskExecutor(client), reporter, config, set_ or [], cache_dir)
        finally:
            client.close()
    else:
        with local_executor(workers) as executor:
            rows, best = run_sweep_file(sweep_file, out, executor, reporter, config, set_ or [], cache_dir)
    metric = spec.select.metric
    table = []
    for method in spec.methods:
        sub = [r for r in rows if r["method"] == method and r.get(metric) is not None]
        if sub:
            b = (max if spec.select.goal == "max" else min)(sub, key=lambda r: r[metric])
            table.append([method, str(len(sub)), f"{b[metric]:.4f}", str(b["count"])])
        else:
            table.append([method, str(len([r for r in rows if r["method"] == method])), "-", "-"])
    reporter.table(f"featmap sweep: {len(rows)} combinations", ["method", "combinations", "best " + metric,
                                                                  "count at best"], table)
    reporter.info(f"wrote sweep.csv, plots{', best.yaml' if best else ''} to {out}")


SchedulerOpt = typer.Option(None, "--scheduler", help="Dask scheduler address, e.g. tcp://HOST:8786 (default: a LocalCluster on this machine).")


@command
def batch(
    batch_file: Path = typer.Argument(..., help="Batch YAML: drives (world, kitti or dataset + location; globbed), per-drive overrides."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default: the file's out, else runs/batch/<file stem>)."),
    scheduler: Optional[str] = SchedulerOpt,
    workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="LocalCluster worker processes (default: the file's workers, else the cores)."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Run many drives as Dask tasks (one run folder each, resumable) and fuse them into one merged map."""
    from featmap.batch import connect, plan_batch, run_batch

    plan = plan_batch(batch_file, out, config, set_ or [], scheduler)
    reporter = _reporter()
    client, cluster = connect(plan.scheduler, workers or plan.workers, given_by=plan.scheduler_given_by)
    try:
        reporter.info(f"Dask scheduler {client.scheduler.address}: {sum(client.nthreads().values())} worker threads")
        result = run_batch(plan, client, reporter)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if result.failed:
        typer.echo(f"featmap: {len(result.failed)} of {len(result.summary.drives)} drive(s) failed "
                   f"(see {plan.out / 'summary.json'})", err=True)
        raise typer.Exit(code=1)


@command
def figures(
    run_dir: Path = typer.Argument(..., help="A featmap run folder."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output folder (default: RUN_DIR/figures)."),
    tiles: Optional[str] = typer.Option(None, "--tiles", help="Tile source for Fig. 11: xyzservices name or {z}/{x}/{y} URL."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Write the paper's figures (2-3, 6-11, 13-14) for one run (its Tables 1-3: featmap compare)."""
    from featmap.outputs import tiles_of
    from featmap.pipeline.config import config_from_dict, load_config
    from featmap.pipeline.run_folder import check_folder_path, load_run
    from featmap.plotting.figures import FigureInputs, make_figures

    if out is not None:
        check_folder_path(out)
    cfg = None
    if config is not None or set_ or tiles is not None:   # the run's own config, changed where asked
        from featmap.config import apply_overrides
        from featmap.pipeline.config import FeatmapConfig

        if tiles is not None:
            from featmap.plotting.basemap import tile_provider

            try:
                tile_provider(tiles)
            except ValueError as exc:
                _fail(f"--tiles {tiles}: {exc}")
        if config is None and not (run_dir / "config.yaml").is_file():
            _fail(f"{run_dir}: no config.yaml to apply --set / --tiles to (not a featmap run folder?); "
                  "give --config")
        base = load_config(config if config is not None else run_dir / "config.yaml").model_dump(mode="json")
        overrides = list(set_ or []) + ([f"output.tile_source={tiles}"] if tiles is not None else [])
        changed_by = " / ".join(flag for flag, given in (("--set", set_), ("--tiles", tiles is not None)) if given)
        cfg = config_from_dict(apply_overrides(base, overrides, FeatmapConfig), changed_by or str(config))
    run_data = load_run(run_dir, cfg)
    inputs = FigureInputs(segments=run_data.segments, methods=list(run_data.fused), fusion=run_data.config.fusion,
                          trajectory=run_data.trajectory, frame=run_data.frame, truth=run_data.truth,
                          tiles=tiles_of(run_data.config.output))
    for p in make_figures(inputs, out or Path(run_dir) / "figures"):
        typer.echo(f"wrote {p}")


SIZE_UNITS = {"": 1, "B": 1, "K": 1000, "KB": 1000, "M": 1000**2, "MB": 1000**2, "G": 1000**3, "GB": 1000**3,
              "T": 1000**4, "TB": 1000**4, "KIB": 1024, "MIB": 1024**2, "GIB": 1024**3, "TIB": 1024**4}


def parse_size(text: str, flag: str) -> int:
    """Bytes from a size such as ``4GB``, ``500M``, ``1.5GiB`` or ``0`` (K, M, G, T are powers of 1000;
    KiB, MiB, GiB, TiB of 1024); one-line error naming ``flag`` otherwise."""
    import re

    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]*)\s*", text)
    if match is None or match.group(2).upper() not in SIZE_UNITS:
        _fail(f"{flag} {text!r}: not a size (examples: 4GB, 500MB, 1.5GiB, 0)")
    return int(float(match.group(1)) * SIZE_UNITS[match.group(2).upper()])


def _gigabytes(n_bytes: int) -> str:
    return f"{n_bytes / 1e9:.2f} GB"


@command
def cache(
    cache_dir: Path = CacheOpt,
    max_size: Optional[str] = typer.Option(None, "--max-size", help="Remove the least recently used entries until the rest take at most this much (e.g. 4GB, 500MB, 0)."),
    unused_days: Optional[float] = typer.Option(None, "--unused-days", min=0, help="Remove the entries no run has used for more than this many days."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Only say what would be removed."),
):
    """Show the segment cache's size, or prune it: least recently used entries first (old extractor
    code's and deleted drives' entries are never used again, so they go first)."""
    import time

    from featmap.pipeline import SegmentStore

    pruning = max_size is not None or unused_days is not None
    if dry_run and not pruning:
        _fail("--dry-run: give --max-size or --unused-days (what would be removed)")
    store = SegmentStore(cache_dir, writable=False)          # (never created here; a missing one is an error)
    reporter = _reporter()
    if not pruning:
        entries = store.entries()
        total = sum(entry.size for entry in entries)
        when = (lambda t: time.strftime("%Y-%m-%d %H:%M", time.localtime(t)))
        uses = [when(entries[0].last_use), when(entries[-1].last_use)] if entries else ["-", "-"]
        reporter.table(f"segment cache {cache_dir}", ["entries", "size", "least recently used", "most recently used"],
                       [[f"{len(entries):,}", _gigabytes(total), *uses]])
        return
    result = store.prune(None if max_size is None else parse_size(max_size, "--max-size"),
                         None if unused_days is None else unused_days * 86400.0, dry_run=dry_run)
    verb = "would remove" if dry_run else "removed"
    rows = [[verb, f"{result.removed_entries:,}", _gigabytes(result.removed_bytes)],
            ["kept", f"{result.kept_entries:,}", _gigabytes(result.kept_bytes)]]
    if result.removed_leftovers:
        rows.append([f"{verb} (temporary files of killed runs)", f"{result.removed_leftovers:,}",
                     _gigabytes(result.leftover_bytes)])
    reporter.table(f"segment cache {cache_dir}{' (dry run)' if dry_run else ''}", ["", "entries", "size"], rows)


@command
def compare(run_dir: Path = typer.Argument(..., help="A featmap run folder (with metrics.json).")):
    """Write comparison.csv and comparison.md (the paper's Tables 1-3 for one run) and print them."""
    from featmap.io.run_metrics import read_run_metrics
    from featmap.outputs import write_comparison

    _, md = write_comparison(read_run_metrics(run_dir / "metrics.json"), run_dir)
    typer.echo(md)
    typer.echo(f"wrote {run_dir / 'comparison.csv'} and {run_dir / 'comparison.md'}")


@command
def config(
    config_file: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
):
    """Print the configuration (the commented defaults, or a file with --set overrides, resolved)."""
    from featmap.pipeline.config import default_config_yaml, load_config

    if config_file is None and not set_:
        typer.echo(default_config_yaml(), nl=False)
    else:
        typer.echo(load_config(config_file, set_ or []).to_yaml(), nl=False)


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

    from featmap.datasets.kitti_download import download_drive
    from featmap.datasets.kitti_raw import parse_drive

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
    origin: Optional[str] = typer.Option(None, "--origin", help="LAT,LON of a CSV's local frame (default: the run's metrics.json or the batch merge's merged.json beside it); a GeoJSON in a run's folder is scored in the run's frame."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Also write the metrics to this JSON file."),
):
    """Score any fused map against ground-truth footprints (the metrics of EVALUATION.md).

    Footprints that the map's run was scored against count what its scans observed of them (the run's
    footprint_walls.csv); other footprints count every wall, whole (recall is then a lower bound)."""
    import json

    from featmap.evaluation.score_files import evaluate_file
    from featmap.pipeline.run_folder import RunFolderError

    metrics = evaluate_file(fused, truth, origin)
    if out is not None:
        from featmap.io.atomic import atomic_write_text

        if out.is_dir():
            raise RunFolderError(f"--out {out}: is a folder; give a .json file path")
        try:
            atomic_write_text(out, json.dumps(metrics, indent=1))
        except OSError as exc:
            raise RunFolderError(f"--out {out}: cannot write ({exc.strerror})") from None
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
    pose_noise_tau: float = typer.Option(2.0, "--pose-noise-tau", help="Correlation time of the OXTS pose error, seconds (Gauss-Markov drift)."),
    dropout: float = typer.Option(0.0, "--dropout", min=0.0, max=0.99, help="Probability that a return is lost."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, byte-identical drive)."),
    drive_id: str = typer.Option("0001", "--drive-id", help="Four-digit drive number of the written drive."),
):
    """Ray-cast a LiDAR drive through a world and write it in the KITTI raw layout with ground truth."""
    import time

    from featmap.reporting import track
    from featmap.simulation.sensors import SENSORS
    from featmap.simulation.simulate import simulate_drive
    from featmap.simulation.worlds import load_world

    if sensor not in SENSORS:
        _fail(f"--sensor {sensor!r}: allowed: {', '.join(SENSORS)}")
    if not (len(drive_id) == 4 and drive_id.isdigit()):
        _fail(f"--drive-id {drive_id!r}: expected four digits, e.g. 0001")
    if out.exists() and not out.is_dir():
        _fail(f"--out {out}: exists and is not a folder")
    if not world.strip():
        _fail("--world '': give a built-in world's name or a world file")
    w = load_world(world)
    reporter = _reporter()
    start = time.perf_counter()
    drive = simulate_drive(w, out, SENSORS[sensor], frames, noise, dropout, _parse_pose_noise(pose_noise), seed,
                           drive_id, progress=lambda it, n: track(reporter, it, n, f"simulating {w.name}"),
                           pose_noise_tau_s=pose_noise_tau)
    seconds = time.perf_counter() - start
    typer.echo(f"wrote {drive.n_frames} frames of {w.name} ({sensor}) to {drive.drive_dir} "
               f"in {seconds:.1f} s ({drive.n_frames / seconds:.1f} frames/s); ground truth in "
               f"{drive.drive_dir / 'truth'}; run it with: featmap run --drive {drive.drive} --data-dir {out}")


def main() -> None:
    app(prog_name="featmap")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
