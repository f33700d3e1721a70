"""The ``simpletrack`` entry point imports only the module of the command it runs: the help
lists every command from ``COMMANDS``, a client-side command loads none of the service's
dependencies, and a missing dependency is named by the extra that brings it."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from simpletrack.cli.main import COMMANDS, build_parser, extra_hint
from tests.service_helpers import ROOT


def test_every_command_has_its_own_help_line_in_the_listing() -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert helps == COMMANDS


@pytest.mark.parametrize("command", ["status", "watch", "view", "record", "replay", "bridge"])
def test_a_client_side_command_loads_no_service_module(command: str) -> None:
    code = (
        "import sys\n"
        "from simpletrack.cli.main import main\n"
        f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
        "print(' '.join(sorted(sys.modules)), file=sys.stderr)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    loaded = set(out.stderr.split())
    heavy = {"pydantic", "pydantic_settings", "scipy", "prometheus_client", "simpletrack.core"}
    heavy |= {"simpletrack.server", "simpletrack.cli.serve", "simpletrack.datasets", "mcap"}
    assert not heavy & loaded, heavy & loaded


def test_a_missing_module_names_its_extra() -> None:
    assert extra_hint("pydantic_settings.main") == (
        "needs the service extra: pip install 'simpletrack-service[service]' "
        "(missing module 'pydantic_settings.main')"
    )
    assert extra_hint("matplotlib") is not None and "[plot]" in str(extra_hint("matplotlib"))
    assert extra_hint("simpletrack.core") is None  # ours: a bug, not a missing extra
