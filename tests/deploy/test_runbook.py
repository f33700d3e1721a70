"""docs/RUNBOOK.md: every alert's ``runbook_url`` leads to a section of it, in both rule files,
and the runbook's own links between sections land."""

from __future__ import annotations

import re

from tests.deploy.helpers import ALERTS, K8S, ROOT, alert_rules, load_yaml

RUNBOOK = ROOT / "docs" / "RUNBOOK.md"


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
    assert github_anchor("SimpletrackDown") == "simpletrackdown"
    assert github_anchor("Commands used below") == "commands-used-below"
    assert github_anchor("Runbook: the `simpletrack` alerts") == "runbook-the-simpletrack-alerts"


def test_every_alert_has_a_runbook_url_leading_to_its_own_section() -> None:
    sections = anchors()
    for source in (load_yaml(ALERTS), load_yaml(K8S / "prometheusrule.yaml")["spec"]):
        rules = alert_rules(source)
        assert rules
        for rule in rules:
            url = rule["annotations"].get("runbook_url")
            assert url, f"{rule['alert']} has no runbook_url"
            path, _, anchor = url.partition("#")
            assert (ROOT / path) == RUNBOOK, url
            assert anchor == github_anchor(rule["alert"]), url
            assert anchor in sections, f"{url}: no such heading in docs/RUNBOOK.md"


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
