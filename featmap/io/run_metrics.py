"""``metrics.json``: the typed record of one run, written by the pipeline and read by compare, figures,
sweeps and batches.

Paths in it are absolute (a reference such as a simulated drive's ``truth/`` folder stays where it is
when the run folder moves); readers also accept paths relative to the run folder.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from featmap.errors import InputFileError, shown
from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_write_text
from featmap.io.jsonfile import read_json, validate_record

SCHEMA_VERSION = 2
Score = Union[int, float, None, dict[str, Optional[float]]]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SourceRecord(_Model):
    """Where the scans came from."""

    kind: str = Field(description="format name in the dataset registry")
    name: str
    location: str = Field(description="absolute path of the drive folder or log file")
    dimension: int
    frames: list[int] = Field(description="frame numbers selected")
    frames_processed: list[int] = Field(description="frames whose segments went into the map")
    skipped: dict[str, str] = Field(default_factory=dict, description="frame -> why it was left out")
    flags: dict[str, list[int]] = Field(default_factory=dict, description="e.g. poor_gps -> frames")


class GeoRecord(_Model):
    """The run's :class:`GeoFrame`; its range checks here, so a bad one is an error naming the file."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    lat0_deg: float = Field(gt=-90, lt=90)
    lon0_deg: float = Field(ge=-180, le=180)
    alt0_m: float = 0.0

    def frame(self) -> GeoFrame:
        return GeoFrame(self.lat0_deg, self.lon0_deg, self.alt0_m)


class ScanCounts(_Model):
    total: int = Field(ge=0)
    processed: int = Field(ge=0)
    extracted_now: int = Field(ge=0)
    from_cache: int = Field(ge=0)


class MethodRecord(_Model):
    """One fusion method's result: its count, time and scores per evaluator (e.g. ``truth``)."""

    count: int = Field(ge=0)
    clusters_dropped: int = Field(0, ge=0)
    seconds: float
    scores: dict[str, dict[str, Score]] = Field(default_factory=dict)


class RefinementRecord(_Model):
    """What pose refinement did: its method, whether its corrections were applied, their size and time."""

    method: str = Field(description="refinement method (none: poses as the source gave them)")
    applied: bool = Field(description="whether the corrections were applied (kept only when the scans then agree better)")
    seconds: float
    scans: int = Field(description="scans whose poses were refined or interpolated")
    keyframes: Optional[int] = Field(None, description="scans solved (the others got interpolated corrections)")
    iterations: int = 0
    matches: int = Field(0, description="segment pairs of different scans matched in the last iteration")
    converged: bool = True
    correction_mean_m: float = Field(0.0, description="mean translation correction per scan")
    correction_max_m: float = 0.0
    rotation_mean_deg: float = Field(0.0, description="mean heading correction per scan")
    rotation_max_deg: float = 0.0
    residual_before_mm: Optional[float] = Field(None, description="mean distance between matched segments of different scans, source poses")
    residual_after_mm: Optional[float] = Field(None, description="the same after refinement")
    loops: Optional[int] = Field(None, description="loop closures found by the wide search (None: search off)")
    slam_poses: bool = Field(False, description="the source's poses were taken as a SLAM result (held near them by the slam_absolute_* prior where set)")


class OnlineRecord(_Model):
    """How a run mapped online (``featmap run --online N``; its per-scan times are in ``online.csv``)."""

    every: int = Field(description="the map was made after every this many scans, and after the last")
    maps: int = Field(description="how many times the map was made")


class RunMetrics(_Model):
    schema_version: int = SCHEMA_VERSION
    featmap_version: str
    source: SourceRecord
    geo_frame: Optional[GeoRecord] = None
    references: dict[str, str] = Field(default_factory=dict, description="evaluator -> reference used (absolute path)")
    primary: Optional[str] = Field(None, description="the evaluator whose scores summarise the run")
    scans: ScanCounts
    segments: int = Field(ge=0)
    timings_s: dict[str, Optional[float]]
    methods: dict[str, MethodRecord]
    refinement: Optional[RefinementRecord] = Field(None, description="pose refinement before fusion (None: runs before it existed)")
    online: Optional[OnlineRecord] = Field(None, description="the scans were mapped online, one at a time (None: all at once)")

    @model_validator(mode="after")
    def _primary_is_a_reference(self) -> "RunMetrics":
        if self.primary is not None and self.primary not in self.references:
            raise ValueError(f"'primary' names {shown(self.primary)}, not one of the references "
                             f"({', '.join(self.references) or 'none'})")
        return self

    def primary_scores(self, method: str) -> dict[str, Score]:
        """The primary evaluator's scores of ``method`` ({} when the run had no reference)."""
        return self.methods[method].scores.get(self.primary, {}) if self.primary else {}

    def reference_path(self, name: str, run_dir: str | Path) -> Path | None:
        """The reference an evaluator used, resolved against ``run_dir`` when it is relative."""
        value = self.references.get(name)
        if value is None:
            return None
        path = Path(value)
        return path if path.is_absolute() else Path(run_dir) / path

    def scored_against(self, name: str, path: str | Path, run_dir: str | Path) -> bool:
        """Whether the run in ``run_dir`` used the file or folder at ``path`` as its ``name`` reference."""
        own = self.reference_path(name, run_dir)
        return own is not None and own.resolve() == Path(path).resolve()


def write_run_metrics(path: str | Path, metrics: RunMetrics) -> Path:
    return atomic_write_text(path, json.dumps(metrics.model_dump(mode="json"), indent=1, allow_nan=False))


def read_run_metrics(path: str | Path) -> RunMetrics:
    """Read and validate a ``metrics.json``; a one-line InputFileError naming what is wrong."""
    path = Path(path)
    data = read_json(path, "not found: is this a featmap run folder? (featmap run writes it)")
    if not isinstance(data, dict):
        raise InputFileError(path, "expected a JSON object written by featmap run")
    version = data.get("schema_version", 1)
    if type(version) is not int:        # (a bool is no version either)
        raise InputFileError(path, f"not a featmap metrics file: 'schema_version' must be a whole number, "
                                   f"got {shown(version)}")
    if version != SCHEMA_VERSION:
        raise InputFileError(path, f"written by another featmap version (schema {version}, "
                                   f"expected {SCHEMA_VERSION}); run featmap run again")
    return validate_record(path, data, RunMetrics, "metrics file")
