"""Configuration: ``configs/default.toml`` is the schema and the defaults.

Every key mixcount knows is in ``default.toml``. Other files (``quick.toml``, a user's ``--config``)
and ``--set section.key=value`` overrides may only change keys that exist there; an unknown key or a
value of the wrong type is a :class:`ConfigError`. The result is a :class:`Config`: a frozen, hashable
view whose sections each area turns into its own frozen dataclass (``SceneConfig.from_config(cfg)``...).
"""

from __future__ import annotations

import copy
import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from mixcount.errors import ConfigError
from mixcount.resources import data_dir

CONFIG_DIR = data_dir("configs")
DEFAULT_CONFIG = CONFIG_DIR / "default.toml"


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None


def _check_type(key: str, default: Any, value: Any) -> Any:
    """Return ``value`` coerced to the type of ``default`` or raise ConfigError."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(default, str):
        if isinstance(value, str):
            return value
    elif isinstance(default, list):
        if isinstance(value, list):
            return value
    else:
        return value
    raise ConfigError(
        f"config key {key!r} expects {type(default).__name__}, got {type(value).__name__} ({value!r})"
    )


def _merge(base: dict[str, Any], overlay: Mapping[str, Any], prefix: str, source: str) -> None:
    for key, value in overlay.items():
        dotted = f"{prefix}{key}"
        if key not in base:
            raise ConfigError(f"unknown config key {dotted!r} in {source}")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(f"config key {dotted!r} is a section, got {value!r} in {source}")
            _merge(base[key], value, dotted + ".", source)
        else:
            base[key] = _check_type(dotted, base[key], value)


def _parse_override(text: str) -> tuple[list[str], Any]:
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    key, raw = text.split("=", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # bare strings: --set compose.split=test
    return key.strip().split("."), value


def _freeze(value: Any) -> Any:
    if isinstance(value, dict):
        return MappingProxyType({k: _freeze(v) for k, v in value.items()})
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def _thaw(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _thaw(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [_thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class Config:
    """Read-only configuration. ``cfg["scene"]["n_objects"]`` or ``cfg.get("scene.n_objects")``."""

    data: Mapping[str, Any]
    sources: tuple[str, ...] = field(default=())

    def __getitem__(self, section: str) -> Mapping[str, Any]:
        try:
            return self.data[section]
        except KeyError:
            raise ConfigError(f"unknown config section {section!r}") from None

    def get(self, dotted: str) -> Any:
        node: Any = self.data
        for part in dotted.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise ConfigError(f"unknown config key {dotted!r}")
            node = node[part]
        return node

    def to_dict(self) -> dict[str, Any]:
        return _thaw(self.data)

    @property
    def hash(self) -> str:
        """Stable short hash of every value: recorded in stage metadata and dataset.json."""
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def with_overrides(self, overrides: Mapping[str, Any]) -> "Config":
        """Return a copy with dotted keys replaced (checked like any override)."""
        data = self.to_dict()
        for dotted, value in overrides.items():
            nested: dict[str, Any] = {}
            node = nested
            parts = dotted.split(".")
            for part in parts[:-1]:
                node = node.setdefault(part, {})
            node[parts[-1]] = value
            _merge(data, nested, "", "override")
        return Config(_freeze(data), self.sources + ("overrides",))


def load_config(
    files: list[Path | str] | tuple[Path | str, ...] = (),
    overrides: list[str] | tuple[str, ...] = (),
) -> Config:
    """Load default.toml, then each of ``files`` in order, then ``section.key=value`` overrides."""
    data = copy.deepcopy(_read_toml(DEFAULT_CONFIG))
    sources = [str(DEFAULT_CONFIG)]
    for f in files:
        path = Path(f)
        if not path.exists() and (CONFIG_DIR / path).exists():
            path = CONFIG_DIR / path
        if not path.exists() and (CONFIG_DIR / f"{path}.toml").exists():
            path = CONFIG_DIR / f"{path}.toml"
        _merge(data, _read_toml(path), "", str(path))
        sources.append(str(path))
    for text in overrides:
        parts, value = _parse_override(text)
        nested: dict[str, Any] = {}
        node = nested
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
        _merge(data, nested, "", f"override {text!r}")
        sources.append(f"set:{text}")
    return Config(_freeze(data), tuple(sources))
