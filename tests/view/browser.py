"""Headless chromium for the view's page: the binary (skip without one, fail under CI=true),
a screenshot of a URL, and its DOM once the page's scripts ran."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
WINDOW = (1000, 700)


def need_chromium() -> str:
    exe = CHROMIUM if os.access(CHROMIUM, os.X_OK) else shutil.which("chromium")
    if exe is None:
        message = "chromium is not installed: the page cannot be drawn (apt-get install chromium)"
        if os.environ.get("CI") == "true":
            pytest.fail(message)  # CI installs it (scripts/setup.sh): it must run these
        pytest.skip(message)
    return exe


def _run(url: str, profile: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """Chromium on ``url`` with ``extra`` flags. Virtual time waits for the page's fetch of
    /state.json, so what comes out is drawn from it (``live=0`` in the URL: an event stream
    never finishes loading and would hold virtual time forever)."""
    exe = need_chromium()
    cmd = [
        exe,
        "--headless=new",
        "--disable-gpu",
        "--no-sandbox",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        f"--user-data-dir={profile}",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
        "--virtual-time-budget=5000",
        *extra,
        url,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def screenshot(url: str, out: Path) -> Path:
    """The page at ``url`` as a PNG of ``WINDOW`` pixels."""
    done = _run(url, out.parent / "chromium-profile", f"--screenshot={out}")
    assert done.returncode == 0 and out.is_file(), done.stderr[-2000:]
    return out


def dump_dom(url: str, workdir: Path) -> str:
    """The page's DOM (its panel and legend as the scripts filled them), as HTML."""
    done = _run(url, workdir / "chromium-profile", "--dump-dom")
    assert done.returncode == 0 and "<canvas" in done.stdout, done.stderr[-2000:]
    return done.stdout
