"""The compiled stage-1 assignment (core/assignment_kernels.py): its solver gives scipy's
answer, ties and all, and the tracker run with it tracks exactly as with the Python path."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from scipy.optimize import linear_sum_assignment

from simpletrack.core import assignment_kernels as ak
from simpletrack.core import tracker as tracker_module
from simpletrack.core.config import Matcher, Metric, TrackerConfig
from simpletrack.core.frames import Frame
from simpletrack.core.lifecycle import UpdateKind
from simpletrack.core.tracker import Tracker
from tests.core.helpers import config
from tests.core.helpers import crowd as helpers_crowd

F64 = npt.NDArray[np.float64]


def cost_cases(seed: int) -> list[F64]:
    """Random, tied (small integers, constant), with dear 'far' pairs, with +inf holes; every
    shape from empty to 8 x 8, both orientations."""
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(400):
        n, m = (int(v) for v in rng.integers(0, 9, 2))
        kind = k % 5
        if kind == 0:
            c = rng.random((n, m))
        elif kind == 1:
            c = rng.integers(0, 3, (n, m)).astype(np.float64)
        elif kind == 2:
            c = np.full((n, m), 1.5)
        else:
            c = rng.random((n, m))
            c[rng.random((n, m)) < 0.3] = 1e6 if kind == 3 else np.inf
        cases.append(c)
    return cases


@pytest.mark.parametrize("seed", range(5))
def test_lsap_is_scipys_assignment_ties_included(seed: int) -> None:
    infeasible = 0
    for cost in cost_cases(seed):
        rows, cols, status = ak.lsap(cost)
        try:
            want_rows, want_cols = linear_sum_assignment(cost)
        except ValueError:  # no full assignment of finite cost
            infeasible += 1
            assert status == ak.INFEASIBLE
            continue
        assert status == 0
        np.testing.assert_array_equal(rows, want_rows)
        np.testing.assert_array_equal(cols, want_cols)
    assert infeasible > 0  # the +inf cases include some without a full assignment


def test_lsap_solves_large_costs_as_given_like_scipy() -> None:
    # Shifting costs by their minimum first would round these differently: scipy takes (0, 1).
    tie = np.array([[3.0000000000000010e15, 3.0000000000000010e15], [3.0000000000000005e15, 3e15]])
    tie[1, 1] = 3.0000000000000010e15
    rng = np.random.default_rng(3)
    for cost in [tie] + [rng.random((5, 7)) * 1e3 + 3e15 for _ in range(200)]:
        rows, cols, status = ak.lsap(cost)
        want_rows, want_cols = linear_sum_assignment(cost)
        assert status == 0
        np.testing.assert_array_equal(rows, want_rows)
        np.testing.assert_array_equal(cols, want_cols)


@pytest.mark.parametrize("bad", [np.nan, -np.inf])
def test_lsap_refuses_what_scipy_refuses(bad: float) -> None:
    cost = np.ones((3, 3))
    cost[1, 2] = bad
    with pytest.raises(ValueError):
        linear_sum_assignment(cost)
    assert ak.lsap(cost)[2] == ak.INFEASIBLE


def test_compiled_solver_equals_its_python_function() -> None:
    for cost in cost_cases(11)[:100]:
        got, plain = ak.lsap(cost), ak.lsap.py(cost)
        assert got[2] == plain[2]
        np.testing.assert_array_equal(got[0], plain[0])
        np.testing.assert_array_equal(got[1], plain[1])


def crowd(seed: int, frames: int = 25) -> list[Frame]:
    return helpers_crowd(seed, frames, 24, seen=0.8)


def configs() -> list[TrackerConfig]:
    return [
        config(),
        config(matcher=Matcher.GREEDY),
        config(gate_widening=0.2, max_age=3),
        config(matcher=Matcher.GREEDY, gate_widening=0.2, max_age=3),
        config(metric=Metric.L2, max_distance=2.0),
        config(metric=Metric.IOU_BEV, max_distance=0.9),
    ]


@pytest.mark.parametrize("index", range(len(configs())))
@pytest.mark.parametrize("seed", range(3))
def test_tracker_tracks_as_with_the_python_assignment(
    index: int, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = configs()[index]
    frames = crowd(seed)
    t = Tracker(cfg)
    compiled = [t.step(f) for f in frames]

    def python_path(*args: object) -> tuple[object, ...]:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty, ak.INFEASIBLE  # what sends _stage1 down its Python path

    monkeypatch.setattr(tracker_module, "stage1_dense", python_path)
    t = Tracker(cfg)
    t._fused = False  # the staged path, where stage1_dense is looked up
    plain = [t.step(f) for f in frames]
    matched = 0
    for a, b in zip(compiled, plain, strict=True):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.boxes.params, b.boxes.params)
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.update, b.update)
        matched += int((a.update == UpdateKind.MATCHED).sum())
    assert matched > 50  # the crowd is tracked, not just born and dropped
