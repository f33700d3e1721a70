"""Behaviour a user of the tracker notices: identities, births, deaths, outputs."""

from __future__ import annotations

import numpy as np
import pytest

from simpletrack.core.config import OutputPolicy, preset
from simpletrack.core.lifecycle import TrackState
from simpletrack.core.tracker import Tracker
from tests.core.helpers import car, config, frame


def _ids(tracker: Tracker, rows: list[list[float]], stamp: float) -> list[int]:
    return tracker.step(frame(rows, stamp)).ids.tolist()


def test_empty_frames_give_empty_tracks() -> None:
    t = Tracker(config())
    for k in range(3):
        out = t.step(frame([], k * 0.1))
        assert len(out) == 0 and out.boxes.params.shape == (0, 7)


def test_identity_kept_for_a_moving_object() -> None:
    t = Tracker(config(min_hits=1))
    ids = [_ids(t, [car(1.0 * k)], 0.1 * k) for k in range(10)]
    assert ids[0] == [0] and all(i == [0] for i in ids)


def test_two_objects_keep_separate_ids() -> None:
    t = Tracker(config(min_hits=1))
    for k in range(8):
        out = t.step(frame([car(0.5 * k, 0.0), car(0.5 * k, 6.0)], 0.1 * k))
        by_y = dict(zip(out.boxes.y.round().tolist(), out.ids.tolist(), strict=True))
        assert by_y == {0.0: 0, 6.0: 1}


def test_paper_policy_outputs_after_min_hits() -> None:
    t = Tracker(config(min_hits=3))
    counts = []
    for k in range(6):
        counts.append(len(t.step(frame([car(0.5 * k)], 0.1 * k))))
    # The first min_hits frames of a sequence confirm at once (the reference's rule).
    assert counts == [1, 1, 1, 1, 1, 1]
    late = Tracker(config(min_hits=3))
    for k in range(5):
        late.step(frame([], 0.1 * k))
    outs = [len(late.step(frame([car(0.5 * k)], 0.5 + 0.1 * k))) for k in range(4)]
    assert outs == [0, 0, 1, 1]


def test_reference_policy_also_outputs_tentative_tracks() -> None:
    t = Tracker(config(output=OutputPolicy.REFERENCE, min_hits=3))
    for k in range(5):
        t.step(frame([], 0.1 * k))
    out = t.step(frame([car(0.0)], 0.5))
    assert len(out) == 1 and out.state[0] == TrackState.TENTATIVE


def test_track_dies_after_max_age_missed_frames() -> None:
    t = Tracker(config(min_hits=1, max_age=2, two_stage=False))
    for k in range(3):
        t.step(frame([car(0.5 * k)], 0.1 * k))
    t.step(frame([], 0.3))
    assert len(t.tracks) == 1  # one miss: coasting
    t.step(frame([], 0.4))
    assert len(t.tracks) == 0  # max_age misses: dead
    # A detection at the same place now starts a new identity: ids are never reused.
    t.step(frame([car(2.5)], 0.5))
    assert t.tracks.ids.tolist() == [1]


def test_identity_kept_through_a_one_frame_gap() -> None:
    t = Tracker(config(min_hits=1, max_age=2, two_stage=False))
    ids = []
    for k in range(8):
        rows = [] if k == 4 else [car(1.0 * k)]
        ids.append(_ids(t, rows, 0.1 * k))
    assert ids[4] == []  # coasting tracks are not output by the paper policy
    assert ids[5:] == [[0], [0], [0]]


def test_two_stage_association_keeps_identity_through_low_scores() -> None:
    """The paper's fig. 6: scores 0.9 0.8 0.4 0.2 0.8 with T_h = 0.5, T_l = 0.1."""
    scores = [0.9, 0.8, 0.4, 0.2, 0.8]

    def run(two_stage: bool) -> list[list[int]]:
        t = Tracker(config(min_hits=1, max_age=2, two_stage=two_stage))
        return [_ids(t, [car(1.0 * k, score=s)], 0.1 * k) for k, s in enumerate(scores)]

    one = run(two_stage=False)
    two = run(two_stage=True)
    assert one[4] != [0]  # one-stage: terminated early, a new id: an identity switch
    assert two == [[0], [0], [], [], [0]]  # extended, not output on low frames, same id


def test_detection_never_matches_a_track_of_another_class() -> None:
    t = Tracker(config(min_hits=1))
    t.step(frame([car(0.0, cls=0)], 0.0))
    t.step(frame([car(0.0, cls=1)], 0.1))
    assert t.tracks.ids.tolist() == [0, 1] and t.tracks.cls.tolist() == [0, 1]
    assert t.tracks.time_since_update.tolist() == [1, 0]  # the car track was not updated


def test_low_score_detections_never_start_tracks() -> None:
    t = Tracker(config(min_hits=1))
    t.step(frame([car(0.0, score=0.3)], 0.0))
    assert len(t.tracks) == 0


def test_nms_removes_duplicates_before_tracking() -> None:
    t = Tracker(config(min_hits=1))
    out = t.step(frame([car(0.0, score=0.9), car(0.2, score=0.8)], 0.0))
    assert len(out) == 1 and out.boxes.score[0] == pytest.approx(0.9)


def test_nuscenes_policy_outputs_coasting_prediction_with_decayed_score() -> None:
    t = Tracker(preset("nuscenes"))
    moving = [[1.0 * k, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.8, 0] for k in range(3)]
    for k in range(3):
        t.step(frame([moving[k]], 0.5 * k))
    out = t.step(frame([], 1.5))
    assert len(out) == 1
    assert out.boxes.score[0] == pytest.approx(0.8 * 0.01)
    assert out.boxes.x[0] > 2.0  # the prediction moved on
    assert len(t.step(frame([], 2.0))) == 0  # max_age 2: dead


def test_key_frame_mode_uses_non_key_frames_only_to_update() -> None:
    cfg = preset("nuscenes")
    t = Tracker(cfg)
    t.step(frame([[0.0, 0, 0, 0, 4, 2, 1.5, 0.9, 0]], 0.0))
    # A non-key frame: a high-score detection updates; a new far one starts nothing.
    out = t.step(
        frame(
            [[0.5, 0, 0, 0, 4, 2, 1.5, 0.9, 0], [40.0, 0, 0, 0, 4, 2, 1.5, 0.9, 0]],
            0.1,
            key_frame=False,
        )
    )
    assert out.ids.tolist() == [0]
    assert len(t.tracks) == 1
    assert t.tracks.hits.tolist() == [1]  # life counters move on key frames only


def test_world_frame_tracking_with_ego_motion() -> None:
    # A parked car seen from a vehicle driving forward: static in the world, one id.
    from simpletrack.core.frames import Frame

    t = Tracker(config(min_hits=1))
    for k in range(6):
        pose = np.eye(4)
        pose[0, 3] = 2.0 * k  # ego moves +2 m per frame
        f = frame([car(20.0 - 2.0 * k)], 0.1 * k)
        out = t.step(Frame(boxes=f.boxes, stamp=f.stamp, pose=pose))
        assert out.ids.tolist() == [0]
        assert out.boxes.x[0] == pytest.approx(20.0, abs=0.5)
        back = out.in_sensor_frame(pose)
        assert back.boxes.x[0] == pytest.approx(20.0 - 2.0 * k, abs=0.5)


def test_stamps_must_not_go_backwards() -> None:
    t = Tracker(config())
    t.step(frame([], 1.0))
    with pytest.raises(ValueError, match="before"):
        t.step(frame([], 0.5))


def test_thousand_boxes_in_one_frame() -> None:
    rng = np.random.default_rng(0)
    n = 1000
    rows = np.zeros((n, 9))
    rows[:, 0] = np.arange(n) * 6.0  # well separated
    rows[:, 1] = rng.uniform(-1, 1, n)
    rows[:, 4:7] = [4.0, 2.0, 1.5]
    rows[:, 7] = 0.9
    t = Tracker(config(min_hits=1))
    a = t.step(frame(rows.tolist(), 0.0))
    rows[:, 0] += 0.3
    b = t.step(frame(rows.tolist(), 0.1))
    assert len(a) == len(b) == n
    assert sorted(b.ids.tolist()) == list(range(n))
