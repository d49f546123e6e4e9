"""Debian's Chromium for the HMI's page in its test and benchmark, headless (Playwright cannot download a browser here)."""

from __future__ import annotations

import shutil
from pathlib import Path

CHROMIUM = Path(shutil.which("chromium") or "/usr/bin/chromium")
# no sync, no update checks, no QUIC: this machine's closed network refuses them, many at a time
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
