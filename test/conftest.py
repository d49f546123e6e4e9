from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from hydro_ros.contract.machine import load_machine_config

REPO = Path(__file__).resolve().parent.parent
SAM_CONFIG = REPO / "config" / "sam.yaml"
K70M = REPO / "config" / "k70m.yaml"


@pytest.fixture(scope="session")
def sam_config() -> dict:
    return load_machine_config(SAM_CONFIG)


@pytest.fixture(scope="session")
def k70m() -> dict:
    from hydro_ros.models.crane import load_crane

    return load_crane(K70M)[1]


SHARED_ENV = "HYDRO_ROS_TEST_SHARED"  # make test's folder for what its three pytest runs build once (it empties it first;
# set by hand, emptying it after a code change is yours to do: a build is named, not keyed by the code)


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], Any]) -> Any:
    """What ``build(folder)`` returns, built by the first pytest process that asks and read back by the others: a module
    fixture is otherwise built once per xdist worker that runs one of its tests (the fleet's month of recordings: 40 s
    each), and again by each tier of ``make test`` that has a test on it (SHARED_ENV: the tiers share one folder). A build
    that failed fails the others at once with its error; a half-written result is never read (written aside, then moved)."""
    if os.environ.get(SHARED_ENV):
        shared = Path(os.environ[SHARED_ENV])
        shared.mkdir(parents=True, exist_ok=True)
    else:
        shared = tmp_path_factory.getbasetemp()
        if os.environ.get("PYTEST_XDIST_WORKER"):
            shared = shared.parent  # the workers' base directories are siblings under the run's own
    folder, result, failed = shared / f"once-{name}", shared / f"once-{name}.pickle", shared / f"once-{name}.failed"
    with open(shared / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if failed.exists():
            pytest.fail(f"built_once({name!r}) failed in another process: {failed.read_text()}", pytrace=False)
        if not result.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            try:
                built = build(folder)
            except Exception as exc:  # not an interrupt or a skip: those say nothing of the build
                failed.write_text(f"{type(exc).__name__}: {exc}"[:2000])
                raise
            aside = result.with_suffix(".writing")
            aside.write_bytes(pickle.dumps(built))
            os.replace(aside, result)
        return pickle.loads(result.read_bytes())


# the tiers: `make test-fast` runs what has none of these marks (setup.cfg [tool:pytest] describes them)
TIER_FIXTURES = {"ros_domain": "ros_graph", "chromium": "browser"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that starts nodes or a browser is marked by the fixture it takes, so no mark can be forgotten."""
    for item in items:
        for fixture, mark in TIER_FIXTURES.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(getattr(pytest.mark, mark))


@pytest.fixture
def chromium() -> None:
    """Debian's chromium, or a skip (a failure in CI)."""
    from test.browser import require_chromium

    require_chromium()


@pytest.fixture
def ros_domain() -> int:
    """A test-unique ROS domain on localhost only (brief: never leave the machine, never cross)."""
    # a pytest run draws from TEST_ROS_DOMAINS (usable ids 10-229; `make test` gives its two concurrent runs halves), and its
    # parallel workers (pytest-xdist: gw0, gw1, ...) from ranges of their own within it
    low, high = (int(v) for v in os.environ.get("TEST_ROS_DOMAINS", "10-229").split("-"))
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    width = (high - low + 1) // max(workers, 1)
    domain = low + width * worker + (os.getpid() + hash(os.environ.get("PYTEST_CURRENT_TEST", ""))) % width
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    return domain
