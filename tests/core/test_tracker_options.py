"""The per-class track-score and life-cycle options, each as a user of the tracker sees it:
the score a track emits, when it dies, when it is still written, how far its gate reaches."""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import msgpack
import numpy as np
import pytest
from pydantic import ValidationError

from simpletrack.core import tracker as tracker_module
from simpletrack.core.config import ClassConfig, Matcher, Metric, TrackerConfig, preset
from simpletrack.core.frames import Tracks
from simpletrack.core.lifecycle import UpdateKind
from simpletrack.core.tracker import Tracker
from tests.core.helpers import car, config, frame

OFF: dict[str, Any] = {
    "track_score": "detection",
    "score_decay": 0.05,
    "delete_below": None,
    "coast_output": 0,
    "gate_widening": 0.0,
    "max_position_std": None,
}


def _scene(seed: int, n_frames: int = 40, n_obj: int = 14) -> list[list[list[float]]]:
    """Objects of two classes moving at random, missed 25 % of the time, plus clutter."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-30, 30, size=(n_obj, 2))
    vel = rng.uniform(-10, 10, size=(n_obj, 2))
    frames = []
    for k in range(n_frames):
        rows = []
        for i in range(n_obj):
            if rng.random() < 0.75:
                x, y = start[i] + vel[i] * 0.1 * k + rng.normal(scale=0.3, size=2)
                rows.append(car(float(x), float(y), float(rng.uniform(0.05, 1.0)), i % 2))
        for _ in range(int(rng.integers(0, 4))):
            x, y = rng.uniform(-40, 40, size=2)
            rows.append(car(float(x), float(y), float(rng.uniform(0.05, 0.9)), int(k % 2)))
        frames.append(rows)
    return frames


def _run(cfg: TrackerConfig, frames: list[list[list[float]]]) -> list[Tracks]:
    t = Tracker(cfg)
    return [t.step(frame(rows, 0.1 * k)) for k, rows in enumerate(frames)]


def _rows(out: Tracks, keep: np.ndarray) -> list[np.ndarray]:
    return [
        out.ids[keep],
        out.boxes.params[keep],
        out.boxes.score[keep],
        out.state[keep],
        out.update[keep],
        out.hits[keep],
        out.age[keep],
        out.time_since_update[keep],
    ]


def _same(a: list[Tracks], b: list[Tracks], cls: int | None = None, ids: bool = True) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        kx = np.ones(len(x), bool) if cls is None else x.boxes.cls == cls
        ky = np.ones(len(y), bool) if cls is None else y.boxes.cls == cls
        for u, v in list(zip(_rows(x, kx), _rows(y, ky), strict=True))[0 if ids else 1 :]:
            np.testing.assert_array_equal(u, v)


def _with(cfg: TrackerConfig, code: int | None = None, **fields: Any) -> TrackerConfig:
    classes = {
        name: {**c.model_dump(), **fields} if code in (None, i) else c.model_dump()
        for i, (name, c) in enumerate(cfg.classes.items())
    }
    return cfg.with_overrides(classes=classes)


# ------------------------------------------------------------------ all off = today
@pytest.mark.parametrize("name", ["kitti", "wod", "nuscenes"])
def test_options_set_off_explicitly_track_exactly_like_the_defaults(name: str) -> None:
    base = preset(name)
    # Two of the preset's classes, built once with every option spelt out as off and once
    # from the fields this tracker had before the options (their defaults fill the rest).
    two = dict(list(base.classes.items())[:2])
    spelt = {n: {**c.model_dump(), **OFF} for n, c in two.items()}
    before = {n: c.model_dump(exclude=set(OFF)) for n, c in two.items()}
    frames = _scene(7)
    _same(
        _run(base.with_overrides(classes=spelt), frames),
        _run(base.with_overrides(classes=before), frames),
    )


def test_options_of_one_class_leave_the_other_class_alone() -> None:
    base = config(min_hits=2, max_age=4)
    on = _with(
        base,
        code=0,
        track_score="fused",
        score_decay=0.1,
        delete_below=0.3,
        coast_output=2,
        gate_widening=0.5,
        max_position_std=3.0,
    )
    frames = _scene(3)
    changed, plain = _run(on, frames), _run(base, frames)
    # Ids interleave over classes (births differ), so compare the other class's rows' content.
    _same(changed, plain, cls=1, ids=False)
    with pytest.raises(AssertionError):
        _same(changed, plain, cls=0, ids=False)


# ------------------------------------------------------------------ fused track score
def _mean_emitted(cfg: TrackerConfig) -> tuple[float, float, list[float]]:
    """A true car seen for 20 frames and a false one for 3, every detection scored 0.6."""
    t = Tracker(cfg)
    scores: dict[int, list[float]] = defaultdict(list)
    for k in range(20):
        rows = [car(1.0 * k, 0.0, score=0.6)]
        if 5 <= k < 8:
            rows.append(car(0.0, 40.0, score=0.6))
        out = t.step(frame(rows, 0.1 * k))
        for i, s in zip(out.ids.tolist(), out.boxes.score.tolist(), strict=True):
            scores[i].append(s)
    first = scores[0][:3]
    assert sorted(scores) == [0, 1] and len(scores[0]) == 20 and len(scores[1]) == 3
    return float(np.mean(scores[0])), float(np.mean(scores[1])), first


def test_fused_score_ranks_a_long_true_track_above_a_short_false_one() -> None:
    plain = config(min_hits=0, two_stage=False)  # every row written, from the first
    true_mean, false_mean, _ = _mean_emitted(plain)
    assert true_mean == pytest.approx(false_mean)  # detection scores alone cannot rank them
    fused = _with(plain, track_score="fused", score_decay=0.05)
    true_mean, false_mean, first = _mean_emitted(fused)
    assert true_mean > false_mean + 0.1
    # CBMOT's rule: the track's score drops by 0.05, then 1 - (1 - s_det)(1 - s_track).
    assert first == pytest.approx([0.6, 1 - 0.4 * (1 - 0.55), 1 - 0.4 * (1 - 0.77)])


def test_delete_below_kills_a_track_once_its_fused_score_sinks_under_it() -> None:
    def missed_frames_lived(**opts: Any) -> int:
        cfg = config(min_hits=1, max_age=10, two_stage=False, track_score="fused", **opts)
        t = Tracker(cfg)
        for k in range(3):  # scores 0.6, 0.8, 0.88
            t.step(frame([car(1.0 * k, score=0.6)], 0.1 * k))
        for k in range(3, 13):
            t.step(frame([], 0.1 * k))
            if len(t.tracks) == 0:
                return k - 3
        return 10

    # Coasting drops 0.88 by 0.1 a frame: 0.78 0.68 0.58, then 0.48 < 0.5 on the 4th miss.
    assert missed_frames_lived(score_decay=0.1, delete_below=0.5) == 3
    assert missed_frames_lived(score_decay=0.1) == 9  # off: max_age 10 kills on the 10th
    assert missed_frames_lived(score_decay=0.1, delete_below=0.3) == 5  # 0.28 on the 6th


def test_delete_below_spares_tentative_tracks() -> None:
    t = Tracker(config(min_hits=3, max_age=5, two_stage=False, delete_below=0.95))
    for k in range(4):
        t.step(frame([], 0.1 * k))  # past the first min_hits frames: births are tentative
    t.step(frame([car(0.0, score=0.6)], 0.4))
    t.step(frame([], 0.5))
    assert len(t.tracks) == 1  # 0.6 * 0.01 is far under 0.95, yet tentative: kept
    t.step(frame([car(0.2, score=0.6)], 0.6))
    t.step(frame([car(0.4, score=0.6)], 0.7))  # third hit: confirmed, scored 0.6 < 0.95
    assert len(t.tracks) == 0


# ------------------------------------------------------------------ coasting output
def test_coast_output_writes_a_coasting_track_with_its_last_match_score_then_stops() -> None:
    def written(coast_output: int) -> list[list[tuple[int, float]]]:
        t = Tracker(config(min_hits=1, max_age=4, two_stage=False, coast_output=coast_output))
        rows = []
        for k, s in enumerate([0.9, 0.8, 0.77]):
            rows.append(t.step(frame([car(1.0 * k, score=s)], 0.1 * k)))
        for k in range(3, 7):
            rows.append(t.step(frame([], 0.1 * k)))
        return [list(zip(o.ids.tolist(), o.boxes.score.tolist(), strict=True)) for o in rows]

    assert written(0)[3:] == [[], [], [], []]
    out = written(2)
    assert out[:3] == [[(0, 0.9)], [(0, 0.8)], [(0, 0.77)]]
    assert out[3:5] == [[(0, 0.77)], [(0, 0.77)]]  # not 0.77 * 0.01
    assert out[5:] == [[], []]  # two frames, then silent (alive until max_age 4)
    assert written(3)[3:] == [[(0, 0.77)]] * 3 + [[]]


def test_coast_output_writes_the_prediction_moving_on() -> None:
    t = Tracker(config(min_hits=1, max_age=3, two_stage=False, coast_output=2))
    for k in range(8):
        t.step(frame([car(1.0 * k)], 0.1 * k))  # 10 m/s along x
    a = t.step(frame([], 0.8))
    b = t.step(frame([], 0.9))
    assert a.boxes.x[0] == pytest.approx(8.0, abs=0.3)
    assert b.boxes.x[0] == pytest.approx(9.0, abs=0.3)


def test_coast_output_keeps_the_fused_score_of_the_last_match() -> None:
    t = Tracker(config(min_hits=1, max_age=3, two_stage=False, coast_output=1, track_score="fused"))
    for k in range(2):
        last = t.step(frame([car(1.0 * k, score=0.6)], 0.1 * k))
    coasting = t.step(frame([], 0.2))
    assert coasting.boxes.score.tolist() == last.boxes.score.tolist() == [pytest.approx(0.82)]


# ------------------------------------------------------------------ widening gate
def _occlusion_ids(
    widening: float, jump: float, missed: int = 3, matcher: Matcher = Matcher.HUNGARIAN
) -> list[list[int]]:
    """A car at 10 m/s for 15 frames, unseen for ``missed`` frames, seen again ``jump``
    metres ahead of where its constant velocity puts it (it sped up while hidden)."""
    cfg = config(
        min_hits=1,
        max_age=5,
        two_stage=False,
        metric=Metric.L2,
        max_distance=2.0,
        gate_widening=widening,
        matcher=matcher,
    )
    t = Tracker(cfg)
    ids = []
    for k in range(15):
        ids.append(t.step(frame([car(1.0 * k)], 0.1 * k)).ids.tolist())
    for k in range(15, 15 + missed):
        t.step(frame([], 0.1 * k))
    for k in range(15 + missed, 20 + missed):
        ids.append(t.step(frame([car(1.0 * k + jump)], 0.1 * k)).ids.tolist())
    return ids


@pytest.mark.parametrize("matcher", list(Matcher))
@pytest.mark.parametrize("gated", [False, True], ids=["dense", "gated"])
def test_widening_gate_keeps_identity_through_an_occlusion(
    matcher: Matcher, gated: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    if gated:  # every class block on the sparse path: the gate itself must reach that far
        monkeypatch.setattr(tracker_module, "DENSE_CELLS", 0)
    # 3 m off after 3 missed frames: beyond the fixed 2 m gate, within 2 + 0.5 * 3.
    assert _occlusion_ids(0.0, 3.0, matcher=matcher)[-1] == [1]  # renumbered
    assert set(map(tuple, _occlusion_ids(0.5, 3.0, matcher=matcher))) == {(0,)}
    # 3.75 m is beyond 3.5: the widening counts the 3 missed frames, not 4.
    assert _occlusion_ids(0.5, 3.75, matcher=matcher)[-1] == [1]


@pytest.mark.parametrize("matcher", list(Matcher))
@pytest.mark.parametrize("cells", [None, 0, 4], ids=["dense", "gated", "mixed"])
def test_widening_gate_widens_only_the_coasting_tracks_gate(
    matcher: Matcher, cells: int | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two cars at 10 m/s; B is unseen for 3 frames. On the frame B is seen again 3 m off,
    A (seen every frame) is seen 2.5 m off: B's gate has widened to 3.5 m, A's is 2 m.
    Three parked cars of the other class make that class's block the larger one: with
    ``cells`` 4 the moving cars' class is solved dense inside a gated frame."""
    if cells is not None:
        monkeypatch.setattr(tracker_module, "DENSE_CELLS", cells)
    cfg = config(
        min_hits=1,
        max_age=5,
        two_stage=False,
        metric=Metric.L2,
        max_distance=2.0,
        gate_widening=0.5,
        matcher=matcher,
    )
    parked = [car(10.0 * i, -50.0, cls=1) for i in range(3)]
    t = Tracker(cfg)

    def moving_ids() -> dict[float, int]:
        live = (t.tracks.update == UpdateKind.MATCHED) & (t.tracks.cls == 0)
        ys = t.tracks.out_box[live, 1].round().tolist()
        return dict(zip(ys, t.tracks.ids[live].tolist(), strict=True))

    for k in range(15):
        t.step(frame([car(1.0 * k, 0.0), car(1.0 * k, 20.0), *parked], 0.1 * k))
    before = moving_ids()
    for k in range(15, 18):
        t.step(frame([car(1.0 * k, 0.0), *parked], 0.1 * k))
    t.step(frame([car(18.0 + 2.5, 0.0), car(18.0 + 3.0, 20.0), *parked], 1.8))
    after = moving_ids()
    assert after[20.0] == before[20.0]  # B kept its id
    assert after[0.0] not in before.values()  # A's detection started a new track


def test_widening_gate_leaves_a_track_seen_last_frame_at_max_distance() -> None:
    # No missed frame (k = 0): a 2.25 m jump is beyond the 2 m gate, widening or not.
    assert _occlusion_ids(widening=0.5, jump=2.25, missed=0)[-1] == [1]
    assert _occlusion_ids(widening=0.5, jump=1.75, missed=0)[-1] == [0]


# ------------------------------------------------------------------ covariance bound
def _missed_frames_lived(max_age: int = 10, **opts: Any) -> int:
    t = Tracker(config(min_hits=1, max_age=max_age, two_stage=False, **opts))
    for k in range(10):
        t.step(frame([car(1.0 * k)], 0.1 * k))
    for k in range(10, 10 + max_age):
        t.step(frame([], 0.1 * k))
        if len(t.tracks) == 0:
            return k - 10
    return max_age


def test_max_position_std_deletes_a_track_that_coasts_too_long() -> None:
    # Predicted sqrt(P_xx + P_yy) after 1..4 missed frames: 2.03 2.36 2.78 3.25 m.
    assert _missed_frames_lived(max_position_std=3.0) == 3
    assert _missed_frames_lived(max_position_std=2.5) == 2
    assert _missed_frames_lived() == 9  # off: max_age 10 kills on the 10th miss
    # max_age stays the upper bound however loose the bound.
    assert _missed_frames_lived(max_age=3, max_position_std=100.0) == 2


def test_max_position_std_spares_a_matched_track() -> None:
    # A new track's first prediction is 4.5 m uncertain (P0 = 10 per axis), over the bound,
    # but the detection it matches corrects it: it lives on.
    t = Tracker(config(min_hits=1, max_age=10, two_stage=False, max_position_std=3.0))
    ids = [t.step(frame([car(1.0 * k)], 0.1 * k)).ids.tolist() for k in range(5)]
    assert ids == [[0]] * 5


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    ("fields", "named"),
    [
        (
            {"coast_output": 2, "max_age": 2},
            r"coast_output \(2\) must be at most max_age - 1 \(1\)",
        ),
        ({"coast_output": -1}, "-1"),
        ({"gate_widening": -0.5}, r"-0\.5"),
        ({"score_decay": 1.5}, r"1\.5"),
        ({"delete_below": 2.0}, r"2\.0"),
        ({"max_position_std": 0.0}, r"max_position_std[\s\S]*0\.0"),
        ({"track_score": "mean"}, "mean"),
    ],
)
def test_bad_option_values_are_rejected_naming_the_value(
    fields: dict[str, Any], named: str
) -> None:
    with pytest.raises(ValidationError, match=named):
        ClassConfig.model_validate(fields)


def test_valid_options_load_from_plain_values() -> None:
    c = ClassConfig.model_validate(
        {"track_score": "fused", "delete_below": 0.2, "coast_output": 1, "max_position_std": 4}
    )
    assert c.track_score == "fused" and c.max_position_std == 4.0
    assert ClassConfig(max_age=5, gate_widening=0.5).widest_max_distance == 1.5 + 0.5 * 5


# ------------------------------------------------------------------ snapshots
def test_a_snapshot_from_before_match_score_restores_and_continues() -> None:
    cfg = config(min_hits=1, max_age=4, two_stage=False, coast_output=2)
    frames = [[car(1.0 * k, score=0.5 + 0.04 * k)] if k < 6 else [] for k in range(10)]
    whole = _run(cfg, frames)
    t = Tracker(cfg)
    for k, rows in enumerate(frames[:6]):
        t.step(frame(rows, 0.1 * k))
    old = msgpack.unpackb(t.to_bytes(), raw=False)
    del old["tracks"]["match_score"]  # the key set snapshots had before the column
    restored = Tracker.from_bytes(msgpack.packb(old, use_bin_type=True))
    np.testing.assert_array_equal(restored.tracks.match_score, restored.tracks.score)
    rest = [restored.step(frame(rows, 0.1 * k)) for k, rows in enumerate(frames[6:], start=6)]
    _same(rest, whole[6:])  # the last match's score was the current one: nothing lost
    assert [o.boxes.score.tolist() for o in rest[:2]] == [[pytest.approx(0.7)]] * 2


def test_a_snapshot_missing_an_original_column_is_refused() -> None:
    t = Tracker(config(min_hits=1))
    t.step(frame([car(0.0)], 0.0))
    old = msgpack.unpackb(t.to_bytes(), raw=False)
    del old["tracks"]["hits"]
    with pytest.raises(ValueError, match="lacks hits"):
        Tracker.from_bytes(msgpack.packb(old, use_bin_type=True))
