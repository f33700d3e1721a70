"""``simpletrack bench fuzz`` and ``bench faults``: valid and mutated frames through a real
service (every frame answered exactly once, nothing non-finite, the service survives), and a
fault scenario whose victim frames all add up."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from simpletrack.bench.fuzz import MUTATIONS, mutate, valid_frame
from simpletrack.cli.main import main
from simpletrack.wire import DecodedDetections, Rejection, decode_detection_frame

pytestmark = pytest.mark.zenoh


def test_a_short_fuzz_run_is_clean_and_accounts_for_every_frame(tmp_path: Path) -> None:
    out = tmp_path / "fuzz.json"
    rc = main(["bench", "fuzz", "--frames", "1500", "--sensors", "6", "--json", str(out)])
    report = json.loads(out.read_text())
    assert rc == 0 and report["clean"], report
    refused = sum(report["rejected"].values())
    assert report["tracked"] + refused == report["sent"] == 1500
    assert report["mutated"] > 500 and set(report["mutations"]) == set(MUTATIONS)


def test_every_mutation_still_yields_bytes_the_decoder_answers() -> None:
    rng = np.random.default_rng(1)
    for _ in range(500):
        _, payload = mutate(valid_frame("v", "s", 3, rng), rng)
        assert isinstance(decode_detection_frame(payload), DecodedDetections | Rejection)


def test_a_fault_scenario_reports_every_frame_of_its_victim(tmp_path: Path) -> None:
    out = tmp_path / "faults.json"
    assert main(["bench", "faults", "--scenarios", "publisher_restart", "--json", str(out)]) == 0
    (r,) = json.loads(out.read_text())["scenarios"]
    assert r["sent"] > 40 and not r["notes"], r
    assert r["sent"] == r["tracked"] + r["announced"] + r["unanswered"], r
    assert r["bystander_sent"] > 40 and r["ids_kept"].endswith("/6")
