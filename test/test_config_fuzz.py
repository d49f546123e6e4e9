"""Machine configs with random damage: every shipped config with keys removed and values replaced by the wrong type, NaN,
inf, a negative or an absurd number. Each is either a machine the monitor can be built for, or one line naming what
is wrong; never a traceback, never an accepted machine whose monitor cannot be built."""

from __future__ import annotations

import copy
import math
import os
import warnings
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hydro_ros.contract.config import read_config
from hydro_ros.contract.crane import parse_planning
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import parse_machine
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.models.crane import Crane
from test.conftest import REPO

# the shipped configs, and the K70M in the crane form of earlier releases (converted on reading)
CONFIGS = ("sam", "sam_mobile", "sam_mems", "boom_arm", "k70m", "excavator", "crane_form/k70m")
DAMAGE = (None, "", "x", True, [], {}, [1.0, 2.0], math.nan, math.inf, -math.inf, -1.0, 0.0, 1e308, -1e308, 3, "1.4e9")
REMOVE = object()
EXAMPLES = os.environ.get("FUZZ_EXAMPLES")  # more, and freshly drawn, when set (e.g. 400); else 60 of a fixed draw


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path and list index in the mapping, sections and leaves."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        out.append((*prefix, key))
        out += _paths(value, (*prefix, key))
    return out


def _damaged(config: dict, path: tuple, value: Any) -> dict:
    damaged = copy.deepcopy(config)
    parent = damaged
    for key in path[:-1]:
        parent = parent[key]
    if value is REMOVE:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return damaged


@pytest.mark.parametrize("name", CONFIGS)
def test_a_damaged_config_is_a_working_machine_or_one_line(name):
    source = REPO / ("test" if name.startswith("crane_form") else "config") / f"{name}.yaml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # the crane form's: said once, not under test here
        config = read_config(source, required=("machine",), nonempty="machine")
    paths = _paths(config)

    @settings(max_examples=int(EXAMPLES or 60), deadline=None, suppress_health_check=[HealthCheck.too_slow],
              derandomize=not EXAMPLES)
    @given(st.lists(st.tuples(st.sampled_from(paths), st.sampled_from((REMOVE, *DAMAGE))), min_size=1, max_size=3))
    def damaged(changes):
        mapping = config
        for path, value in changes:
            try:
                mapping = _damaged(mapping, path, value)
            except (KeyError, IndexError, TypeError):  # an earlier change removed or replaced the path's parent
                continue
        def monitor() -> None:
            FdiMonitor(parse_machine(copy.deepcopy(mapping), Path(source)))  # accepted builds a monitor, or a refusal

        def planner() -> None:
            Crane(parse_planning(copy.deepcopy(mapping), Path(source)))

        for tool in (monitor, planner) if config.get("kind") == "crane" or "planner" in config else (monitor,):
            try:
                tool()
            except InputError as refused:
                message = str(refused)
                assert message and "\n" not in message and "Traceback" not in message, message

    damaged()
