"""The import rules of docs/ARCHITECTURE.md, read from every import statement of the package
(top-level or inside a function), and the light imports checked in a fresh interpreter."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "service", ROOT / "schemas", ROOT / "clients"]

# What the pure core may import: numerics, serialisation, validation, and plain stdlib.
CORE_ALLOWED = {
    "numpy", "scipy", "numba", "msgpack", "pydantic",
    "__future__", "dataclasses", "enum", "typing", "collections", "functools", "hashlib", "math",
    "os", "threading", "types", "warnings", "importlib", "heapq", "itertools", "re", "ast",
    "pathlib",
}  # fmt: skip
# Only the kernel compiler may import numba, read the environment (SIMPLETRACK_JIT) and read
# files (its kernels' sources, whose digest names their cache entries).
CORE_ONLY_IN = {
    "numba": "jit.py", "os": "jit.py", "importlib": "jit.py", "ast": "jit.py", "pathlib": "jit.py"
}  # fmt: skip

# Layer -> the simpletrack layers it may import (itself always). Tools may import anything
# below the CLI; nothing below the tools may import a tool.
TOOLS = {"datasets", "eval", "sim", "bench", "plot", "spawn", "mcap"}
MAY_IMPORT: dict[str, set[str]] = {
    "core": set(),
    "wire": {"core"},  # only wire/convert.py, checked below
    "session": set(),
    "client": {"wire", "session"},
    "ros2": {"wire", "session", "client"},  # an adapter over the client library: light too
    "view": {"wire", "session", "client"},  # a planner-side page: light too
    "server": {"core", "wire", "session"},
    "datasets": {"core", "wire", "client"},
    "eval": {"core", "wire", "session", "datasets", "spawn", "server"},
    "spawn": {"core", "wire", "session", "server"},
    "sim": {
        "core",
        "wire",
        "session",
        "client",
        "datasets",
        "eval",
        "spawn",
        "server",
        "view",
        "mcap",
        "ros2",
    },
    "mcap": {"wire", "client"},  # recordings: the wire's schemas and keys, no service
    "bench": {"core", "wire", "session", "client", "datasets", "eval", "spawn", "server", "sim"},
    "plot": {"core", "datasets"},
    "cli": {"core", "wire", "session", "client", "server", "ros2", "view", *TOOLS},
}


def _layer(path: Path) -> str:
    rel = next(path.relative_to(s / "simpletrack") for s in SOURCES if path.is_relative_to(s))
    return rel.parts[0].removesuffix(".py")


def _modules() -> Iterator[Path]:
    for source in SOURCES:
        yield from sorted((source / "simpletrack").rglob("*.py"))


def _imports(path: Path) -> Iterator[str]:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            assert node.level == 0, f"{path}: relative import"
            if node.module == "simpletrack":  # from simpletrack import plot
                yield from (f"simpletrack.{a.name}" for a in node.names)
            else:
                yield node.module


def _edges() -> Iterator[tuple[Path, str, str]]:
    for path in _modules():
        for module in _imports(path):
            parts = module.split(".")
            if parts[0] == "simpletrack":
                assert len(parts) > 1, f"{path}: import of the bare namespace"
                yield path, _layer(path), parts[1]


def test_every_module_belongs_to_a_known_layer() -> None:
    layers = {_layer(p) for p in _modules()}
    assert layers == set(MAY_IMPORT), layers ^ set(MAY_IMPORT)


def _folder(layer: str) -> str:
    """The source folder a layer lives in (service, schemas or clients)."""
    return next(s.name for s in SOURCES if any((s / "simpletrack").glob(f"{layer}*")))


def test_clients_import_only_the_wire_and_themselves() -> None:
    """What a vehicle, planner or operator installs (clients/) stands on the wire (schemas/)
    alone: no module under clients/ imports a package that lives under service/."""
    bad = [
        f"{p.relative_to(ROOT)}: {src} imports {dst} (service/)"
        for p, src, dst in _edges()
        if p.is_relative_to(ROOT / "clients") and _folder(dst) == "service"
    ]
    assert not bad, bad
    assert _folder("core") == "service" and _folder("client") == "clients"  # the rule can fail


def test_layers_import_only_what_they_may() -> None:
    bad = [
        f"{p.relative_to(ROOT)}: {src} imports {dst}"
        for p, src, dst in _edges()
        if dst != src and dst not in MAY_IMPORT[src]
    ]
    assert not bad, bad


def test_only_the_adapter_joins_wire_and_core() -> None:
    bad = [
        str(p.relative_to(ROOT))
        for p, src, dst in _edges()
        if src == "wire" and dst == "core" and p.name != "convert.py"
    ]
    assert not bad, bad


def test_the_core_is_pure() -> None:
    core = ROOT / "service" / "simpletrack" / "core"
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p in sorted(core.rglob("*.py"))
        for m in _imports(p)
        if m.split(".")[0] not in CORE_ALLOWED and not m.startswith("simpletrack.core")
    ]
    assert not bad, bad


def test_only_the_kernel_compiler_imports_numba_and_os() -> None:
    core = ROOT / "service" / "simpletrack" / "core"
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p in sorted(core.rglob("*.py"))
        for m in _imports(p)
        if CORE_ONLY_IN.get(m.split(".")[0], p.name) != p.name
    ]
    assert not bad, bad


def test_the_cli_lists_every_command_module() -> None:
    from simpletrack.cli.main import COMMANDS

    cli = ROOT / "service" / "simpletrack" / "cli"
    commands = {p.stem for p in cli.glob("*.py") if "def register(" in p.read_text()}
    assert commands and set(COMMANDS) == commands, set(COMMANDS) ^ commands


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


@pytest.mark.parametrize(
    ("statement", "absent"),
    [
        (
            "import simpletrack.core; simpletrack.core.Tracker",
            {"zenoh", "prometheus_client", "pydantic_settings", "simpletrack.wire"},
        ),
        (
            "import simpletrack.client",
            {
                "scipy",
                "prometheus_client",
                "pydantic",
                "pydantic_settings",
                "simpletrack.core",
                "yaml",
            },
        ),
        ("import simpletrack.wire", {"zenoh", "scipy", "pydantic", "simpletrack.core"}),
        (
            "import simpletrack.ros2.bridge",
            {"scipy", "pydantic", "prometheus_client", "simpletrack.core", "simpletrack.server"},
        ),
        ("import simpletrack.session", {"pydantic", "scipy", "simpletrack.core"}),
        (
            "import simpletrack.view",
            {"scipy", "pydantic", "simpletrack.core", "simpletrack.server"},
        ),
        # The assignment solvers load on first use (core/solvers.py): every command's start
        # paid ~0.25 s for scipy.optimize before.
        (
            "from simpletrack.cli.main import build_parser; build_parser()",
            {"scipy.optimize", "scipy.sparse.csgraph"},
        ),
        (
            "import simpletrack.core; simpletrack.core.Tracker",
            {"scipy.optimize", "scipy.sparse.csgraph"},
        ),
        # Kernels compile on first call (core/jit.py): importing numba costs ~0.2-0.4 s.
        ("import simpletrack.core; simpletrack.core.Tracker", {"numba", "llvmlite"}),
        ("import simpletrack.core.geometry, simpletrack.core.nms", {"numba", "llvmlite"}),
        ("from simpletrack.cli.main import build_parser; build_parser()", {"numba"}),
    ],
)
def test_light_imports_stay_light(statement: str, absent: set[str]) -> None:
    loaded = _loaded_after(statement)
    assert not absent & loaded, absent & loaded


def test_the_custody_machine_is_pure() -> None:
    """Custody decisions read no clock and touch no network: the worker passes ``now`` in
    and carries the actions out (server/custody_machine.py)."""
    path = ROOT / "service" / "simpletrack" / "server" / "custody_machine.py"
    allowed = {"__future__", "collections", "collections.abc", "dataclasses", "enum", "hashlib"}
    allowed |= {"typing"}
    for name in _imports(path):
        if name.startswith("simpletrack."):
            assert name.startswith("simpletrack.wire."), f"custody machine imports {name}"
        else:
            assert name in allowed, f"custody machine imports {name} (no Zenoh, no clock)"
