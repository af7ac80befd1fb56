"""Typed configuration: nested pydantic models, YAML files and ``--set a.b=v`` overrides.

Precedence is defaults < YAML file < overrides. Every model forbids unknown keys, so a typo in a
YAML file or an override is an error naming the key and its closest valid spelling, not a silently
ignored setting. ``configs/default.yaml`` mirrors these defaults with one comment per key (a test
keeps the two identical).
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any, Iterable, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from featmap.errors import ConfigError
from featmap.extraction.vertical_structure import VerticalStructureConfig


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class ExtractionConfig(_Section):
    """Per-scan wall extraction (velodyne frame, metres); the keys after vertical_structure are ransac_planes'."""

    method: Literal["vertical_structure", "ransac_planes"] = Field(
        "vertical_structure", description="vertical_structure = tall thin lines of the top view; ransac_planes = sequential RANSAC planes (the keys below)")
    vertical_structure: VerticalStructureConfig = VerticalStructureConfig()
    min_range_m: float = Field(2.5, ge=0, description="drop returns closer than this (vehicle body)")
    max_range_m: float = Field(50.0, gt=0, description="drop returns farther than this (sparse, noisy)")
    z_min_m: float = Field(-3.0, description="drop returns below this height in the velodyne frame")
    z_max_m: float = Field(6.0, description="drop returns above this height in the velodyne frame")
    voxel_size_m: float = Field(0.15, ge=0, description="voxel down-sampling before RANSAC (0 = off)")
    ground_threshold_m: float = Field(0.15, gt=0, description="RANSAC inlier distance of the ground plane")
    ground_margin_m: float = Field(0.3, ge=0, description="also drop points this close above the ground plane")
    plane_threshold_m: float = Field(0.08, gt=0, description="RANSAC inlier distance of a wall plane")
    ransac_iterations: int = Field(200, ge=10, description="RANSAC iterations per plane")
    ransac_max_points: int = Field(1200, ge=100, description="RANSAC hypotheses come from a random subset of this many points")
    max_planes: int = Field(25, ge=1, description="planes tried per scan")
    max_normal_tilt_deg: float = Field(10.0, ge=0, le=90, description="a wall's normal lies within this of horizontal")
    min_plane_inliers: int = Field(60, ge=3, description="stop when the best plane has fewer inliers")
    min_vertical_extent_m: float = Field(1.2, ge=0, description="a wall piece spans at least this in height")
    min_top_height_m: float = Field(1.85, ge=0, description="a wall piece reaches at least this high above the ground (0 = keep fences and cars)")
    max_gap_m: float = Field(1.5, gt=0, description="split a plane's inliers where they leave a gap this long")
    min_segment_length_m: float = Field(1.0, ge=0, description="drop wall pieces shorter than this")
    min_segment_points: int = Field(25, ge=2, description="drop wall pieces with fewer points")
    seed: int = Field(0, description="seed for Open3D's RANSAC (reproducible results)")


class ProposedConfig(_Section):
    """The paper's method (Section 3): three criteria, clustering, least squares."""

    delta_deg: float = Field(5.0, ge=0, le=90, description="criterion 1: max included angle beta")
    gamma: float = Field(0.3, ge=0, le=1, description="criterion 2: min feature-circle overlap S_overlap/S_min")
    eta_m: float = Field(0.5, ge=0, description="criterion 3: max relative distance d_max")
    min_support: int = Field(4, ge=1, description="drop clusters with fewer member segments")
    fit_weighting: Literal["length", "none"] = Field("length", description="weight of each member's endpoints in the TLS fit")


class MeanShiftConfig(_Section):
    """Competing algorithm 1 (after Lakaemper 2009): mean shift on orientation, then on centres."""

    orientation_bandwidth_deg: float = Field(3.0, gt=0, le=90, description="mean-shift bandwidth on orientation")
    center_bandwidth_m: float = Field(3.0, gt=0, description="mean-shift bandwidth on segment centres")


class DensityConfig(_Section):
    """Competing algorithm 2 (after Sarkar et al. 2014): orientation mean shift, then density clustering."""

    orientation_bandwidth_deg: float = Field(3.0, gt=0, le=90, description="mean-shift bandwidth on orientation")
    lateral_eps_m: float = Field(0.5, gt=0, description="max lateral separation of neighbouring segments")
    longitudinal_gap_m: float = Field(1.0, ge=0, description="max gap along the line between neighbouring segments")
    min_samples: int = Field(1, ge=1, description="DBSCAN min_samples (1 = every segment is a core point)")


class CornerConfig(_Section):
    """Corner optimisation, run identically after every method (as in the paper's Table 2)."""

    mode: Literal["midpoint", "intersection", "none"] = Field(
        "intersection", description="midpoint = the paper's rule; intersection = ours; none = off")
    snap_distance_m: float = Field(1.0, ge=0, description="endpoints of different features closer than this are joined")
    min_angle_deg: float = Field(30.0, ge=0, le=90, description="intersection mode: lines must meet at least this steeply")


class FusionConfig(_Section):
    proposed: ProposedConfig = ProposedConfig()
    meanshift: MeanShiftConfig = MeanShiftConfig()
    density: DensityConfig = DensityConfig()
    corners: CornerConfig = CornerConfig()


class OutputConfig(_Section):
    """What a run writes besides the CSV files of the output contract."""

    geojson: bool = Field(True, description="write fused_<method>.geojson (WGS84)")
    kml: bool = Field(True, description="write map.kml for Google Earth")
    html: bool = Field(True, description="write map.html (interactive Leaflet map)")
    plots: bool = Field(True, description="write overview PNG plots")
    tile_source: str = Field("OpenStreetMap.Mapnik", description="basemap: an xyzservices name or a {z}/{x}/{y} URL template")
    tile_cache_dir: str = Field("~/.cache/featmap/tiles", description="on-disk cache of fetched map tiles")
    tile_timeout_s: float = Field(5.0, gt=0, description="give up on the basemap after this many seconds")


class FeatmapConfig(_Section):
    extraction: ExtractionConfig = ExtractionConfig()
    fusion: FusionConfig = FusionConfig()
    output: OutputConfig = OutputConfig()

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


# --------------------------------------------------------------------------------------------------


def _valid_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """All dotted keys of a model, leaves and sections."""
    keys = []
    for name, field in model.model_fields.items():
        dotted = f"{prefix}{name}"
        keys.append(dotted)
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            keys.extend(_valid_keys(annotation, dotted + "."))
    return keys


def closest_key(key: str, model: type[BaseModel] = FeatmapConfig) -> str | None:
    """The valid dotted key most similar to ``key`` (for 'did you mean' messages)."""
    matches = difflib.get_close_matches(key, _valid_keys(model), n=1, cutoff=0.5)
    if not matches:  # compare leaf names too: "fusion.proposed.delta" -> "...delta_deg"
        leaves = {k.rsplit(".", 1)[-1]: k for k in _valid_keys(model)}
        leaf = difflib.get_close_matches(key.rsplit(".", 1)[-1], list(leaves), n=1, cutoff=0.5)
        matches = [leaves[leaf[0]]] if leaf else []
    return matches[0] if matches else None


def _format_validation_error(error: ValidationError, source: str) -> str:
    parts = []
    for item in error.errors():
        key = ".".join(str(p) for p in item["loc"])
        if item["type"] == "extra_forbidden":
            hint = closest_key(key)
            parts.append(f"unknown key '{key}'" + (f" (did you mean '{hint}'?)" if hint else ""))
        else:
            msg = item["msg"]
            if "expected" in item.get("ctx", {}):
                msg = f"must be one of {item['ctx']['expected']}"
            parts.append(f"'{key}' {msg[0].lower() + msg[1:]} (got {item.get('input')!r})")
    return f"{source}: " + "; ".join(parts)


def parse_override(text: str) -> tuple[list[str], Any]:
    """Split ``"a.b.c=value"`` into its key path and YAML-parsed value."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. --set fusion.proposed.delta_deg=5")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"--set {text!r}: the key is empty")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.split("."), value


def apply_overrides(data: dict[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Return a copy of ``data`` with every ``a.b=v`` override set (unknown keys fail later)."""
    data = _deep_copy(data)
    for text in overrides:
        path, value = parse_override(text)
        if ".".join(path) not in _valid_keys(FeatmapConfig):
            hint = closest_key(".".join(path))
            raise ConfigError(f"--set {text}: unknown key '{'.'.join(path)}'"
                              + (f" (did you mean '{hint}'?)" if hint else ""))
        node = data
        for part in path[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                child = {}
                node[part] = child
            node = child
        node[path[-1]] = value
    return data


def _deep_copy(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data


def yaml_error_line(exc: Exception) -> str:
    """``":LINE"`` of a YAML syntax error (1-based), or ``""`` when PyYAML does not know it."""
    mark = getattr(exc, "problem_mark", None)
    return f":{mark.line + 1}" if mark is not None else ""


def read_yaml_mapping(path: str | Path) -> dict[str, Any]:
    """Read a YAML file that must hold a mapping; a one-line ConfigError otherwise."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}{yaml_error_line(exc)}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections, got {type(data).__name__}")
    return data


def config_from_dict(data: dict[str, Any], source: str = "config") -> FeatmapConfig:
    try:
        return FeatmapConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation_error(exc, source)) from None


def load_config(path: str | Path | None = None, overrides: Iterable[str] = ()) -> FeatmapConfig:
    """Defaults, then the YAML file at ``path`` (if any), then ``--set`` overrides."""
    data = read_yaml_mapping(path) if path is not None else {}
    overrides = list(overrides)
    source = str(path) if path is not None else "config"
    if overrides:
        data = apply_overrides(data, overrides)
        source += " with --set " + " ".join(overrides)
    return config_from_dict(data, source)


def save_config(config: FeatmapConfig, path: str | Path) -> Path:
    """Write the fully resolved config (atomically) so a run can be repeated exactly."""
    from featmap.io.atomic import atomic_write_text

    return atomic_write_text(path, config.to_yaml())


def commented_yaml(config: BaseModel | None = None, indent: int = 0) -> str:
    """Render a config as YAML with each field's description as a trailing comment.

    ``configs/default.yaml`` is this rendering of the defaults (``featmap config`` prints it).
    """
    config = FeatmapConfig() if config is None else config
    lines = []
    pad = "  " * indent
    for name, field in type(config).model_fields.items():
        value = getattr(config, name)
        if isinstance(value, BaseModel):
            doc = (type(value).__doc__ or "").strip().splitlines()
            lines.append(f"{pad}{name}:" + (f"  # {doc[0]}" if doc else ""))
            lines.append(commented_yaml(value, indent + 1).rstrip("\n"))
        else:
            rendered = yaml.safe_dump({name: value}, default_flow_style=True, width=1000).strip()[1:-1]
            comment = f"  # {field.description}" if field.description else ""
            lines.append(f"{pad}{rendered}{comment}")
    return "\n".join(lines) + "\n"
