"""A node's parameters declared once: descriptors with unit and range, values refused with a reason.

Each node module declares its parameters as the fields of a dataclass, each field's :class:`Spec` (default, unit and
description, range) in its metadata (:func:`parameter`, :func:`declared`); ``PARAMETERS`` is that table read off the
fields. :func:`declare` declares them on the node with a ``ParameterDescriptor`` (description, range, ``read_only`` for
what is read once at start), checks every value set at start (``-p``, a params file) or at run time (``ros2 param set``)
and refuses a bad one with its reason, and returns the dataclass holding the current values, typed
(``self.params.stale_timeout``); accepted run-time changes update it and reach the node's callback. Names made at run
time (a fault per cylinder) are a :class:`Parameters` table of their own. The same tables write the commented params
files in ``config/params/`` (robot_localization's ``params/*.yaml`` habit).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from hydro_ros.contract.config import config_dir
from hydro_ros.contract.errors import InputError

PACKAGE_SHARE = "$(find-pkg-share hydro_ros)"  # expanded by launch_ros (ParameterFile with allow_substs)

SPEC = "hydro_ros.parameter"  # the key of a field's Spec in its metadata

BUILT_IN = {"use_sim_time": "take the time from /clock (a bag replay or a simulator) instead of the system clock"}


@dataclass(frozen=True)
class Spec:
    """One parameter: its default, what it is (with its unit), and what values it takes."""

    default: Any
    description: str
    low: float | None = None  # inclusive
    high: float | None = None  # inclusive
    read_only: bool = True  # read once at start; False: applied while running
    choices: tuple[str, ...] = ()
    existing_file: bool = False  # a path that must name a file ("" allowed where the default is "")

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is refused, or None."""
        if isinstance(value, float) and not math.isfinite(value):
            return "must be a finite number"
        if self.low is not None and value < self.low:
            return f"must be >= {self.low:g}"
        if self.high is not None and value > self.high:
            return f"must be <= {self.high:g}"
        if self.choices and value not in self.choices:
            return f"must be one of {', '.join(repr(choice) for choice in self.choices)}"
        if self.existing_file and (value or self.default) and not Path(value).is_file():
            return "no such file"
        if isinstance(self.default, list) and isinstance(value, list) and len(value) != len(self.default):
            return f"must have {len(self.default)} elements"
        return None

    def range_text(self) -> str:
        if self.choices:
            return " | ".join(choice or '""' for choice in self.choices)
        if self.low is None and self.high is None:
            return ""
        return f"[{'-inf' if self.low is None else _number(self.low)}, {'inf' if self.high is None else _number(self.high)}]"

    def descriptor(self, name: str) -> ParameterDescriptor:
        constraints = "; ".join(part for part in (
            f"range {self.range_text()}" if self.range_text() else "", "an existing file" if self.existing_file else "",
            "read once at start" if self.read_only else "may change while running") if part)
        descriptor = ParameterDescriptor(name=name, description=self.description, read_only=self.read_only,
                                         additional_constraints=constraints)
        if isinstance(self.default, bool) or (self.low is None and self.high is None):
            return descriptor
        low = -math.inf if self.low is None else self.low
        high = math.inf if self.high is None else self.high
        if isinstance(self.default, int):
            big = 2**63 - 1
            descriptor.integer_range = [IntegerRange(from_value=int(max(low, -big)), to_value=int(min(high, big)), step=0)]
        elif isinstance(self.default, float):
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
        return descriptor


def declared(spec: Spec) -> Any:
    """A dataclass field declaring one node parameter: ``spec``'s default, ``spec`` in the field's metadata."""
    if isinstance(spec.default, list):
        return field(default_factory=lambda: list(spec.default), metadata={SPEC: spec})
    return field(default=spec.default, metadata={SPEC: spec})


def parameter(default: Any, description: str, low: float | None = None, high: float | None = None, **facts: Any) -> Any:
    """``declared(Spec(...))``: a field declaring a parameter of this node alone."""
    return declared(Spec(default, description, low, high, **facts))


def specs_of(declaration: type) -> dict[str, Spec]:
    """The parameters a dataclass declares, in field order."""
    return {item.name: item.metadata[SPEC] for item in fields(declaration)}


Declaration = TypeVar("Declaration")


def declare(node: Node, declaration: type[Declaration], on_change: Callable[[str, Any], None] | None = None,
            defaults: dict[str, Any] | None = None) -> Declaration:
    """Declares the parameters of ``declaration``'s fields on ``node`` (see :class:`Parameters`); returns an instance of it
    holding their values, kept current as run-time changes are accepted (before ``on_change`` hears of them)."""
    table = Parameters(node, specs_of(declaration), on_change, defaults)
    table.mirror = declaration(**table.values)
    return table.mirror


class Parameters:
    """Declares ``specs`` on ``node``; ``values[name]`` is the current value of each.

    ``on_change(name, value)`` is called for each accepted run-time change of a non-read-only parameter.
    A bad value at start raises InputError (the node exits with that line); at run time it is refused.
    """

    def __init__(self, node: Node, specs: dict[str, Spec], on_change: Callable[[str, Any], None] | None = None,
                 defaults: dict[str, Any] | None = None) -> None:
        self.specs = specs
        self.values: dict[str, Any] = {}
        self.mirror: Any = None  # the dataclass `declare` returned, if any: its fields follow the values
        self._on_change = on_change
        for name, description in BUILT_IN.items():  # rclpy declares these without a description
            if node.has_parameter(name) and not node.describe_parameter(name).description:
                descriptor = node.describe_parameter(name)
                descriptor.description = description
                node.set_descriptor(name, descriptor)
        node.add_on_set_parameters_callback(self._check)
        node.add_post_set_parameters_callback(self._apply)
        for name, spec in specs.items():
            default = (defaults or {}).get(name, spec.default)
            try:
                value = node.declare_parameter(name, default, spec.descriptor(name)).value
            except (InvalidParameterValueException, ParameterException) as exc:
                reason = str(exc.args[0]).split("Reason: ", 1)[-1].removesuffix(f": {name}")
                raise InputError(f"parameter {reason}" if reason.startswith(name) else f"parameter {name}: {reason}") from None
            self.values[name] = value

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            spec = self.specs.get(parameter.name)
            if spec is None:
                continue
            reason = spec.problem(parameter.value)
            if reason:
                return SetParametersResult(successful=False, reason=f"{parameter.name} = {parameter.value!r} refused: {reason}")
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name not in self.specs:
                continue
            changed = parameter.name in self.values and self.values[parameter.name] != parameter.value
            self.values[parameter.name] = parameter.value
            if self.mirror is not None:
                setattr(self.mirror, parameter.name, parameter.value)
            if changed and self._on_change is not None:
                self._on_change(parameter.name, parameter.value)


def params_yaml(node_name: str, specs: dict[str, Spec], values: dict[str, Any] | None = None) -> str:
    """A ``ros__parameters`` block for one node, each parameter commented with unit, default and range."""
    lines = [f"{node_name}:", "  ros__parameters:"]
    for name, spec in specs.items():
        value = (values or {}).get(name, spec.default)
        facts = [f"default {_yaml_scalar(_shown(spec.default))}"]
        if spec.range_text():
            facts.append(f"range {spec.range_text()}")
        facts.append("read at start" if spec.read_only else "settable while running")
        lines.append(f"    # {spec.description} ({'; '.join(facts)})")
        lines.append(f"    {name}: {_yaml_scalar(value)}")
    return "\n".join(lines) + "\n"


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else f"{value:g}"


def _shown(default: Any) -> Any:
    """A default as a params file may write it: the package's own files through $(find-pkg-share hydro_ros)."""
    if isinstance(default, str) and default.startswith(str(config_dir()) + "/"):
        return f"{PACKAGE_SHARE}/config/{Path(default).name}"
    return default


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if "e" not in repr(value) else f"{value:.6e}".replace("e", "e+", 1).replace("e+-", "e-")
    if isinstance(value, list):
        return "[" + ", ".join(_yaml_scalar(item) for item in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)
