"""The documentation can be found: docs/README.md lists every file in docs/ (one line each),
its links land, and the project's README links the index and the pages an operator needs."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
INDEX = DOCS / "README.md"


def links(path: Path) -> list[str]:
    """Targets of the Markdown links of a file, without their #fragment."""
    return [t.partition("#")[0] for t in re.findall(r"\]\(([^)\s]+)\)", path.read_text())]


def index_rows() -> dict[str, str]:
    """First cell of each row of the index's table (link text or code) -> the whole row."""
    rows = {}
    for line in INDEX.read_text().splitlines():
        m = re.match(r"\|\s*\[?([^]|]+?)\]?(?:\([^)]*\))?\s*\|", line)
        if m and not set(m.group(1)) <= set("-: "):
            rows[m.group(1).strip()] = line
    return rows


def test_every_docs_file_is_listed_in_the_index_with_a_line() -> None:
    rows = index_rows()
    for path in sorted(DOCS.glob("*.md")):
        assert path.name in rows, f"docs/{path.name} is not listed in docs/README.md"
        cells = [c.strip() for c in rows[path.name].strip("|").split("|")]
        assert len(cells) == 3 and all(cells), f"docs/README.md: {path.name} needs what and who"
    for path in sorted(p for p in DOCS.iterdir() if p.is_dir()):
        assert f"{path.name}/" in rows, f"docs/{path.name}/ is not listed in docs/README.md"


def test_the_index_lists_only_files_that_exist() -> None:
    for name in index_rows():
        if name != "file":
            assert (DOCS / name).exists(), f"docs/README.md lists {name}, which does not exist"
    for target in links(INDEX):
        if target and not target.startswith(("http://", "https://")):
            assert (DOCS / target).exists(), f"docs/README.md links {target}: no such file"


def test_the_readme_links_the_index_and_the_operators_pages() -> None:
    targets = set(links(ROOT / "README.md"))
    for name in ("README.md", "RUNBOOK.md", "SCALE.md", "VIEW.md", "DEPLOY.md"):
        assert f"docs/{name}" in targets, f"README.md has no link to docs/{name}"
    for target in targets:
        if target.startswith("docs/"):
            assert (ROOT / target).exists(), f"README.md links {target}: no such file"
