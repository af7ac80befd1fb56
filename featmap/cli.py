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


def main() -> None:
    app(prog_name="featmap")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
