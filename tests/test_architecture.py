"""The import rules of docs/ARCHITECTURE.md: the core is pure; nothing of the service
imports the clients."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# What the pure core may import: numerics, serialisation, validation, and plain stdlib.
CORE_ALLOWED = {
    "numpy", "scipy", "msgpack", "pydantic", "service",  # service.core only, checked below
    "__future__", "dataclasses", "enum", "typing", "collections",
}  # fmt: skip


def _imports(package: str) -> Iterator[tuple[Path, str]]:
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                yield from ((path, a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                yield path, node.module


def test_the_core_is_pure() -> None:
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in _imports("service/core")
        if m.split(".")[0] not in CORE_ALLOWED
        or (m.startswith("service") and not m.startswith("service.core"))
    ]
    assert not bad, bad


def test_service_and_schemas_never_import_clients() -> None:
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for pkg in ("service", "schemas")
        for p, m in _imports(pkg)
        if m.split(".")[0] == "clients"
    ]
    assert not bad, bad


def test_schemas_use_only_the_cores_box_types_from_the_service() -> None:
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in _imports("schemas")
        if m.startswith("service") and not m.startswith("service.core")
    ]
    assert not bad, bad
