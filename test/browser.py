"""Headless Debian Chromium driven by Playwright (its own browser downloads are not possible here)."""

from __future__ import annotations

import os

import pytest

from hydro_ros.hmi.headless import CHROMIUM


def require_chromium() -> None:
    """Skip where no browser is installed; in CI a missing browser is a failure, not a skip."""
    if not CHROMIUM.exists():
        message = f"{CHROMIUM}: not installed (Debian package chromium; .ci/run and make test install it)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
