"""The checkpoint rule (server/checkpoint_rule.py): a stream's state goes to its standby once
it has taken ``every_frames`` frames since its last checkpoint, or once that checkpoint is
``max_age_s`` old and it changed at all; a standby without its state gets it at once; a stop
sends everything. Table tests."""

from __future__ import annotations

import pytest

from simpletrack.server.checkpoint_rule import CheckpointMark, checkpoint_due

EVERY, MAX_AGE = 5, 10.0
LAST = CheckpointMark("m-b", frames=100, at=50.0)


@pytest.mark.parametrize(
    ("frames", "now", "due"),
    [(100, 50.5, False), (101, 50.5, True), (101, 99.0, True)],
)
def test_one_frame_each_tick_sends_every_changed_stream(frames: int, now: float, due: bool) -> None:
    """The default (``every_frames`` = 1): every stream that changed since its last one."""
    assert checkpoint_due(LAST, "m-b", frames, now, 1, MAX_AGE) is due


@pytest.mark.parametrize(
    ("last", "standby", "frames", "now", "flags", "due", "why"),
    [
        (None, "m-b", 1, 50.0, {}, True, "the standby has none of its state"),
        (LAST, "m-c", 100, 50.1, {}, True, "a new standby has none of its state"),
        (LAST, "m-c", 100, 50.1, {"new_standby_only": True}, True, "the same, asked for new only"),
        (LAST, "m-b", 100, 99.0, {}, False, "unchanged, however old"),
        (LAST, "m-b", 100, 50.0, {"final": True}, True, "a stop sends every stream"),
        (LAST, "m-b", 104, 51.0, {}, False, "4 frames in 1 s (a 4 Hz sensor): not yet"),
        (LAST, "m-b", 105, 51.0, {}, True, "5 frames: a takeover would replay 5"),
        (LAST, "m-b", 110, 51.0, {}, True, "10 frames in 1 s (10 Hz): every tick, as before"),
        (LAST, "m-b", 110, 51.0, {"new_standby_only": True}, False, "only new standbys now"),
        (LAST, "m-b", 101, 59.9, {}, False, "one frame, 9.9 s old (0.1 Hz)"),
        (LAST, "m-b", 101, 60.0, {}, True, "one frame and 10 s old: the age decides"),
        (LAST, "m-b", 104, 60.0, {}, True, "4 frames in 10 s (0.4 Hz)"),
    ],
)
def test_checkpoint_due(
    last: CheckpointMark | None,
    standby: str,
    frames: int,
    now: float,
    flags: dict[str, bool],
    due: bool,
    why: str,
) -> None:
    assert checkpoint_due(last, standby, frames, now, EVERY, MAX_AGE, **flags) is due, why
