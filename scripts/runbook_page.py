"""Render docs/RUNBOOK.md as the console page Prometheus serves next to its alerts.

    .venv/bin/python scripts/runbook_page.py            # rewrite the page(s) from RUNBOOK.md
    .venv/bin/python scripts/runbook_page.py --check    # exit 1 if a page is out of date

Every alert's ``runbook_url`` is ``{{ $externalURL }}/consoles/simpletrack-runbook.html#<alert
in lower case>``: Prometheus itself serves the runbook (``--web.console.templates``), so the
link is absolute, clickable in Alertmanager, Grafana or a chat message, and resolves wherever
the stack is deployed, even when every ``simpletrack`` instance is down. The page is written
twice, for compose (``deploy/prometheus/consoles/``, mounted with the rest of
deploy/prometheus/) and for Kubernetes (``deploy/k8s/prometheus-runbook/``, a ConfigMap a
kustomization can only take from its own folder). tests/deploy/test_runbook.py keeps both
equal to what this script makes of RUNBOOK.md.

Prometheus renders a console page as a Go template, so no ``{{`` may reach it: braces in the
text become HTML character references. Headings get GitHub's anchors (lower case, punctuation
dropped, spaces to hyphens), the same as on the Markdown file.
"""

from __future__ import annotations

import argparse
import html
import re
import sys
from pathlib import Path

from markdown_it import MarkdownIt

ROOT = Path(__file__).resolve().parents[1]
RUNBOOK = ROOT / "docs" / "RUNBOOK.md"
PAGE_NAME = "simpletrack-runbook.html"
PAGES = (
    ROOT / "deploy" / "prometheus" / "consoles" / PAGE_NAME,
    ROOT / "deploy" / "k8s" / "prometheus-runbook" / PAGE_NAME,
)

# Single braces only in the style sheet: a Go template starts at "{{".
HEAD = """<!DOCTYPE html>
<!-- Generated from docs/RUNBOOK.md by scripts/runbook_page.py: edit the Markdown, then run
     the script. Served by Prometheus at <external URL>/consoles/simpletrack-runbook.html. -->
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
body {{ font-family: sans-serif; max-width: 60rem; margin: 1rem auto; padding: 0 1rem;
  line-height: 1.45; color: #1f2328; }}
h2 {{ border-bottom: 1px solid #d0d7de; padding-bottom: 0.2rem; margin-top: 2rem; }}
code {{ background: #f3f4f6; padding: 0.1rem 0.25rem; border-radius: 3px; }}
pre {{ background: #f3f4f6; padding: 0.6rem; overflow-x: auto; }}
pre code {{ padding: 0; }}
:target {{ background: #fff8c5; }}
</style>
</head>
<body>
"""
TAIL = "</body>\n</html>\n"


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces
    to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def render(markdown: str) -> str:
    """The console page for a runbook in Markdown."""
    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    tokens = md.parse(markdown)
    title = "Runbook"
    for i, token in enumerate(tokens):
        if token.type == "heading_open":
            text = tokens[i + 1].content
            token.attrSet("id", github_anchor(text))
            if token.tag == "h1":
                title = text.replace("`", "")
    body = md.renderer.render(tokens, md.options, {})
    # Braces only occur in text here (markdown-it percent-encodes them in link targets).
    body = body.replace("{", "&#123;").replace("}", "&#125;")
    page = HEAD.format(title=html.escape(title)) + body + TAIL
    assert "{{" not in page
    return page


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--check", action="store_true", help="exit 1 if a page is out of date")
    args = p.parse_args(argv)
    page = render(RUNBOOK.read_text())
    stale = [path for path in PAGES if not path.is_file() or path.read_text() != page]
    if args.check:
        for path in stale:
            print(f"{path.relative_to(ROOT)} is out of date: run scripts/runbook_page.py")
        return 1 if stale else 0
    for path in stale:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(page)
        print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
