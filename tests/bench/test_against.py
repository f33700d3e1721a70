"""``bench core --against REF``: both sides really run (each from its own tree), the table
has both columns and ratios, the throwaway worktree is gone afterwards, a bad REF is a clear
error. No timed assertions: the figures themselves are whatever the machine gives."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# The synthetic sweep alone: no data needed, a few seconds per side.
TINY = ["--scenes", "0", "--kitti-sequences", "0", "--sizes", "20", "--sweep-frames", "3"]

pytestmark = pytest.mark.skipif(
    subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True).returncode
    != 0,
    reason="needs the project as a git checkout",
)


def bench(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(str(ROOT / f) for f in ("service", "schemas", "clients"))
    return subprocess.run(
        [sys.executable, "-m", "simpletrack.cli.main", "bench", "core", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )


def worktrees() -> str:
    return subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "list"], capture_output=True, text=True, check=True
    ).stdout


def test_against_head_measures_both_sides_and_cleans_up(tmp_path: Path) -> None:
    out = tmp_path / "against.json"
    done = bench(*TINY, "--against", "HEAD", "--rounds", "2", "--json", str(out))
    assert done.returncode == 0, done.stderr
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert f"HEAD ({head[:9]})" in done.stdout
    row = next(line for line in done.stdout.splitlines() if "sweep 20 boxes p50 ms" in line)
    cells = row.split()
    assert len(cells) == 8 and all(float(c) > 0 for c in cells[-3:])  # this, REF, ratio
    doc = json.loads(out.read_text())
    assert doc["commit"] == head and doc["rounds"] == 2
    assert len(doc["runs"]["this"]) == len(doc["runs"]["ref"]) == 2
    # Each side imported the tracker from its own tree: this checkout, and REF's worktree.
    assert Path(doc["packages"]["this"]).resolve().is_relative_to(ROOT.resolve())
    ref_package = Path(doc["packages"]["ref"])
    assert not ref_package.resolve().is_relative_to(ROOT.resolve())
    assert not ref_package.exists()  # the worktree is removed afterwards
    assert "simpletrack-against-" not in worktrees()


def test_a_ref_that_names_no_commit_is_a_clear_error() -> None:
    done = bench(*TINY, "--against", "no-such-revision-xyz")
    assert done.returncode == 2
    assert "--against 'no-such-revision-xyz' names no commit" in done.stderr
    assert "Traceback" not in done.stderr
    assert "simpletrack-against-" not in worktrees()
