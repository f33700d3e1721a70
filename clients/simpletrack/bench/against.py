"""``bench core --against REF``: this code and a git revision's, measured in one run.

REF's package is checked out as a throwaway detached worktree (outside the checkout, removed
afterwards, also on failure or Ctrl-C). Each round runs the same ``bench core`` command once
with this code and once with REF's, each in a fresh interpreter (the same Python, PYTHONPATH
on the side's three source folders), the order alternating from round to round so that
neither side always runs on the warmer machine. Each figure is the median over the rounds;
the ratio is REF / this for times and this / REF for throughput: above 1, this code is faster.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[3]
SOURCE_FOLDERS = ("service", "schemas", "clients")
# (figure, path into a side's JSON, higher is better)
_LOAD_FIGURES = (
    ("p50 ms", ("latency", "p50_ms"), False),
    ("p99 ms", ("latency", "p99_ms"), False),
    ("frames/s", ("frames_per_s",), True),
)


class AgainstError(Exception):
    """REF cannot be measured: not a revision, not a git checkout, its bench failed."""


@dataclass(frozen=True, slots=True)
class Side:
    label: str
    root: Path

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(str(self.root / f) for f in SOURCE_FOLDERS)
        return env


def _git(*args: str) -> str:
    try:
        done = subprocess.run(
            ["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=True
        )
    except FileNotFoundError as exc:
        raise AgainstError("--against needs git on the PATH") from exc
    except subprocess.CalledProcessError as exc:
        raise AgainstError(exc.stderr.strip() or f"git {' '.join(args)} failed") from exc
    return done.stdout.strip()


def resolve(ref: str) -> str:
    """REF's full commit hash; AgainstError with git's reason when it names none."""
    try:
        _git("rev-parse", "--show-toplevel")
    except AgainstError as exc:
        raise AgainstError(f"--against needs a git checkout of the project at {ROOT}") from exc
    try:
        return _git("rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}")
    except AgainstError as exc:
        raise AgainstError(f"--against {ref!r} names no commit of {ROOT}") from exc


@contextmanager
def checkout(commit: str) -> Iterator[Path]:
    """REF's tree in a temporary detached worktree, removed on the way out."""
    parent = Path(tempfile.mkdtemp(prefix="simpletrack-against-"))
    path = parent / "tree"
    _git("worktree", "add", "--detach", "--quiet", str(path), commit)
    try:
        yield path
    finally:
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)],
            capture_output=True,
            check=False,
        )
        subprocess.run(["git", "-C", str(ROOT), "worktree", "prune"], check=False)
        if parent.exists():
            import shutil

            shutil.rmtree(parent, ignore_errors=True)


def package_of(side: Side) -> str:
    """Where ``side``'s interpreter imports the tracker from: its own tree, or the run would
    measure the installed package twice (AgainstError then)."""
    code = "import simpletrack.core as c; print(c.__file__)"
    done = subprocess.run(
        [sys.executable, "-c", code], env=side.env(), capture_output=True, text=True, check=False
    )
    path = done.stdout.strip()
    if done.returncode != 0 or not Path(path).resolve().is_relative_to(side.root.resolve()):
        raise AgainstError(
            f"{side.label} imports simpletrack.core from {path or '?'}, not {side.root}"
        )
    return path


def run_side(side: Side, argv: list[str], out: Path) -> dict[str, Any]:
    """One ``bench core`` run of ``side``'s code; its JSON document."""
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "bench", "core", *argv, "--json", str(out)]
    done = subprocess.run(cmd, env=side.env(), capture_output=True, text=True, check=False)
    if done.returncode != 0 or not out.exists():
        tail = "\n".join((done.stderr or done.stdout).strip().splitlines()[-5:])
        raise AgainstError(f"the bench of {side.label} failed (exit {done.returncode}):\n{tail}")
    doc: dict[str, Any] = json.loads(out.read_text())
    return doc


def _dig(doc: dict[str, Any], path: tuple[str, ...]) -> float | None:
    cur: Any = doc
    for key in path:
        if not isinstance(cur, dict) or key not in cur:
            return None
        cur = cur[key]
    return float(cur) if isinstance(cur, int | float) else None


def figures(doc: dict[str, Any]) -> dict[str, tuple[float | None, bool]]:
    """Every comparable figure of one run: name -> (value, higher is better)."""
    out: dict[str, tuple[float | None, bool]] = {}
    for load, result in (doc.get("loads") or {}).items():
        for name, path, higher in _LOAD_FIGURES:
            out[f"{load} {name}"] = (_dig(result, path), higher)
    for point in (doc.get("sweep") or {}).get("points", []):
        out[f"sweep {point['boxes']} boxes p50 ms"] = (_dig(point, ("latency", "p50_ms")), False)
    return out


def _median(values: list[float | None]) -> float | None:
    seen = [v for v in values if v is not None]
    return statistics.median(seen) if seen else None


def compare(
    ref: str,
    argv: list[str],
    rounds: int,
    progress: Callable[[str], None] = lambda m: None,
) -> dict[str, Any]:
    """Both sides ``rounds`` times, alternating; medians and ratios per figure."""
    commit = resolve(ref)
    runs: dict[str, list[dict[str, Any]]] = {"this": [], "ref": []}
    with checkout(commit) as tree, tempfile.TemporaryDirectory() as tmp:
        sides = {"this": Side("this code", ROOT), "ref": Side(f"{ref} ({commit[:9]})", tree)}
        packages = {key: package_of(side) for key, side in sides.items()}
        for k in range(rounds):
            order = ("this", "ref") if k % 2 == 0 else ("ref", "this")
            for key in order:
                progress(f"round {k + 1}/{rounds}: {sides[key].label} ...")
                runs[key].append(run_side(sides[key], argv, Path(tmp) / f"{key}-{k}.json"))
    names: list[str] = []
    for doc in runs["this"] + runs["ref"]:
        names += [n for n in figures(doc) if n not in names]
    rows = []
    for name in names:
        mine = _median([figures(d).get(name, (None, False))[0] for d in runs["this"]])
        theirs = _median([figures(d).get(name, (None, False))[0] for d in runs["ref"]])
        higher = next(figures(d)[name][1] for d in runs["this"] + runs["ref"] if name in figures(d))
        ratio = None
        if mine and theirs:
            ratio = round(mine / theirs if higher else theirs / mine, 2)
        rows.append({"figure": name, "this": mine, "ref": theirs, "ratio": ratio})
    return {
        "against": ref,
        "commit": commit,
        "rounds": rounds,
        "command": ["bench", "core", *argv],
        "packages": packages,
        "figures": rows,
        "runs": runs,
    }


def table(result: dict[str, Any]) -> str:
    """The comparison as a text table, with what the ratio means."""

    def cell(v: float | None) -> str:
        return "–" if v is None else f"{v:.4g}"

    ref = f"{result['against']} ({result['commit'][:9]})"
    head = ("figure", "this code", ref, "ratio")
    body = [
        (r["figure"], cell(r["this"]), cell(r["ref"]), cell(r["ratio"])) for r in result["figures"]
    ]
    widths = [max(len(str(row[i])) for row in (head, *body)) for i in range(4)]
    lines = [
        f"this code against {ref}: medians of {result['rounds']} alternated rounds; "
        "ratio = REF / this for times, this / REF for frames/s (above 1: this code is faster)",
        "  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True)),
        "  ".join("-" * w for w in widths),
    ]
    for row in body:
        lines.append("  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
    return "\n".join(lines)
