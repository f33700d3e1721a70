"""Which workers are tracking (server/gil.py): a flood's threads pause only while another
worker tracks a frame, never for themselves, and the slots survive nesting."""

from __future__ import annotations

import time

from simpletrack.server.gil import Trackers


def paused(t: Trackers, own: int | None = None) -> bool:
    t0 = time.perf_counter()
    t.pause(own)
    return time.perf_counter() - t0 >= t.pause_s


def test_a_pause_only_while_another_worker_tracks() -> None:
    t = Trackers(2, pause_s=0.01)
    assert not t.busy() and not paused(t)
    with t.tracking(1):
        assert t.busy()
        assert paused(t)  # Zenoh's thread, a queryable: any worker tracking counts
        assert paused(t, own=0)  # worker 0 refusing while worker 1 tracks
        assert not paused(t, own=1)  # worker 1 refusing inside its own tracking
        with t.tracking(1):  # per-sensor output inside a fused vehicle's step
            pass
        assert t.busy()
    assert not t.busy() and not paused(t, own=0)


def test_no_pause_when_switched_off() -> None:
    t = Trackers(1, pause_s=0.0)
    with t.tracking(0):
        t0 = time.perf_counter()
        for _ in range(1000):
            t.pause()
        assert time.perf_counter() - t0 < 0.05
