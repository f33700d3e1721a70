"""``simpletrack --version`` names the installed distribution's version (what a bug report
needs), and exits 0 without asking for a command."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import version

from tests.service_helpers import ROOT


def test_version_prints_the_installed_distributions_version() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "simpletrack.cli.main", "--version"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"simpletrack {version('simpletrack-service')}"
