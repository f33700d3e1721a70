"""When a held stream's state goes to its standby (a checkpoint): a pure rule, no clock.

Every tick (``checkpoint_interval_s``) a changed stream is sent: ``every_frames`` = 1, the
default. A takeover after a kill continues from the checkpoint and replays the frames since
(from the vehicle's cache, or those the standby kept), so with ``every_frames`` > 1 a stream
is sent only once it took that many frames since its last checkpoint, or took fewer and that
checkpoint is ``max_age_s`` old. At 10 Hz, 5 frames still go every tick; at 0.5 Hz every 10 s
instead of after each frame: ~17 % less CPU per frame, but a takeover then asks the vehicle's
cache for the frames since, where a checkpoint a frame old needed no asking (docs/SCALE.md).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class CheckpointMark:
    """The last checkpoint sent of a stream: to whom, after how many frames, when."""

    standby: str
    frames: int
    at: float  # monotonic seconds


def checkpoint_due(
    last: CheckpointMark | None,
    standby: str,
    frames: int,
    now: float,
    every_frames: int,
    max_age_s: float,
    *,
    final: bool = False,
    new_standby_only: bool = False,
) -> bool:
    """Send the stream's state to ``standby`` now? ``frames``: the stream's frames taken so
    far. ``final``: every stream (a stop); ``new_standby_only``: only a standby that has none
    of its state (a new stream, a new standby), which is always due."""
    if final or last is None or last.standby != standby:
        return True
    if new_standby_only or frames == last.frames:
        return False
    return frames - last.frames >= every_frames or now - last.at >= max_age_s


__all__ = ["CheckpointMark", "checkpoint_due"]
