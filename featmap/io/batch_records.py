"""The typed records of a batch: ``summary.json`` (one entry per drive and the totals), ``merged/merged.json``
(the merged map: its frame, the drives in it, counts and scores) and each drive's ``batch.json`` (the
content key that lets a re-run skip a finished drive).

Paths in them are absolute.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field

from featmap.errors import InputFileError
from featmap.io.atomic import atomic_write_text
from featmap.io.jsonfile import read_json, validate_record
from featmap.io.run_metrics import GeoRecord, Score

BATCH_SCHEMA_VERSION = 1


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class DriveKey(_Model):
    """``<run folder>/batch.json``: what a drive's run was made from (its content key and the parts of it)."""

    schema_version: int = BATCH_SCHEMA_VERSION
    key: str = Field(description="hash of source identity + resolved config + methods + featmap version")
    featmap_version: str
    source: dict = Field(description="kind, location, frames, skip_bad_scans, data fingerprint")
    methods: list[str]


class DriveRecord(_Model):
    """One drive of a batch in ``summary.json``."""

    name: str
    status: Literal["done", "skipped", "failed"] = Field(description="skipped: up to date from an earlier run")
    run_dir: str
    kind: str
    location: str
    error: Optional[str] = None
    scans: int = 0
    segments: int = 0
    counts: dict[str, int] = Field(default_factory=dict, description="method -> fused features")
    scores: dict[str, dict[str, Score]] = Field(default_factory=dict, description="method -> primary scores")
    primary: Optional[str] = None
    seconds: float = Field(0.0, description="wall-clock time of the drive's task (0 when skipped)")
    cpu_seconds: float = Field(0.0, description="CPU time of the worker process during the task")
    simulation_seconds: float = Field(0.0, description="time of the simulation task it waited for (first use)")
    worker: Optional[str] = None


class BatchSummary(_Model):
    schema_version: int = BATCH_SCHEMA_VERSION
    featmap_version: str
    batch_file: str
    scheduler: str = Field(description="address of the Dask scheduler the batch ran on")
    workers: int = Field(description="worker threads of the cluster")
    drives: list[DriveRecord]
    wall_seconds: float
    work_seconds: float = Field(description="sum of the tasks' times (simulation, drives, merge)")
    work_cpu_seconds: float = Field(0.0, description="sum of the drive tasks' CPU times (the work without waiting "
                                                     "for a core shared with other processes)")
    critical_path_seconds: float = Field(description="longest chain of dependent tasks: simulation -> drive -> merge")
    merge_seconds: Optional[float] = None
    merged: Optional[str] = Field(None, description="the merged map's folder, when one was made")


class MergedDrive(_Model):
    name: str
    run_dir: str
    scan_offset: int = Field(description="merged scan id = offset + the drive's frame number")
    segments: int
    geo_frame: Optional[GeoRecord] = None
    truth: Optional[str] = Field(None, description="the drive's simulator truth folder, if it had one")
    correction: Optional[list[float]] = Field(None, description="dx, dy (m), dyaw (deg) the drive was moved by to "
                                                                "agree with the others (about its map's centre)")
    frames_processed: list[int] = Field(default_factory=list)


class MergedRecord(_Model):
    """``merged/merged.json``."""

    schema_version: int = BATCH_SCHEMA_VERSION
    featmap_version: str
    geo_frame: Optional[GeoRecord] = Field(None, description="the merged local frame (the first drive's)")
    drives: list[MergedDrive]
    left_out: dict[str, str] = Field(default_factory=dict, description="drive -> why it is not in the merged map")
    segments: int
    counts: dict[str, int] = Field(default_factory=dict)
    multi_drive: dict[str, int] = Field(default_factory=dict, description="method -> features seen by 2+ drives")
    reference: Optional[str] = Field(None, description="what the scores are against: the drives' truths (united), "
                                                       "a footprints file, or the drives' scan points")
    evaluator: Optional[str] = Field(None, description="the kind of reference: truth, footprints or map (truth-free)")
    unscored: Optional[str] = Field(None, description="why a map that could have been scored was not")
    alignment: Optional[dict[str, Union[bool, int, float]]] = Field(
        None, description="the drives' rigid alignment: applied, matches, agreement before and after (mm)")
    scores: dict[str, dict[str, Score]] = Field(default_factory=dict, description="method -> merged map's scores")
    drive_scores: dict[str, dict[str, dict[str, Score]]] = Field(
        default_factory=dict, description="method -> drive -> that drive's own map scored against the same reference")
    seconds: float = 0.0


def _write(path: str | Path, model: BaseModel) -> Path:
    return atomic_write_text(path, json.dumps(model.model_dump(mode="json"), indent=1, allow_nan=False))


def _read(path: str | Path, model: type[BaseModel], what: str):
    path = Path(path)
    data = read_json(path, f"not found: is this a featmap {what}?")
    if not isinstance(data, dict) or data.get("schema_version") != BATCH_SCHEMA_VERSION:
        raise InputFileError(path, f"not a featmap {what} of this version (schema {BATCH_SCHEMA_VERSION}); "
                                   "run featmap batch again")
    return validate_record(path, data, model, what)


def write_drive_key(path: str | Path, key: DriveKey) -> Path:
    return _write(path, key)


def read_drive_key(path: str | Path) -> DriveKey:
    return _read(path, DriveKey, "batch key (batch.json)")


def write_batch_summary(path: str | Path, summary: BatchSummary) -> Path:
    return _write(path, summary)


def read_batch_summary(path: str | Path) -> BatchSummary:
    return _read(path, BatchSummary, "batch summary (summary.json)")


def write_merged_record(path: str | Path, record: MergedRecord) -> Path:
    return _write(path, record)


def read_merged_record(path: str | Path) -> MergedRecord:
    return _read(path, MergedRecord, "merged map record (merged/merged.json)")
