"""``simpletrack.spawn``: a sequence through a spawned service equals the in-process tracker."""

from __future__ import annotations

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import preset
from simpletrack.core.frames import Frame
from simpletrack.core.tracker import Tracker
from simpletrack.spawn import RemoteError, spawn_service, track_sequence_over_zenoh

pytestmark = pytest.mark.zenoh


def frames(n: int) -> list[Frame]:
    rng = np.random.default_rng(3)
    out = []
    for k in range(n):
        m = 5 if k % 7 else 3  # some objects blink out now and then
        params = np.zeros((m, 7))
        params[:, 0] = 5.0 + 0.8 * k + rng.normal(0, 0.05, m)
        params[:, 1] = np.arange(m) * 6.0
        params[:, 2] = 0.8
        params[:, 4:7] = (4.0, 1.8, 1.6)
        score = np.linspace(0.95, 0.55, m)
        out.append(Frame(Boxes.from_arrays(params, score, np.arange(m) % 3), stamp=0.1 * k))
    return out


def test_remote_sequence_equals_the_in_process_tracker() -> None:
    config = preset("kitti")
    seq = frames(40)
    local = Tracker(config)
    expected = [local.step(f) for f in seq]
    with spawn_service("kitti") as endpoint:
        got = track_sequence_over_zenoh(seq, config, connect=endpoint, sensor="synthetic")
        with pytest.raises(RemoteError, match="another tracker configuration"):
            track_sequence_over_zenoh(seq[:2], preset("nuscenes"), connect=endpoint)
    assert len(got) == len(expected)
    assert sum(len(t) for t in got) > 100
    for g, e in zip(got, expected, strict=True):
        np.testing.assert_array_equal(g.ids, e.ids)
        np.testing.assert_array_equal(g.boxes.cls, e.boxes.cls)
        np.testing.assert_array_equal(g.state, e.state)
        np.testing.assert_allclose(g.boxes.params, e.boxes.params, atol=1e-4)
        np.testing.assert_allclose(g.boxes.score, e.boxes.score, atol=1e-6)
