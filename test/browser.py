"""Headless Debian Chromium driven by Playwright (its own browser downloads are not possible here)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from hydro_ros.hmi.headless import CHROMIUM, CHROMIUM_ARGS


def require_chromium() -> None:
    """Skip where no browser is installed; in CI a missing browser is a failure, not a skip."""
    if not CHROMIUM.exists():
        message = f"{CHROMIUM}: not installed (Debian package chromium; .ci/run and make test install it)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)


@contextmanager
def chromium_page(width: int = 1280, height: int = 1000) -> Iterator:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield browser.new_page(viewport={"width": width, "height": height})
        finally:
            browser.close()
