"""The configuration of a run: every stage's section, composed (defaults < YAML < ``--set``).

Each section is defined beside its code: ``extraction`` by the extractor registry, ``refinement`` by the
pose-refinement registry, ``fusion`` by the fusion registry, ``evaluation`` by the evaluation plug-ins, ``output`` by the output plug-ins.
``configs/default.yaml`` is the commented rendering of these defaults (``featmap config`` prints it; a
test keeps them identical).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

from featmap.config import Section, commented_yaml, load_config_file, to_yaml, validate_config
from featmap.errors import ConfigError
from featmap.evaluation import EvaluationConfig
from featmap.extraction import ExtractionConfig
from featmap.fusion import FusionConfig
from featmap.io.atomic import atomic_write_text
from featmap.outputs import OutputConfig
from featmap.refinement import RefinementConfig


class FeatmapConfig(Section):
    extraction: ExtractionConfig = ExtractionConfig()  # type: ignore[valid-type]
    refinement: RefinementConfig = RefinementConfig()  # type: ignore[valid-type]
    fusion: FusionConfig = FusionConfig()  # type: ignore[valid-type]
    evaluation: EvaluationConfig = EvaluationConfig()
    output: OutputConfig = OutputConfig()

    def to_yaml(self) -> str:
        return to_yaml(self)


PRESETS_DIR = Path(__file__).resolve().parents[2] / "configs"
"""Named presets (``--config paper``, ``--config indoor_2d``): the YAML files in the source tree's ``configs/``."""


def preset_names() -> list[str]:
    """The config presets in ``configs/`` (batch files there are not configs)."""
    if not PRESETS_DIR.is_dir():
        return []
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml") if not p.stem.startswith("batch"))


def resolve_config_path(path: str | Path, flag: str = "--config") -> Path:
    """A config file's path: ``path`` itself when it exists, else the preset of that name in ``configs/``
    (``flag``: where the name came from, for the error)."""
    path = Path(path)
    if path.exists():
        return path
    if path.suffix in (".yaml", ".yml") or len(path.parts) > 1:
        raise ConfigError(f"{flag} {path}: config file not found")
    preset = PRESETS_DIR / f"{path.name}.yaml"
    if preset.is_file():
        return preset
    names = preset_names()
    raise ConfigError(f"{flag} {path}: no such file, nor a preset" + (f" ({', '.join(names)})" if names else ""))


def load_config(path: str | Path | None = None, overrides: Iterable[str] = ()) -> FeatmapConfig:
    """Defaults, then the YAML file (or named preset) at ``path`` (if any), then ``--set key=value`` overrides."""
    return load_config_file(FeatmapConfig, None if path is None else resolve_config_path(path), overrides)


def config_from_dict(data: dict[str, Any], source: str = "config") -> FeatmapConfig:
    return validate_config(FeatmapConfig, data, source)


def save_config(config: FeatmapConfig, path: str | Path) -> Path:
    """Write the fully resolved config (atomically) so a run can be repeated exactly."""
    return atomic_write_text(path, config.to_yaml())


def default_config_yaml() -> str:
    """The defaults with one comment per key: the text of ``configs/default.yaml`` (``featmap config``)."""
    return ("# featmap default configuration: every parameter, its unit and what it does.\n"
            "# Override with --config FILE and --set section.key=value (defaults < YAML < --set).\n"
            + commented_yaml(FeatmapConfig()))
