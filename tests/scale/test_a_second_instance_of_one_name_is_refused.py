"""Two processes under one instance name would share a liveliness token and a checkpoint
key, and each would believe it owns the same sensors: the second one to start refuses to,
with a message naming the clash."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from simpletrack.spawn import free_port, serve_command
from tests.scale.fleet import Group
from tests.service_helpers import ROOT


def test_a_second_process_with_a_live_instance_name_exits_with_a_clear_message(
    tmp_path: Path,
) -> None:
    group = Group(tmp_path)
    try:
        group.add("m-a")
        cmd = serve_command(f"tcp/127.0.0.1:{free_port()}", free_port(), "m-a")
        cmd += ["--connect", group.endpoints()[0]]
        env = {**os.environ, "NO_COLOR": "1"}
        out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
        assert out.returncode == 2, out.stderr
        assert "instance 'm-a' is already live on prefix 'fleet'" in out.stderr
        assert "Traceback" not in out.stderr
        assert group.members["m-a"].http("/readyz")[0] == 200  # the first one is untouched
    finally:
        group.stop_all()
