"""Config files (docs/interface.md section 3): read YAML with ``extends`` and ``fitted`` merged, coerce numbers, locate defaults.

A valve-controlled machine's config is then typed by :mod:`hydro_ros.contract.machine`."""

from __future__ import annotations

import collections.abc
import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from hydro_ros.contract.errors import InputError


class ConfigError(InputError):
    """A machine config is missing, unreadable or inconsistent."""


def plain_data(node: Any) -> Any:
    """``node`` with NumPy scalars and arrays, tuples and non-string keys made plain, as yaml.safe_dump and json write them."""
    if isinstance(node, dict):
        return {str(key): plain_data(value) for key, value in node.items()}
    if isinstance(node, (list, tuple)):
        return [plain_data(value) for value in node]
    if hasattr(node, "tolist"):  # a NumPy scalar or array
        return plain_data(node.tolist())
    return node


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


def read_config(path: str | Path, *, required: tuple[str, ...], nonempty: str) -> dict[str, Any]:
    """Read any machine config (extends / fitted merged, numbers coerced) and check its required keys."""
    path = Path(path)
    config: dict[str, Any] = _coerce_numbers(_read_merged(path))
    missing = [key for key in required if key not in config]
    if missing:
        raise ConfigError(f"config {path}: missing key(s) {', '.join(missing)}")
    if not config.get(nonempty):
        raise ConfigError(f"config {path}: no {nonempty}")
    return config


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader refusing a mapping that says a key twice (PyYAML keeps the last, and a value is lost unsaid)."""


def _unique_keys(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen = set()
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":  # << merges a mapping in; its keys are the merged one's
            continue
        key = loader.construct_object(key_node, deep=True)  # a key's own content, to name it
        if not isinstance(key, collections.abc.Hashable):
            raise yaml.constructor.ConstructorError(None, None, f"a key that is not a name: {key!r} (line {key_node.start_mark.line + 1})")
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r} (line {key_node.start_mark.line + 1})")
        seen.add(key)
    return loader.construct_mapping(node, deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_keys)


MAX_CONFIG_BYTES = 1_000_000  # the largest shipped config is 25 kB; a commissioned one with its report under 100 kB
MAX_CONFIG_VALUES = 200_000  # values a config may expand to through its YAML aliases (the shipped ones: under 5 000)


def _config_text(path: Path) -> str:
    """The file's text, refused in one line when it cannot be a config: missing, a folder, too large, not UTF-8."""
    if path.is_dir():
        raise ConfigError(f"config {path}: is a folder, not a file")
    if not path.is_file():
        raise ConfigError(f"config {path}: no such file")
    size = path.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ConfigError(f"config {path}: {size / 1e6:.1f} MB, more than a config's {MAX_CONFIG_BYTES / 1e6:g} MB")
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config {path}: not UTF-8 text (byte 0x{data[exc.start]:02X} at offset {exc.start}): "
                          "is it a YAML config?") from None


def _read_merged(path: Path, extended_by: tuple[Path, ...] = ()) -> dict[str, Any]:
    text = _config_text(path)
    try:
        raw: dict[str, Any] = unshared(yaml.load(text, Loader=_UniqueKeyLoader))  # a SafeLoader
    except yaml.YAMLError as exc:
        first_line = str(exc).splitlines()[0]
        raise ConfigError(f"config {path}: not valid YAML ({first_line})") from None
    except RecursionError:
        raise ConfigError(f"config {path}: a YAML alias contains itself") from None
    except _TooManyValues:
        raise ConfigError(f"config {path}: its YAML aliases expand to more than {MAX_CONFIG_VALUES} values "
                          "(aliases of aliases: a 'billion laughs')") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"config {path}: expected a mapping at the top level")
    if "extends" in raw:
        # a variant of another machine config: that file, with this file's keys merged over it
        extends = raw.pop("extends")
        if not isinstance(extends, str):
            raise ConfigError(f"config {path}: extends = {extends!r}: expected the path of the config it varies")
        base_path = path.parent / extends
        chain = (*extended_by, path.resolve())
        if base_path.resolve() in chain:
            cycle = [p.name for p in chain[chain.index(base_path.resolve()):]] + [base_path.name]
            raise ConfigError(f"config {path}: extends itself" if len(cycle) == 2 else
                              f"config {path}: extends a config that extends it ({' -> '.join(cycle)})")
        raw = with_overrides(_read_merged(base_path, chain), raw)
    if "fitted" in raw:
        # values a tool fitted (hydro-ros fdi fit) live in their own block at the end of the file
        fitted = raw.pop("fitted")
        raw = with_overrides(raw, fitted if isinstance(fitted, dict) else {})
    if "commissioned" in raw:
        # hydro-ros commission: the machine's identified model; the rest of the block says how it was found
        commissioned = raw.pop("commissioned")
        model = commissioned.get("model") if isinstance(commissioned, dict) else None
        if not isinstance(model, dict):
            raise ConfigError(f"config {path}: commissioned block without a model mapping")
        raw = with_overrides(raw, model)
    return raw


class _TooManyValues(Exception):
    pass


def unshared(node: Any, budget: list[int] | None = None) -> Any:
    """A copy in which no mapping or list appears twice. YAML anchors (``valve: *valve``) and ``copy.deepcopy`` share
    one object between actuators, and a patch of one actuator's entry would then change every actuator's. At most
    MAX_CONFIG_VALUES values are copied (_TooManyValues): aliases of aliases expand exponentially."""
    budget = [MAX_CONFIG_VALUES] if budget is None else budget
    budget[0] -= 1
    if budget[0] < 0:
        raise _TooManyValues
    if isinstance(node, dict):
        return {key: unshared(value, budget) for key, value in node.items()}
    if isinstance(node, list):
        return [unshared(value, budget) for value in node]
    return copy.copy(node)


def write_extending(base: Path, out: Path, header: str, patch: dict[str, Any]) -> None:
    """A config that extends ``base`` (by its path relative to ``out``) with ``patch``, under a comment ``header``;
    written whole or not at all."""
    import os

    relative = os.path.relpath(Path(base).resolve(), Path(out).resolve().parent)
    text = header + yaml.safe_dump(plain_data({"extends": relative, **patch}), sort_keys=False, width=120)
    partial = Path(out).with_name(Path(out).name + ".partial")
    partial.write_text(text)
    partial.replace(out)


def with_overrides(config: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Copy of ``config`` with nested ``overrides`` merged in (model mismatch, calibration, commissioning)."""
    merged: dict[str, Any] = unshared(config)

    def merge(target: dict[str, Any], patch: Mapping[str, Any]) -> None:
        for key, value in patch.items():
            if isinstance(value, dict) and isinstance(target.get(key), dict):
                merge(target[key], value)
            else:
                target[key] = unshared(value)

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
    return Path(__file__).resolve().parents[2] / "config"


def default_config_path(machine: str = "sam") -> Path:
    return config_dir() / f"{machine}.yaml"
