"""Typed configuration machinery: pydantic sections, YAML files and ``--set a.b=v`` overrides.

This module is the ground floor: it knows nothing about extraction, fusion or outputs. Each of those
defines its own section model (a :class:`Section`) beside its code, and
:mod:`featmap.pipeline.config` composes them into the run's :class:`~featmap.pipeline.config.FeatmapConfig`.
The functions here work on any root model.

Precedence is defaults < YAML file < overrides. Every section forbids unknown keys, so a typo in a
YAML file or an override is an error naming the key and its closest valid spelling, not a silently
ignored setting.
"""

from __future__ import annotations

import difflib
import re
import typing
from pathlib import Path
from typing import Any, Iterable, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from featmap.errors import ConfigError, shown

M = TypeVar("M", bound=BaseModel)


class Section(BaseModel):
    """Base of every configuration section: immutable, strict about unknown keys and types.

    Strict types: ``min_support: true`` is not taken as 1, nor ``delta_deg: "5"`` as 5.0 (an integer
    is still accepted for a float field).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True)


def valid_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """All dotted keys of a model, leaves and sections."""
    keys = []
    for name, field in model.model_fields.items():
        dotted = f"{prefix}{name}"
        keys.append(dotted)
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            keys.extend(valid_keys(annotation, dotted + "."))
    return keys


def leaf_keys(model: type[BaseModel]) -> list[str]:
    """The dotted keys of a model that hold values (not sections)."""
    keys = valid_keys(model)
    return [k for k in keys if not any(other.startswith(k + ".") for other in keys)]


def closest_key(key: str, model: type[BaseModel]) -> str | None:
    """The valid dotted key most similar to ``key`` (for 'did you mean' messages)."""
    keys = valid_keys(model)
    matches = difflib.get_close_matches(key, keys, n=1, cutoff=0.5)
    if not matches:  # compare leaf names too: "fusion.proposed.delta" -> "...delta_deg"
        leaves = {k.rsplit(".", 1)[-1]: k for k in keys}
        leaf = difflib.get_close_matches(key.rsplit(".", 1)[-1], list(leaves), n=1, cutoff=0.5)
        matches = [leaves[leaf[0]]] if leaf else []
    return matches[0] if matches else None


def unknown_key_message(key: str, model: type[BaseModel]) -> str:
    hint = closest_key(key, model)
    return f"unknown key '{key}'" + (f" (did you mean '{hint}'?)" if hint else "")


def format_validation_error(error: ValidationError, source: str, model: type[BaseModel]) -> str:
    """One line naming every offending key, what is wrong with it and what was given."""
    parts = []
    for item in error.errors():
        key = ".".join(str(p) for p in item["loc"])
        if item["type"] == "extra_forbidden":
            parts.append(unknown_key_message(key, model))
        else:
            msg = item["msg"]
            if "expected" in item.get("ctx", {}):
                msg = f"must be one of {item['ctx']['expected']}"
            parts.append(f"'{key}' {msg[0].lower() + msg[1:]} (got {shown(item.get('input'))})")
    return f"{source}: " + "; ".join(parts)


_EXPONENT_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


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
    except RecursionError:
        raise ConfigError(f"--set {shown(text)}: the value is nested too deeply") from None
    if isinstance(value, str) and _EXPONENT_NUMBER.fullmatch(raw.strip()):
        value = float(raw)                          # YAML 1.1 reads an unquoted 1e6 (no dot) as a string
    return key.split("."), value


def apply_overrides(data: dict[str, Any], overrides: Iterable[str], model: type[BaseModel]) -> dict[str, Any]:
    """Return a copy of ``data`` with every ``a.b=v`` override set; unknown keys are errors."""
    data = _deep_copy(data)
    known = set(valid_keys(model))
    for text in overrides:
        path, value = parse_override(text)
        if ".".join(path) not in known:
            raise ConfigError(f"--set {text}: {unknown_key_message('.'.join(path), model)}")
        if isinstance(value, bool) and _takes_text(model, path) and not _takes_bool(model, path):
            value = text.split("=", 1)[1].strip()      # YAML 1.1 reads no/yes/on/off as booleans; a name is meant
        node = data
        for part in path[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                child = {}
                node[part] = child
            node = child
        if isinstance(value, dict) and isinstance(node.get(path[-1]), dict):
            value = _merged(node[path[-1]], value)     # a section given whole keeps the keys it does not name
        node[path[-1]] = value
    return data


def _merged(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``update``'s keys set, nested sections merged key by key (neither is changed)."""
    out = _deep_copy(base)
    for key, value in update.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _field_types(model: type[BaseModel], path: list[str]) -> tuple:
    """The types a dotted key's field accepts (its annotation, or the members of a Union / Optional)."""
    for part in path[:-1]:
        model = model.model_fields[part].annotation
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            return ()
    annotation = model.model_fields[path[-1]].annotation
    return typing.get_args(annotation) or (annotation,)


def _takes_text(model: type[BaseModel], path: list[str]) -> bool:
    """The field takes a string: ``str`` or a Literal of names (e.g. ``Literal["midpoint", "none"]``)."""
    return any(t is str or isinstance(t, str) for t in _field_types(model, path))


def _takes_bool(model: type[BaseModel], path: list[str]) -> bool:
    return bool in _field_types(model, path)


def _deep_copy(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data


def yaml_problem(exc: Exception) -> str:
    """What is wrong in a YAML error, on one line (PyYAML's reader errors span several)."""
    return " ".join(str(getattr(exc, "problem", None) or exc).split())


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, except that a key given twice in one mapping is an error (PyYAML keeps the last)
    and that 1e3 is a number (below)."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":   # '<<: *base' merges another mapping: not a key
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:                     # an unhashable key: PyYAML reports it below
                continue
            if duplicate:
                raise yaml.constructor.ConstructorError(None, None, f"{key!r} is given twice", key_node.start_mark)
        return super().construct_mapping(node, deep)


# YAML 1.1 (PyYAML) reads 1e3 and 5e-1, numbers without a dot, as strings; read them as numbers (as --set does)
_UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(rf"^(?:{_EXPONENT_NUMBER.pattern})$"),
                                       list("-+0123456789."))


class InvalidYamlError(ConfigError):
    """Text that is not valid YAML or gives a key twice, on one line: ``SOURCE:LINE: not valid YAML (PROBLEM)``.

    ``line`` (1-based, None when PyYAML does not know it) and ``problem`` are kept apart for readers that
    report in their own error type (a world file's WorldError, a wall list's InputFileError).
    """

    def __init__(self, source: str, line: int | None, problem: str):
        super().__init__(f"{source}{'' if line is None else f':{line}'}: not valid YAML ({problem})")
        self.source, self.line, self.problem = source, line, problem

    def __reduce__(self):                         # pickles (e.g. from a batch worker) with its three arguments
        return type(self), (self.source, self.line, self.problem)


def load_yaml_text(text: str, source: str) -> Any:
    """The YAML document in ``text`` as config files are read: a key given twice in one mapping is an error
    ('<<' merge keys still work) and 1e3 / 5e-1 are numbers. An :class:`InvalidYamlError` (a ConfigError)
    naming ``source`` and the line otherwise. An empty document is None."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InvalidYamlError(source, None if mark is None else mark.line + 1, yaml_problem(exc)) from None
    except RecursionError:
        raise InvalidYamlError(source, None, "nested too deeply") from None


def read_yaml_mapping(path: str | Path, what: str = "config file") -> dict[str, Any]:
    """Read a YAML file (a ``what``: config, sweep or batch file) that must hold a mapping with no key given
    twice; a one-line ConfigError otherwise."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, expected a YAML file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}); save it as UTF-8") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    data = load_yaml_text(text, str(path))
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections, got {type(data).__name__}")
    return data


def validate_config(model: type[M], data: dict[str, Any], source: str = "config") -> M:
    """``model`` built from ``data``; a one-line ConfigError naming every bad key otherwise."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, model)) from None


def load_config_file(model: type[M], path: str | Path | None = None, overrides: Iterable[str] = ()) -> M:
    """Defaults, then the YAML file at ``path`` (if any), then ``--set`` overrides."""
    data = read_yaml_mapping(path) if path is not None else {}
    overrides = list(overrides)
    source = str(path) if path is not None else "config"
    if overrides:
        data = apply_overrides(data, overrides, model)
        source += " with --set " + " ".join(overrides)
    return validate_config(model, data, source)


def to_yaml(config: BaseModel) -> str:
    """The config as plain YAML (the order of the models' fields)."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)


def commented_yaml(config: BaseModel, indent: int = 0) -> str:
    """Render a config as YAML with each field's description as a trailing comment.

    ``configs/default.yaml`` is this rendering of the defaults (``featmap config`` prints it).
    """
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
