"""Scan sources by format name: how ``featmap run`` (and batches, sweeps) open a dataset.

A new format is one module (a class implementing :class:`featmap.datasets.base.ScanSource` and an
opener ``open(location, frames, skip_bad_scans, reporter) -> ScanSource``) plus one line in ``DATASETS``.
It is then available as ``featmap run --dataset NAME --source LOCATION``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from featmap.datasets import carmen, kitti_raw, simulated
from featmap.datasets.base import ScanSource, SourceSpec
from featmap.errors import DatasetError
from featmap.reporting import NullReporter, Reporter


@dataclass(frozen=True)
class DatasetFormat:
    """A registered format: its name, what a location is, its opener, and the config preset a run of it
    uses when no ``--config`` is given (a name in ``configs/``, or None for the defaults)."""

    name: str
    location_help: str
    open: Callable[..., ScanSource]
    preset: str | None = None


DATASETS: dict[str, DatasetFormat] = {f.name: f for f in (
    DatasetFormat("kitti_raw", "a KITTI raw drive folder ROOT/YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync",
                  kitti_raw.open_drive_folder),
    DatasetFormat("simulated", "a built-in world name (residential, prescan_case1, ...) or a world .yaml/.geojson file",
                  simulated.open_world),
    DatasetFormat("carmen", "a CARMEN 2D laser log: .log, .log.gz, .clf or .clf.bz2", carmen.open_log, preset="indoor_2d"),
)}


def open_source(spec: SourceSpec, reporter: Reporter = NullReporter()) -> ScanSource:
    """Open the scan source ``spec`` names (validating it: bad data fails here, before any work)."""
    try:
        fmt = DATASETS[spec.kind]
    except KeyError:
        raise DatasetError(f"--dataset {spec.kind!r}: unknown format; allowed: {', '.join(DATASETS)}") from None
    return fmt.open(spec.location, spec.frames, spec.skip_bad_scans, reporter, **dict(spec.options))
