"""The test suite's own sharing of expensive fixtures (test/conftest.py built_once)."""

from __future__ import annotations

import pytest

from test.conftest import SHARED_ENV, built_once


def test_a_fixture_is_built_once_and_a_failed_build_fails_the_others_with_its_error(tmp_path, tmp_path_factory, monkeypatch):
    monkeypatch.setenv(SHARED_ENV, str(tmp_path / "shared"))
    builds = []

    def build(folder):
        builds.append(folder)
        (folder / "made").write_text("x")
        return {"folder": folder}

    first = built_once(tmp_path_factory, "thing", build)
    assert built_once(tmp_path_factory, "thing", build) == first and len(builds) == 1 and (first["folder"] / "made").is_file()
    assert not list((tmp_path / "shared").glob("*.writing"))

    def broken(folder):
        (folder / "half").write_text("x")
        raise RuntimeError("the recorder refused")

    with pytest.raises(RuntimeError, match="the recorder refused"):
        built_once(tmp_path_factory, "other", broken)
    with pytest.raises(pytest.fail.Exception, match="failed in another process: RuntimeError: the recorder refused"):
        built_once(tmp_path_factory, "other", build)
