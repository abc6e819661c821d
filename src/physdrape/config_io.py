"""Strict loading of frozen-dataclass configs from YAML/JSON mappings (an unknown key is an error)."""

from __future__ import annotations

import dataclasses
import enum
import typing
from pathlib import Path

import yaml


class ConfigError(ValueError):
    """A configuration file or mapping that does not match the expected fields."""


def from_mapping(cls, data, *, where: str = "config"):
    """Build dataclass `cls` from a mapping, recursing into dataclass-typed fields.

    Unknown keys raise `ConfigError` naming the key and listing the known ones; missing keys take
    the dataclass defaults.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; known keys: {sorted(known)}")
    values = {}
    for name, value in data.items():
        kind = hints[name]
        if dataclasses.is_dataclass(kind):
            value = from_mapping(kind, value, where=f"{where}.{name}")
        elif isinstance(kind, type) and issubclass(kind, enum.Enum):
            try:
                value = kind(value)
            except ValueError:
                raise ConfigError(f"{where}.{name}: {value!r} is not one of {[m.value for m in kind]}") from None
        elif kind is float and isinstance(value, int):
            value = float(value)
        values[name] = value
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def to_mapping(config) -> dict:
    """A JSON/YAML-ready dict of a (nested) dataclass config; enums as their values."""

    def plain(value):
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, enum.Enum):
            return value.value
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return plain(config)


def read_yaml(path: str | Path, *, what: str = "config"):
    """The data of a YAML (or JSON) file; ConfigError when it is missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{what} file not found: {path}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {exc}") from None


def load_config(cls, path: str | Path):
    """Read a YAML (or JSON) file into `cls` strictly."""
    return from_mapping(cls, read_yaml(path), where=str(path))
