"""``simpletrack bench fuzz``: valid and mutated frames through a real service. Every frame is
answered exactly once, nothing non-finite comes back, and the service survives."""

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
