"""A tracker restored from bytes continues exactly like one that never stopped."""

from __future__ import annotations

import numpy as np

from simpletrack.core.config import preset
from simpletrack.core.tracker import Tracker
from tests.core.helpers import frame


def _stream(n_frames: int, seed: int = 0) -> list[list[list[float]]]:
    rng = np.random.default_rng(seed)
    objs = rng.uniform(-30, 30, size=(12, 2))
    vel = rng.uniform(-1, 1, size=(12, 2))
    frames = []
    for k in range(n_frames):
        rows = []
        for i in range(len(objs)):
            if rng.random() < 0.8:
                x, y = objs[i] + vel[i] * k + rng.normal(scale=0.1, size=2)
                rows.append([x, y, 0.0, 0.0, 4.0, 2.0, 1.5, float(rng.uniform(0.05, 1.0)), i % 3])
        frames.append(rows)
    return frames


def test_restore_mid_sequence_equals_uninterrupted_run() -> None:
    frames = _stream(30)
    whole = Tracker(preset("wod"))
    full = [whole.step(frame(r, 0.1 * k)) for k, r in enumerate(frames)]
    first = Tracker(preset("wod"))
    for k, r in enumerate(frames[:13]):
        first.step(frame(r, 0.1 * k))
    restored = Tracker.from_bytes(first.to_bytes())
    for k, r in enumerate(frames[13:], start=13):
        out = restored.step(frame(r, 0.1 * k))
        assert out.ids.tolist() == full[k].ids.tolist()
        np.testing.assert_array_equal(out.boxes.params, full[k].boxes.params)
        np.testing.assert_array_equal(out.boxes.score, full[k].boxes.score)
    assert restored.next_id == whole.next_id


def test_reset_forgets_tracks_and_restarts_ids() -> None:
    t = Tracker(preset("wod"))
    for k, r in enumerate(_stream(5)):
        t.step(frame(r, 0.1 * k))
    assert t.next_id > 0
    t.reset()
    assert len(t.tracks) == 0 and t.next_id == 0 and t.last_stamp is None


def test_state_rejects_unknown_format() -> None:
    import msgpack
    import pytest

    with pytest.raises(ValueError, match="format"):
        Tracker.from_bytes(msgpack.packb({"format": 99}))
