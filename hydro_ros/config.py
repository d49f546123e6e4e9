"""Machine configs (contract section 3): load, coerce numbers, validate, locate defaults."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

_REQUIRED_SAM_KEYS = (
    "machine",
    "sample_rate_hz",
    "actuators",
    "supply_pressure",
    "tank_pressure",
    "sensors",
)


class ConfigError(ValueError):
    """A machine config is missing, unreadable or inconsistent."""


def _coerce_numbers(node: Any) -> Any:
    # PyYAML 1.1 reads '1.4e9' (no sign in the exponent) as a string: convert where it parses.
    if isinstance(node, dict):
        return {key: _coerce_numbers(value) for key, value in node.items()}
    if isinstance(node, list):
        return [_coerce_numbers(value) for value in node]
    if isinstance(node, str):
        try:
            return float(node)
        except ValueError:
            return node
    return node


def load_machine_config(path: str | Path) -> dict[str, Any]:
    """Read ``config/<machine>.yaml``; raise ConfigError with a one-line reason on bad input."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config {path}: no such file")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        first_line = str(exc).splitlines()[0]
        raise ConfigError(f"config {path}: not valid YAML ({first_line})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"config {path}: expected a mapping at the top level")
    if "extends" in raw:
        # a variant of another machine config: that file, with this file's keys merged over it
        base_path = path.parent / str(raw.pop("extends"))
        if base_path.resolve() == path.resolve():
            raise ConfigError(f"config {path}: extends itself")
        base = load_machine_config(base_path)
        base.pop("_path", None)
        raw = with_overrides(base, raw)
    if "fitted" in raw:
        # values a tool fitted (hydro-ros fdi-fit) live in their own block at the end of the file
        fitted = raw.pop("fitted")
        raw = with_overrides(raw, fitted if isinstance(fitted, dict) else {})
    config = _coerce_numbers(raw)
    missing = [key for key in _REQUIRED_SAM_KEYS if key not in config]
    if missing:
        raise ConfigError(f"config {path}: missing key(s) {', '.join(missing)}")
    if not config["actuators"]:
        raise ConfigError(f"config {path}: no actuators")
    config["_path"] = str(path.resolve())
    return config


def with_overrides(config: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """Deep copy of ``config`` with nested ``overrides`` merged in (used for model mismatch)."""
    merged = copy.deepcopy(config)

    def merge(target: dict[str, Any], patch: dict[str, Any]) -> None:
        for key, value in patch.items():
            if isinstance(value, dict) and isinstance(target.get(key), dict):
                merge(target[key], value)
            else:
                target[key] = value

    merge(merged, overrides)
    return merged


def config_dir() -> Path:
    """The installed ``share/hydro_ros/config`` when on an ament prefix, else the source tree's."""
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        try:
            return Path(get_package_share_directory("hydro_ros")) / "config"
        except (PackageNotFoundError, KeyError, ValueError, OSError):
            pass
    except ImportError:
        pass
    return Path(__file__).resolve().parent.parent / "config"


def default_config_path(machine: str = "sam") -> Path:
    return config_dir() / f"{machine}.yaml"
