"""A tracker restored from bytes continues exactly like one that never stopped."""

from __future__ import annotations

import hashlib
from dataclasses import fields

import msgpack
import numpy as np
import pytest

from simpletrack.core.config import preset
from simpletrack.core.state import TrackTable
from simpletrack.core.tracker import STATE_FORMATS, Tracker
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


@pytest.mark.parametrize("state_format", STATE_FORMATS)
def test_restore_mid_sequence_equals_uninterrupted_run(state_format: int) -> None:
    frames = _stream(30)
    whole = Tracker(preset("wod"))
    full = [whole.step(frame(r, 0.1 * k)) for k, r in enumerate(frames)]
    first = Tracker(preset("wod"))
    for k, r in enumerate(frames[:13]):
        first.step(frame(r, 0.1 * k))
    restored = Tracker.from_bytes(first.to_bytes(state_format))
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
    with pytest.raises(ValueError, match="format"):
        Tracker.from_bytes(msgpack.packb({"format": 99}))
    with pytest.raises(ValueError, match=r"state_format must be one of .*: 3"):
        Tracker(preset("wod")).to_bytes(3)


def _after(name: str, n: int) -> Tracker:
    t = Tracker(preset(name))
    for k, r in enumerate(_stream(30)[:n]):
        t.step(frame(r, 0.1 * k))
    return t


def _bits(table: TrackTable) -> dict[str, tuple[str, tuple[int, ...], bytes]]:
    return {
        f.name: (a.dtype.str, a.shape, np.ascontiguousarray(a).tobytes())
        for f in fields(table)
        for a in [getattr(table, f.name)]
    }


# sha256 of Tracker.to_bytes() at 7bccda6, the last version before format 2, for _after(...,
# 13): a member pinned to state_format 1 writes what the members of that version read.
BEFORE_FORMAT_2 = {
    "wod": "540c37d25c1e8ad000271d8334119866404a8d971e1440c01954ff2f49457f38",
    "nuscenes": "52fc5a6f77b7678d818126aa2e07931adf15d59f7fca4ffdd66654e9ffcb820e",
}


@pytest.mark.parametrize("name", sorted(BEFORE_FORMAT_2))
def test_format_1_is_byte_for_byte_what_versions_before_format_2_wrote(name: str) -> None:
    blob = _after(name, 13).to_bytes(1)
    assert hashlib.sha256(blob).hexdigest() == BEFORE_FORMAT_2[name]


def test_format_2_leaves_out_cells_zero_in_every_track_and_restores_them_bit_for_bit() -> None:
    t = _after("nuscenes", 13)
    assert len(t.tracks) >= 8
    p = t.tracks.p.copy()
    p[0, 3, 5] = -0.0  # equal to 0.0 but not zero bits: kept, and back as -0.0
    p[1, 4, 6] = np.nan
    t.tracks = TrackTable(
        *(p if f.name == "p" else getattr(t.tracks, f.name) for f in fields(t.tracks))
    )
    dense, compact = t.to_bytes(1), t.to_bytes(2)
    # A Kalman covariance sets 16 of its 100 cells (the diagonal and position-velocity).
    assert len(compact) < 0.6 * len(dense), (len(compact), len(dense))
    for blob in (dense, compact):
        back = Tracker.from_bytes(blob)
        assert _bits(back.tracks) == _bits(t.tracks)
        assert (back.next_id, back.frame_count, back.last_stamp) == (
            t.next_id,
            t.frame_count,
            t.last_stamp,
        )
    assert np.signbit(Tracker.from_bytes(compact).tracks.p[0, 3, 5])
    empty = Tracker(preset("nuscenes"))
    assert _bits(Tracker.from_bytes(empty.to_bytes(2)).tracks) == _bits(empty.tracks)


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"cells": [0, 7, 100]}, "past the row"),
        ({"cells": [7, 0]}, "not increasing"),
        ({"cells": [-1, 0]}, "negative"),
        ({"cells": [], "data": b"", "shape": [10**9, 10, 10]}, "rows the data does not bound"),
        ({"data": b"\0" * 8}, "too few values"),
    ],
)
def test_a_compact_column_that_does_not_fit_its_shape_is_refused(
    change: dict[str, object], why: str
) -> None:
    obj = msgpack.unpackb(_after("nuscenes", 13).to_bytes(2), raw=False)
    assert "cells" in obj["tracks"]["p"]
    obj["tracks"]["p"].update(change)
    with pytest.raises(ValueError):
        Tracker.from_bytes(msgpack.packb(obj, use_bin_type=True))
