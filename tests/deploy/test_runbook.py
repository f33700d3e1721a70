"""docs/RUNBOOK.md and the console page Prometheus serves it as: every alert's ``runbook_url``
is an absolute link (``{{ $externalURL }}/consoles/simpletrack-runbook.html#<alert>``) to a
section of it, in both rule files; the page (compose's and the Kubernetes ConfigMap's) is what
scripts/runbook_page.py makes of the Markdown; the runbook's own links between sections land.
tests/deploy/test_prometheus.py has a real Prometheus serve the links."""

from __future__ import annotations

import importlib.util
import re
import sys
from html.parser import HTMLParser
from pathlib import Path
from types import ModuleType

from tests.deploy.helpers import ALERTS, K8S, ROOT, alert_rules, load_yaml

RUNBOOK = ROOT / "docs" / "RUNBOOK.md"
RUNBOOK_URL = re.compile(
    r"\{\{ \$externalURL \}\}/consoles/(?P<page>[\w.-]+\.html)#(?P<anchor>[\w-]+)"
)


def _page_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "runbook_page", ROOT / "scripts" / "runbook_page.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


page_script = _page_script()


class _Ids(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.ids.update(v for k, v in attrs if k == "id" and v)


def page_ids(path: Path) -> set[str]:
    parser = _Ids()
    parser.feed(path.read_text())
    return parser.ids


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces
    to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors() -> set[str]:
    return {
        github_anchor(m.group(1))
        for m in re.finditer(r"^#{1,6} (.+)$", RUNBOOK.read_text(), flags=re.MULTILINE)
    }


def test_the_anchor_rule_is_githubs() -> None:
    for rule in (github_anchor, page_script.github_anchor):
        assert rule("SimpletrackDown") == "simpletrackdown"
        assert rule("Commands used below") == "commands-used-below"
        assert rule("Runbook: the `simpletrack` alerts") == "runbook-the-simpletrack-alerts"


def test_every_alert_links_absolutely_to_its_own_section_of_the_served_page() -> None:
    """Absolute (Prometheus's external URL: clickable from Alertmanager, a chat message or a
    mail), served by Prometheus itself (so it works while every instance is down), to the
    section named after the alert."""
    sections = anchors()
    for source in (load_yaml(ALERTS), load_yaml(K8S / "prometheusrule.yaml")["spec"]):
        rules = alert_rules(source)
        assert rules
        for rule in rules:
            url = rule["annotations"].get("runbook_url")
            assert url, f"{rule['alert']} has no runbook_url"
            assert url.startswith(("http://", "https://", "{{ $externalURL }}/")), url
            m = RUNBOOK_URL.fullmatch(url)
            assert m is not None, url
            assert m["page"] == page_script.PAGE_NAME, url
            assert m["anchor"] == github_anchor(rule["alert"]), url
            assert m["anchor"] in sections, f"{url}: no such heading in docs/RUNBOOK.md"
            for page in page_script.PAGES:
                assert m["anchor"] in page_ids(page), f"{url}: no such id in {page}"


def test_the_served_pages_are_the_runbook_rendered() -> None:
    """Edit docs/RUNBOOK.md, then run `.venv/bin/python scripts/runbook_page.py`."""
    want = page_script.render(RUNBOOK.read_text())
    for page in page_script.PAGES:
        assert page.read_text() == want, f"{page} is out of date: run scripts/runbook_page.py"
    assert page_script.main(["--check"]) == 0


def test_the_page_is_safe_as_a_go_template() -> None:
    """Prometheus renders a console page as a Go template: an action would break or run."""
    page = page_script.render("# T\n\n`{{ $labels.instance }}` and {{ `x` }} {{\n")
    assert "{{" not in page
    assert "&#123;&#123; $labels.instance &#125;&#125;" in page
    for path in page_script.PAGES:
        assert "{{" not in path.read_text()


def test_every_heading_of_the_runbook_is_an_anchor_of_the_page() -> None:
    prose = re.sub(r"^```.*?^```", "", RUNBOOK.read_text(), flags=re.MULTILINE | re.DOTALL)
    headings = {github_anchor(h) for h in re.findall(r"^#{1,6} (.+)$", prose, re.MULTILINE)}
    assert len(headings) > len(alert_rules())
    assert headings <= page_ids(page_script.PAGES[0])


def test_each_section_says_what_it_means_how_to_confirm_and_what_to_do() -> None:
    text = RUNBOOK.read_text()
    for rule in alert_rules():
        name = rule["alert"]
        body = text.split(f"\n## {name}\n", 1)[1].split("\n## ", 1)[0]
        for part in ("**Means.**", "**Confirm.**", "**Do.**"):
            assert part in body, f"{name}: no {part}"


def test_the_runbooks_links_between_sections_land() -> None:
    sections = anchors()
    links = re.findall(r"\]\(#([^)]+)\)", RUNBOOK.read_text())
    assert links
    for link in links:
        assert link in sections, link
