"""An ordinary frame's step in one compiled call (core/step_kernels.py) tracks exactly as the
staged path (the same kernels called one by one from Python) under every option it reads;
the frames it does not take go down the staged path, and a block without a finite assignment
fails as it always did."""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from simpletrack.core import tracker as tracker_module
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import (
    Matcher,
    Metric,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    TrackScore,
    VerticalOverlap,
)
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.lifecycle import UpdateKind
from simpletrack.core.step_kernels import InfeasibleBlock
from simpletrack.core.tracker import Tracker
from tests.core.helpers import config, crowd, models_config


def stream(seed: int) -> list[Frame]:
    """Crowded, with velocities, every third frame non-key: births, deaths, coasting, ties;
    a few degenerate boxes (zero width, NaN score, infinite velocity) to drop."""
    out = []
    for k, f in enumerate(crowd(seed, 30, 40, seen=0.75, with_velocity=True, non_key_every=3)):
        b = f.boxes
        params, score, velocity = b.params.copy(), b.score.copy(), b.velocity.copy()
        if k % 4 == 1:
            params[k % 5 :: 9, 5] = 0.0
            score[2::13] = np.nan
            velocity[5::17, 0] = np.inf
        out.append(
            replace(f, boxes=Boxes(params=params, score=score, cls=b.cls, velocity=velocity))
        )
    return out


def configs() -> list[TrackerConfig]:
    fused = {"track_score": TrackScore.FUSED, "score_decay": 0.15}
    return [
        config(),
        config(OutputPolicy.REFERENCE, min_hits=2, two_stage=True),
        config(OutputPolicy.NUSCENES, min_hits=0, **fused),
        config(max_age=4, coast_output=2, delete_below=0.3, **fused),
        config(max_age=3, gate_widening=0.3, max_position_std=1.2),
        config(matcher=Matcher.GREEDY, gate_widening=0.2, max_age=3),
        config(metric=Metric.IOU_3D, max_distance=0.9),
        config(metric=Metric.GIOU_BEV, max_distance=1.4),
        config(OutputPolicy.PAPER).model_copy(
            update={
                "vertical_overlap": VerticalOverlap.REFERENCE,
                "tie_order": TieOrder.REFERENCE,
            }
        ),
        config(OutputPolicy.NUSCENES, max_age=3, coast_output=1).model_copy(
            update={"motion": MotionModel.CONSTANT_VELOCITY}
        ),
        models_config(),
        models_config(OutputPolicy.NUSCENES, pedestrian="cv"),
    ]


def _same(a: Tracks, b: Tracks) -> None:
    for f in dataclasses.fields(Tracks):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "boxes":
            for col in ("params", "score", "cls", "velocity"):
                np.testing.assert_array_equal(getattr(x, col), getattr(y, col), err_msg=col)
        elif x is None or y is None:
            assert x is None and y is None, f.name
        else:
            assert x.dtype == y.dtype, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)


def _calls(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    seen = {"fused": 0}
    step_frame = tracker_module.step_frame

    def counted(*args: Any) -> Any:
        seen["fused"] += 1
        return step_frame(*args)

    monkeypatch.setattr(tracker_module, "step_frame", counted)
    return seen


@pytest.mark.parametrize("index", range(len(configs())))
@pytest.mark.parametrize("seed", range(2))
def test_the_fused_step_tracks_bit_for_bit_as_the_staged_path(
    index: int, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames = stream(seed)
    seen = _calls(monkeypatch)
    fused, staged = Tracker(configs()[index]), Tracker(configs()[index])
    staged._fused = False
    updates: set[int] = set()
    for f in frames:
        a, b = fused.step(f), staged.step(f)
        _same(a, b)
        updates.update(fused.tracks.update.tolist())
        for col in dataclasses.fields(fused.tracks):
            np.testing.assert_array_equal(
                getattr(fused.tracks, col.name), getattr(staged.tracks, col.name), col.name
            )
    assert fused.next_id == staged.next_id > 30
    assert seen["fused"] == len(frames)  # every frame went through the compiled step
    assert UpdateKind.MATCHED in updates and len(updates) >= 2


def test_stage_two_extensions_match_too(monkeypatch: pytest.MonkeyPatch) -> None:
    """Low-score detections extend coasting tracks the same way on both paths."""
    cfg = config(two_stage=True, min_hits=1, max_age=3)
    frames = stream(7)
    fused, staged = Tracker(cfg), Tracker(cfg)
    staged._fused = False
    extended = 0
    for f in frames:
        a, b = fused.step(f), staged.step(f)
        _same(a, b)
        extended += int((fused.tracks.update == UpdateKind.EXTENDED).sum())
    assert extended > 5


def test_frames_the_fused_step_does_not_take_go_down_the_staged_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """After a gap (re-association), with a class measured in numpy (L2), past the dense
    size: the staged path, and the same tracks as a tracker that never fuses."""
    frames = stream(3)
    frames[12] = replace(frames[12], after_gap=True)
    seen = _calls(monkeypatch)
    for cfg in (config(), config(metric=Metric.L2, max_distance=2.0)):
        fused, staged = Tracker(cfg), Tracker(cfg)
        staged._fused = False
        for f in frames:
            _same(fused.step(f), staged.step(f))
    assert seen["fused"] == len(frames) - 1  # the L2 tracker and the gap frame: staged
    monkeypatch.setattr(tracker_module, "DENSE_CELLS", 4)
    seen["fused"] = 0
    t = Tracker(config())
    for f in frames[:5]:
        t.step(f)
    assert seen["fused"] == 1  # the first frame only: no tracks yet, 0 pairs


@pytest.mark.parametrize("tie_order", list(TieOrder))
def test_frames_with_an_ego_pose_are_moved_then_tracked_as_on_the_staged_path(
    tie_order: TieOrder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The degenerate boxes dropped and the world frame applied before the compiled call."""
    frames = []
    for k, f in enumerate(stream(6)):
        yaw = 0.3 + 0.02 * k
        pose = np.eye(4)
        pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        pose[:3, 3] = [100.0 + k, -50.0, 1.0]
        frames.append(replace(f, pose=pose))
    seen = _calls(monkeypatch)
    cfg = config().model_copy(update={"tie_order": tie_order})
    fused, staged = Tracker(cfg), Tracker(cfg)
    staged._fused = False
    for f in frames:
        _same(fused.step(f), staged.step(f))
    assert seen["fused"] == len(frames) and fused.next_id > 30


def test_read_only_detections_are_tracked_as_writable_ones() -> None:
    """Decoded frames hold views of the message's bytes: read-only arrays."""
    frames = stream(4)
    plain, read_only = Tracker(config()), Tracker(config())
    for f in frames:
        b = f.boxes
        cols = [b.params.copy(), b.score.copy(), b.cls.copy(), b.velocity.copy()]
        for a in cols:
            a.flags.writeable = False
        frozen = replace(
            f, boxes=Boxes(params=cols[0], score=cols[1], cls=cols[2], velocity=cols[3])
        )
        _same(read_only.step(frozen), plain.step(f))


def test_a_frame_the_compiled_solve_gives_up_on_is_tracked_by_the_staged_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """InfeasibleBlock (a Hungarian block without a finite full assignment) leaves no trace:
    the staged path tracks the frame (and raises scipy's error if the block is infeasible)."""
    frames = stream(5)

    def gives_up(*args: Any) -> Any:
        raise InfeasibleBlock("no finite assignment")

    monkeypatch.setattr(tracker_module, "step_frame", gives_up)
    retried, staged = Tracker(config()), Tracker(config())
    staged._fused = False
    for f in frames:
        _same(retried.step(f), staged.step(f))
    assert retried.next_id == staged.next_id and retried.frame_count == staged.frame_count
