"""Re-association across a bridged gap: the frame after an outage flagged ``after_gap``.

The scenes are seen from a moving sensor (as KITTI's camera): three parked cars approach it at
the ego's 10 m/s; during a 5 s outage the ego slowed, so every car is 20 m short of where its
velocity puts it, beyond the stage-1 gate, by the same shift."""

from __future__ import annotations

import numpy as np

from simpletrack.core.config import OutputPolicy
from simpletrack.core.frames import Frame
from simpletrack.core.reassociation import reassociate
from simpletrack.core.tracker import Tracker
from tests.core.helpers import car, config, frame

EGO_SPEED = 10.0
GAP_S = 5.0
SHORTFALL_M = 20.0  # how much less the ego drove during the gap than its speed says


def _track_then_gap(
    lateral: list[float], after: list[float], after_gap: bool
) -> tuple[dict[float, int], dict[float, int]]:
    """Ids by lateral position before the gap and on the first frame after it (cars at
    ``lateral`` before, at ``after`` after: the same cars, or others)."""
    tracker = Tracker(config(OutputPolicy.REFERENCE))
    out = None
    for k in range(10):
        x = 80.0 - EGO_SPEED * 0.1 * k
        out = tracker.step(frame([car(x, y) for y in lateral], stamp=0.1 * k))
    assert out is not None and len(out) == len(lateral)
    before = dict(zip(out.boxes.params[:, 1].round(1).tolist(), out.ids.tolist(), strict=True))
    stamp = 0.9 + GAP_S
    x = 80.0 - EGO_SPEED * stamp + SHORTFALL_M
    f = frame([car(x, y) for y in after], stamp=stamp)
    out = tracker.step(Frame(boxes=f.boxes, stamp=f.stamp, after_gap=after_gap))
    now = dict(zip(out.boxes.params[:, 1].round(1).tolist(), out.ids.tolist(), strict=True))
    return before, now


def test_parked_cars_keep_their_ids_across_a_5_s_bridged_gap() -> None:
    before, now = _track_then_gap([-8.0, 0.0, 8.0], [-8.0, 0.0, 8.0], after_gap=True)
    assert now == before


def test_without_the_gap_flag_the_missed_prediction_gives_new_ids() -> None:
    before, now = _track_then_gap([-8.0, 0.0, 8.0], [-8.0, 0.0, 8.0], after_gap=False)
    assert not set(now.values()) & set(before.values())


def test_two_cars_side_by_side_never_swap_ids_across_a_gap() -> None:
    # 3 m apart: either detection could be either car, so neither takes an old id.
    before, now = _track_then_gap([0.0, 3.0], [0.0, 3.0], after_gap=True)
    assert now[0.0] != before[3.0] and now[3.0] != before[0.0]


def test_a_car_appearing_elsewhere_does_not_take_a_leaving_cars_id() -> None:
    # The car at y = 7 left the view; another appears at y = 28, far from where the
    # common shift puts any track: it is a new object.
    before, now = _track_then_gap([-12.0, 0.0, 7.0], [-12.0, 0.0, 28.0], after_gap=True)
    assert now[-12.0] == before[-12.0] and now[0.0] == before[0.0]
    assert now[28.0] not in before.values()


def test_reassociation_never_pairs_different_classes() -> None:
    xy = np.array([[0.0, 0.0]])
    det, trk = reassociate(xy, np.array([0], np.int32), xy, np.array([1], np.int32), np.ones(1))
    assert det.size == 0 and trk.size == 0
