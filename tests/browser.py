"""A real browser for the page tests: Debian's Chromium driven by Playwright (no browser download).

tests/run.sh installs Debian's ``chromium`` when it is missing (as root); Playwright comes with
the dev extra. Without either, the browser tests skip and say why.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from conftest import processes_naming

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage"]
"""What Chromium needs here: no sandbox as root, and no calls home (this machine has no network)."""


@contextlib.asynccontextmanager
async def chromium(profile: Path) -> AsyncIterator[object]:
    """A headless Chromium with its own profile folder (so a test can find and kill its processes);
    yields Playwright's browser context."""
    try:
        from playwright.async_api import async_playwright
    except ImportError:
        pytest.skip("Playwright is not installed (pip install -e '.[dev]')")
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (tests/run.sh installs it as root: apt-get install chromium)")
    async with async_playwright() as p:
        context = await p.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, args=ARGS, headless=True,
            viewport={"width": 1280, "height": 860})
        try:
            yield context
        finally:
            with contextlib.suppress(Exception):
                await context.close()


def kill_browser(profile: Path) -> int:
    """SIGKILL every process of the browser with this profile, as a crash or a pulled cable would
    end it: no page handler runs. Returns how many were killed."""
    pids = processes_naming(str(profile))
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return len(pids)
