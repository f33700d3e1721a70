"""``bench core|service --against REF``: the same benchmark run by this code and by the code of
git revision REF, in alternating rounds on the same machine, and each figure's ratio.

A figure measured minutes apart on a shared machine moves by tens of percent, so a ratio is
only worth quoting when both sides ran in the same window: the rounds alternate (this code,
REF, this code, REF, ...) and the medians over rounds are compared. Every run is a fresh
interpreter, so neither side inherits the other's imports, compiled kernels or allocator.

REF's files come from ``git archive`` into a temporary directory outside the checkout (no
worktree is registered in the repository, so an interrupted run leaves nothing in ``.git``);
each side's run is its own ``simpletrack bench ... --json FILE`` with PYTHONPATH set to that
side's service/schemas/clients folders and the same Python interpreter. The parent reads the
two JSON documents, so REF only has to accept the options passed through.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from simpletrack.bench.stats import table

Kind = Literal["time", "rate", "info"]
Bench = Literal["core", "service"]
FOLDERS = ("service", "schemas", "clients")  # the package's portions, as in the checkout
MISSING = "–"  # a figure one side does not report
STDERR_TAIL = 15  # lines of a failed run's stderr quoted in the error
# The service process's PYTHONPATH when set (bench/service.py launch_tracker): `bench service
# --against REF --server-only` runs this checkout's bench and load generator with REF's service.
SERVER_PATH_ENV = "SIMPLETRACK_BENCH_SERVER_PATH"

# The child: record which files it imported (the proof of which code ran), then run the
# command-line entry point exactly as `simpletrack` would.
BOOTSTRAP = """\
import json, runpy, sys
out = sys.argv[1]
sys.argv = ["simpletrack", *sys.argv[2:]]
import simpletrack.bench, simpletrack.core
with open(out, "w") as f:
    json.dump({"core": simpletrack.core.__file__, "bench": simpletrack.bench.__file__}, f)
runpy.run_module("simpletrack.cli.main", run_name="__main__", alter_sys=True)
"""


# REF's kernels compiled (or loaded) once before its timed runs.
WARM = "from simpletrack.core import jit; jit.preload()"


class AgainstError(Exception):
    """REF cannot be compared: not a revision, not a git checkout, or its run failed."""


@dataclass(frozen=True, slots=True)
class Side:
    """One side of the comparison: a tree holding the package's folders."""

    name: str  # "this" or "ref"
    label: str  # what the table's column says
    root: Path
    revision: str | None
    dirty: bool

    def pythonpath(self) -> str:
        return os.pathsep.join(str(self.root / f) for f in FOLDERS)

    def describe(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "root": str(self.root),
            "revision": self.revision,
            "uncommitted_changes": self.dirty,
        }


@dataclass(frozen=True, slots=True)
class Figure:
    name: str
    kind: Kind
    unit: str


# ----------------------------------------------------------------------------- git
def checkout_root() -> Path:
    """The tree this code was imported from (service/simpletrack/bench/ is three levels down)."""
    return Path(__file__).resolve().parents[3]


def _git(root: Path, *args: str, binary: bool = False) -> subprocess.CompletedProcess[Any]:
    try:
        return subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=not binary, check=False
        )
    except FileNotFoundError:
        raise AgainstError("--against needs git, and no git command was found") from None


def _err(proc: subprocess.CompletedProcess[Any]) -> str:
    text = proc.stderr if isinstance(proc.stderr, str) else proc.stderr.decode(errors="replace")
    return text.strip().splitlines()[-1] if text.strip() else f"exit code {proc.returncode}"


def this_side(root: Path) -> Side:
    """This code, which must sit in a git checkout for REF to be found."""
    top = _git(root, "rev-parse", "--show-toplevel")
    if top.returncode != 0 or Path(top.stdout.strip()).resolve() != root.resolve():
        raise AgainstError(
            f"--against needs this code in a git checkout: {root} is not the top of one "
            f"({_err(top) if top.returncode else 'its repository is ' + top.stdout.strip()})"
        )
    head = _git(root, "rev-parse", "HEAD").stdout.strip() or None
    dirty = bool(_git(root, "status", "--porcelain", "--untracked-files=no").stdout.strip())
    label = "this code" + (f" ({head[:7]}{'+' if dirty else ''})" if head else "")
    return Side("this", label, root, head, dirty)


def resolve(root: Path, ref: str) -> str:
    """REF's full commit id, or a one-line reason why there is none."""
    if not ref or ref.startswith("-"):
        raise AgainstError(f"--against {ref!r}: not a git revision")
    proc = _git(root, "rev-parse", "--verify", "--quiet", "--end-of-options", f"{ref}^{{commit}}")
    if proc.returncode != 0 or not proc.stdout.strip():
        raise AgainstError(
            f"--against {ref!r}: not a git revision of {root} "
            "(a branch, tag or commit, e.g. main, HEAD~3, 8ecd962)"
        )
    return str(proc.stdout.strip())


@contextlib.contextmanager
def ref_tree(root: Path, revision: str, parent: Path) -> Iterator[Path]:
    """REF's files under ``parent``/ref, removed on leaving (error and Ctrl-C included)."""
    dest = parent / "ref"
    dest.mkdir()
    try:
        proc = _git(root, "archive", "--format=tar", revision, *FOLDERS, binary=True)
        if proc.returncode != 0:
            raise AgainstError(f"git archive {revision[:12]} failed: {_err(proc)}")
        with tarfile.open(fileobj=io.BytesIO(proc.stdout)) as tar:
            tar.extractall(dest, filter="data")
        missing = [f for f in FOLDERS if not (dest / f / "simpletrack").is_dir()]
        if missing:
            raise AgainstError(
                f"revision {revision[:12]} has no simpletrack package under {', '.join(missing)}"
                " (it predates the service/schemas/clients layout)"
            )
        yield dest
    finally:
        shutil.rmtree(dest, ignore_errors=True)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (a CI timeout, `kill`) unwinds like Ctrl-C, so REF's temporary tree is removed
    either way; Python's default would end the process without running ``finally``."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


# ----------------------------------------------------------------------------- runs
def run_once(
    side: Side,
    bench: Bench,
    options: Sequence[str],
    work: Path,
    tag: str,
    server: Side | None = None,
) -> dict[str, Any]:
    """One fresh interpreter running ``simpletrack bench BENCH OPTIONS --json`` with ``side``'s
    code; its JSON document with ``imported`` (the files it loaded) added. ``server``: the
    side whose code the service process runs (``bench service --server-only``), else
    ``side``'s."""
    out, imported = work / f"{tag}.json", work / f"{tag}.imported.json"
    log_out, log_err = work / f"{tag}.stdout", work / f"{tag}.stderr"
    # -P: no current directory on sys.path, so no stray tree there shadows either side.
    cmd = [sys.executable, "-P", "-c", BOOTSTRAP, str(imported), "bench", bench, *options]
    with log_out.open("wb") as so, log_err.open("wb") as se:
        rc = subprocess.run(
            [*cmd, "--json", str(out)], env=_env(side, server), stdout=so, stderr=se
        ).returncode
    if rc != 0 or not out.is_file():
        tail = log_err.read_text(errors="replace").strip().splitlines()[-STDERR_TAIL:]
        raise AgainstError(
            f"{side.label}: `simpletrack bench {bench} {' '.join(options)}` exited with {rc}"
            + ("" if out.is_file() else " and wrote no JSON")
            + (":\n    " + "\n    ".join(tail) if tail else "")
        )
    doc: dict[str, Any] = json.loads(out.read_text())
    doc["imported"] = json.loads(imported.read_text()) if imported.is_file() else None
    return doc


def _env(side: Side, server: Side | None = None) -> dict[str, str]:
    """A child's environment: only ``side``'s folders on PYTHONPATH (the caller's may name this
    checkout, which would shadow REF's modules); ``server``'s for the service it starts."""
    env = {**os.environ, "PYTHONPATH": side.pythonpath()}
    env.pop(SERVER_PATH_ENV, None)
    if server is not None:
        env[SERVER_PATH_ENV] = server.pythonpath()
    return env


def warm_kernels(side: Side, work: Path) -> float:
    """Compile ``side``'s kernels once, before its timed runs; returns the seconds it took.
    REF's tree is fresh, numba's cache beside its sources empty: every run of it compiled
    them again, and a service run waits for them before it is ready (on 2 cores over a
    minute: past the bench's readiness wait, so `bench service --against` could not run at
    all). A REF whose core has no ``preload`` compiles in its runs, as before."""
    t0 = time.monotonic()
    with (work / "ref-warm.stderr").open("wb") as err:
        cmd = [sys.executable, "-P", "-c", WARM]
        subprocess.run(cmd, env=_env(side), stdout=subprocess.DEVNULL, stderr=err, check=False)
    return round(time.monotonic() - t0, 1)


# ----------------------------------------------------------------------------- figures
def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def core_figures(doc: dict[str, Any]) -> dict[Figure, float | None]:
    """The headline figures of one ``bench core`` document, missing keys tolerated (REF's
    document may be older)."""
    out: dict[Figure, float | None] = {}
    fused = doc.get("fused") or {}
    for key, name in (("latency", "fused vehicle"), ("one_sensor_latency", "one-sensor vehicle")):
        lat = fused.get(key) or {}
        for q in ("p50", "p99"):
            out[Figure(f"{name} {q}", "time", "ms")] = _num(lat.get(f"{q}_ms"))
    for name, r in (doc.get("loads") or {}).items():
        lat = r.get("latency") or {}
        out[Figure(f"{name} frames/s", "rate", "frames/s")] = _num(r.get("frames_per_s"))
        for q in ("p50", "p99"):
            out[Figure(f"{name} {q}", "time", "ms")] = _num(lat.get(f"{q}_ms"))
        for stage, ms in ((r.get("stages") or {}).get("ms_per_frame") or {}).items():
            out[Figure(f"{name} stage {stage}", "time", "ms")] = _num(ms)
    sweep = doc.get("sweep") or {}
    for p in sweep.get("points") or []:
        lat = p.get("latency") or {}
        out[Figure(f"sweep {p.get('boxes')} boxes p50", "time", "ms")] = _num(lat.get("p50_ms"))
        cost = ((p.get("stages") or {}).get("ms_per_frame") or {}).get("cost_matrix")
        out[Figure(f"sweep {p.get('boxes')} boxes cost_matrix", "time", "ms")] = _num(cost)
    if sweep:
        out[Figure("sweep growth exponent", "info", "")] = _num(sweep.get("exponent"))
    return out


def service_figures(doc: dict[str, Any]) -> dict[Figure, float | None]:
    """The headline figures of one ``bench service`` document, per step and for capacity."""
    out: dict[Figure, float | None] = {}
    for s in doc.get("steps") or []:
        step = f"{s.get('kind')} {s.get('sensors')} sensors"
        lat = s.get("latency") or {}
        for q in ("p50", "p99"):
            out[Figure(f"{step} {q}", "time", "ms")] = _num(lat.get(f"{q}_ms"))
        out[Figure(f"{step} delivered", "rate", "frames/s")] = _num(s.get("delivered_per_s"))
        cpu = _num(s.get("server_cpu_ms_per_frame"))
        out[Figure(f"{step} server CPU per frame", "time", "ms")] = cpu
        gil = _num((s.get("profile") or {}).get("gil_ms_per_frame"))
        if gil is not None:  # --profile-gil (--server-only: both sides' services profiled)
            out[Figure(f"{step} interpreter lock per frame", "time", "ms")] = gil
    cap = doc.get("capacity") or {}
    out[Figure("1 sensor p99", "time", "ms")] = _num(cap.get("one_sensor_p99_ms"))
    out[Figure("largest passing step", "rate", "sensors")] = _num(cap.get("max_sensors_passing"))
    out[Figure("streams per core", "rate", "streams")] = _num(cap.get("streams_per_core"))
    return out


FIGURES: dict[Bench, Callable[[dict[str, Any]], dict[Figure, float | None]]] = {
    "core": core_figures,
    "service": service_figures,
}


def ratio(kind: Kind, this: float | None, ref: float | None) -> float | None:
    """> 1 when this code is better: REF/this for times, this/REF for rates."""
    if kind == "info" or this is None or ref is None or this <= 0 or ref <= 0:
        return None
    return ref / this if kind == "time" else this / ref


def compare_docs(
    bench: Bench, this_docs: Sequence[dict[str, Any]], ref_docs: Sequence[dict[str, Any]]
) -> list[dict[str, Any]]:
    """Per figure (in this code's order, then REF's own): the median of each side over its
    rounds (rounds where the figure is absent are left out) and the ratio of the medians."""
    per_round = {
        "this": [FIGURES[bench](d) for d in this_docs],
        "ref": [FIGURES[bench](d) for d in ref_docs],
    }
    order: dict[Figure, None] = {}
    for side in ("this", "ref"):
        for figs in per_round[side]:
            order.update(dict.fromkeys(figs))
    rows = []
    for fig in order:
        row: dict[str, Any] = {"figure": fig.name, "kind": fig.kind, "unit": fig.unit}
        for side, rounds in per_round.items():
            values = [r.get(fig) for r in rounds]
            present = [v for v in values if v is not None]
            row[f"{side}_rounds"] = values
            row[side] = round(statistics.median(present), 6) if present else None
        r = ratio(fig.kind, row["this"], row["ref"])
        row["ratio"] = None if r is None else round(r, 4)
        rows.append(row)
    return rows


def _cell(value: float | None, kind: Kind, unit: str) -> str:
    if value is None:
        return MISSING
    if kind == "rate" and unit == "sensors":
        return f"{value:g}"
    return f"{value:.1f}" if kind == "rate" else f"{value:.3f}"


def against_table(doc: dict[str, Any]) -> str:
    """The printed comparison: figure, this code, REF, ratio."""
    this, ref = doc["sides"]["this"], doc["sides"]["ref"]
    rows = [
        [
            f"{r['figure']}" + (f" ({r['unit']})" if r["unit"] else ""),
            _cell(r["this"], r["kind"], r["unit"]),
            _cell(r["ref"], r["kind"], r["unit"]),
            MISSING if r["ratio"] is None else f"{r['ratio']:.2f}x",
        ]
        for r in doc["figures"]
    ]
    only = [r["figure"] for r in doc["figures"] if (r["this"] is None) != (r["ref"] is None)]
    lines = [
        f"{doc['benchmark']} against {doc['against']['ref']} ({doc['against']['revision'][:12]}):"
        f" median of {doc['rounds']} round(s), each side a fresh process, alternating "
        f"{' '.join('A' if s == 'this' else 'B' for s in doc['order'])} "
        "(A this code, B REF)",
        "ratio > 1: this code is better (REF/this for times in ms, this/REF for frames/s, "
        "sensors and streams)",
        "",
        table(["figure", this["label"], ref["label"], "ratio"], rows),
    ]
    if only:
        lines += [
            "",
            f"{MISSING}: reported by one side only ({len(only)}: {', '.join(only[:6])}"
            + (", ..." if len(only) > 6 else "")
            + ")",
        ]
    return "\n".join(lines)


def compare(
    bench: Bench,
    options: Sequence[str],
    ref: str,
    rounds: int,
    progress: Callable[[str], None] = print,
    root: Path | None = None,
    server_only: bool = False,
    per_run: Callable[[str], list[str]] | None = None,
) -> dict[str, Any]:
    """Run ``simpletrack bench BENCH OPTIONS`` ``rounds`` times with this code and with REF's,
    alternating, and compare the medians. ``server_only`` (bench service): both sides' runs
    are this code's bench and load generator, only the service process runs each side's
    code. ``per_run(tag)``: options for one run only (``this-1``, ``ref-1``, ...). Raises
    AgainstError with a one-line reason."""
    root = root or checkout_root()
    this = this_side(root)
    revision = resolve(root, ref)
    order = ["this", "ref"] * rounds
    docs: dict[str, list[dict[str, Any]]] = {"this": [], "ref": []}
    seconds: dict[str, list[float]] = {"this": [], "ref": []}
    with (
        _terminate_as_interrupt(),
        tempfile.TemporaryDirectory(prefix="simpletrack-against-") as tmp,
    ):
        work = Path(tmp) / "runs"
        work.mkdir()
        with ref_tree(root, revision, Path(tmp)) as tree:
            other = Side("ref", f"{ref} ({revision[:7]})", tree, revision, False)
            sides = {"this": this, "ref": other}
            progress(f"{other.label}: compiling its kernels once (a fresh tree) ...")
            warm_s = warm_kernels(other, work)
            progress(f"{other.label}: kernels ready in {warm_s:.1f} s")
            for k, name in enumerate(order):
                side = sides[name]
                n = k // 2 + 1
                progress(f"round {n}/{rounds}: {side.label} ...")
                t0 = time.monotonic()
                tag = f"{name}-{n}"
                opts = [*options, *(per_run(tag) if per_run else ())]
                if server_only:
                    docs[name].append(run_once(this, bench, opts, work, tag, server=side))
                else:
                    docs[name].append(run_once(side, bench, opts, work, tag))
                seconds[name].append(round(time.monotonic() - t0, 1))
                progress(f"round {n}/{rounds}: {side.label} took {seconds[name][-1]:.1f} s")
    return {
        "benchmark": f"bench {bench}",
        "against": {"ref": ref, "revision": revision},
        "rounds": rounds,
        "server_only": server_only,
        "order": order,
        "options_passed": list(options),
        "ratio": "> 1 means this code is better: REF/this for times, this/REF for rates",
        "ref_tree": str(tree),  # removed by now; recorded so a reader can check it is gone
        "ref_compile_seconds": warm_s,
        "sides": {
            name: {**side.describe(), "run_seconds": seconds[name], "runs": docs[name]}
            for name, side in sides.items()
        },
        "figures": compare_docs(bench, docs["this"], docs["ref"]),
    }
