"""Headless Chromium for the report tests: open an HTML file from disk and read what its script recorded.

Not a test module (pytest collects ``test_*.py`` only). Without a Chromium
binary the calling test is skipped, unless ``SLAM2D_REQUIRE_BROWSER=1`` is set
(``make test`` sets it and installs Chromium), in which case it fails.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

REQUIRE_ENV = "SLAM2D_REQUIRE_BROWSER"
TIMEOUT_S = 60
_FALLBACK = Path("/usr/bin/chromium")


def find_chromium() -> str | None:
    """The Chromium binary on PATH (``chromium``, ``chromium-browser``) or at /usr/bin/chromium, else None."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found:
        return found
    return str(_FALLBACK) if _FALLBACK.is_file() else None


def chromium_or_skip() -> str:
    """The Chromium binary; skip the test without one, or fail when the environment requires it."""
    binary = find_chromium()
    if binary is None:
        reason = "no Chromium binary (chromium, chromium-browser or /usr/bin/chromium); install it with apt-get install chromium"
        if os.environ.get(REQUIRE_ENV) == "1":
            pytest.fail(f"{reason}; {REQUIRE_ENV}=1 requires the browser test to run")
        pytest.skip(reason)
    return binary


def dump_dom(html_path: str | Path, *, timeout: float = TIMEOUT_S, width: int = 1280) -> str:
    """The DOM of a local HTML file after it loaded and ran its scripts, as headless Chromium serialises it.

    The window is ``width`` pixels wide (a laptop's 1280 by default), so layout checks see that width.
    """
    binary = chromium_or_skip()
    url = Path(html_path).resolve().as_uri()
    with tempfile.TemporaryDirectory(prefix="slam2d-chromium-", ignore_cleanup_errors=True) as profile:
        command = [
            binary, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}", f"--window-size={width},900", "--virtual-time-budget=10000",
            "--dump-dom", url,
        ]
        try:
            result = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"chromium did not finish rendering {url} within {timeout:g} s")
    if result.returncode != 0 or not result.stdout.strip():
        tail = "\n".join(result.stderr.strip().splitlines()[-5:])
        pytest.fail(f"chromium exited with status {result.returncode} and {len(result.stdout)} bytes of DOM:\n{tail}")
    return result.stdout


def images_loaded(html_path: str | Path) -> tuple[int, int]:
    """``(loaded, total)`` images, from the ``data-images-loaded="L/T"`` attribute the report's script sets."""
    dom = dump_dom(html_path)
    match = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom)
    if match is None:
        pytest.fail("the rendered page has no data-images-loaded attribute: its load script did not run")
    return int(match.group(1)), int(match.group(2))
