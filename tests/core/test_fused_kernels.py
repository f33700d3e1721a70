"""A fused vehicle's compiled bookkeeping (core/fused_kernels.py) gives, bit for bit, what the
numpy it replaced in core/vehicle.py gave, compiled and as Python: born, updated, coasting and
hidden tracks, key frames and not, every output policy, empty sides."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from simpletrack.core import fused_kernels as fk
from simpletrack.core.advance_kernels import POLICY_NUSCENES, POLICY_REFERENCE

COASTED, MATCHED, EXTENDED = 0, 1, 3
TENTATIVE, CONFIRMED = 0, 1
LOGIT_MAX = 6.9


def numpy_columns(b: dict[str, Any], a: dict[str, Any]) -> tuple[Any, ...]:
    """``VehicleTracker._columns`` as it was, numpy over the rows."""
    n, n_s = a["ids"].size, b["misses"].shape[1]
    before_ids, born, upd, s = b["ids"], a["born"], a["update"], a["s"]
    pos = np.minimum(np.searchsorted(before_ids, a["ids"]), max(before_ids.size - 1, 0))
    old = ~born
    misses = np.full((n, n_s), -1, dtype=np.int32)
    stamps = np.full((n, n_s), -1, dtype=np.int64)
    kind = np.full(n, MATCHED, dtype=np.int8)
    odds = np.zeros(n)
    occluded = np.zeros(n, dtype=np.int32)
    hidden = np.zeros(n, dtype=bool)
    if before_ids.size:
        misses[old] = b["misses"][pos[old]]
        stamps[old] = b["stamps"][pos[old]]
        kind[old] = b["kind"][pos[old]]
        odds[old] = b["odds"][pos[old]]
        occluded[old] = b["occluded"][pos[old]]
        hidden[old] = b["hidden"][pos[old]]
    updated = old & (upd != COASTED)
    coasted = old & (upd == COASTED) & ~hidden
    unseen = old & (upd == COASTED) & hidden
    occluded[updated | coasted] = 0
    if a["key_frame"]:
        occluded[unseen] += 1
        misses[updated] = -1
        misses[updated, s] = 0
        misses[coasted, s] = np.maximum(misses[coasted, s], 0) + 1
        odds[coasted] += a["miss"]
    stamps[updated, s] = a["stamp"]
    kind[updated] = upd[updated]
    matched = old & (upd == MATCHED)
    odds[matched] += a["evidence"][matched]
    misses[born] = -1
    misses[born, s] = 0
    stamps[born] = -1
    stamps[born, s] = a["stamp"]
    odds[born] = a["evidence"][born]
    np.clip(odds, -LOGIT_MAX, LOGIT_MAX, out=odds)
    return misses, stamps, kind, odds, occluded


def numpy_report(r: dict[str, Any]) -> tuple[Any, ...]:
    """The masks of ``VehicleTracker._report`` as it was."""
    out_ids, ids, tsu, stamps, s = r["out_ids"], r["ids"], r["tsu"], r["stamps"], r["s"]
    n = ids.size
    order = np.argsort(out_ids, kind="stable")
    pos = np.minimum(np.searchsorted(out_ids[order], ids), max(out_ids.size - 1, 0))
    where = order[pos] if out_ids.size else pos
    in_step = (out_ids[where] == ids) if out_ids.size else np.zeros(n, dtype=bool)
    kind = np.full(n, COASTED, dtype=np.int8)
    kind[in_step] = r["out_update"][where[in_step]]
    others = np.delete(stamps, s, axis=1).max(axis=1, initial=-1)
    since = (tsu == 0) & (kind == COASTED) & (~in_step | (others > stamps[:, s]))
    kind = np.where(since, r["last_kind"], kind).astype(np.int8)
    fresh = kind == MATCHED
    confirmed = r["state"] == CONFIRMED
    window = r["coast"][r["cls"]]
    coast = confirmed & ~fresh & (window > 0) & (tsu <= window)
    if r["policy"] == POLICY_NUSCENES:
        keep = np.ones(n, dtype=bool)
    elif r["policy"] == POLICY_REFERENCE:
        keep = (r["state"] == TENTATIVE) | (confirmed & fresh)
    else:
        keep = confirmed & fresh
    keep |= coast
    keep &= fresh | (r["occluded"] == 0)
    if r["doubt"]:
        keep &= ~((r["log_odds"] < r["min"]) & (r["state"] == TENTATIVE))
    return kind, fresh, coast, keep, where, in_step


def column_case(rng: np.random.Generator, trial: int) -> tuple[dict[str, Any], dict[str, Any]]:
    n0, n_s = int(rng.integers(0, 40)), int(rng.integers(1, 4))
    b_ids = np.sort(rng.choice(1000, n0, replace=False)).astype(np.int64)
    b = {
        "ids": b_ids,
        "misses": rng.integers(-1, 5, (n0, n_s)).astype(np.int32),
        "stamps": rng.integers(-1, 10**9, (n0, n_s)).astype(np.int64),
        "kind": rng.choice([COASTED, MATCHED, EXTENDED], n0).astype(np.int8),
        "odds": rng.uniform(-8, 8, n0),  # some past the clip
        "occluded": rng.integers(0, 4, n0).astype(np.int32),
        "hidden": rng.random(n0) < 0.3,
    }
    kept = b_ids[rng.random(n0) < 0.8]  # some tracks die, some are born
    new = np.arange(1000, 1000 + int(rng.integers(0, 10)), dtype=np.int64)
    ids = np.concatenate([kept, new])
    a = {
        "ids": ids,
        "born": ids >= 1000,
        "update": rng.choice([COASTED, MATCHED, EXTENDED], ids.size).astype(np.int8),
        "evidence": np.log(rng.uniform(0.01, 0.99, ids.size) / 0.5),
        "s": int(rng.integers(0, n_s)),
        "key_frame": trial % 3 != 0,
        "stamp": int(rng.integers(0, 10**9)),
        "miss": math.log1p(-rng.uniform(0.1, 0.99)),
    }
    return b, a


def report_case(rng: np.random.Generator, trial: int) -> dict[str, Any]:
    n, n_s, n_cls = int(rng.integers(0, 40)), int(rng.integers(1, 4)), 4
    ids = np.sort(rng.choice(500, n, replace=False)).astype(np.int64)
    out_ids = ids[rng.random(n) < 0.7].copy()
    rng.shuffle(out_ids)  # a step's report is in no particular order
    stamps = rng.integers(-1, 50, (n, n_s)).astype(np.int64)
    return {
        "out_ids": out_ids,
        "out_update": rng.choice([COASTED, MATCHED, EXTENDED], out_ids.size).astype(np.int8),
        "ids": ids,
        "tsu": rng.integers(0, 4, n).astype(np.int32),
        "stamps": stamps,
        "last_kind": rng.choice([COASTED, MATCHED, EXTENDED], n).astype(np.int8),
        "s": int(rng.integers(0, n_s)),
        "state": rng.integers(0, 2, n).astype(np.int8),
        "cls": rng.integers(0, n_cls, n).astype(np.int32),
        "coast": rng.integers(0, 3, n_cls).astype(np.int64),
        "occluded": rng.integers(0, 2, n).astype(np.int32),
        "log_odds": rng.uniform(-3, 3, n),
        "policy": trial % 3,
        "doubt": trial % 2 == 0,
        "min": 0.2,
    }


@pytest.mark.parametrize("compiled", [True, False])
def test_the_fused_columns_equal_the_numpy_they_replaced(compiled: bool) -> None:
    fn = fk.fused_columns if compiled else fk.fused_columns.py
    rng = np.random.default_rng(11)
    for trial in range(300):
        b, a = column_case(rng, trial)
        got = fn(
            b["misses"], b["stamps"], b["kind"], b["odds"], b["occluded"], b["hidden"],
            b["ids"], a["ids"], a["born"], a["update"], a["evidence"], a["s"],
            a["key_frame"], a["stamp"], a["miss"], LOGIT_MAX,
        )  # fmt: skip
        for g, w in zip(got, numpy_columns(b, a), strict=True):
            assert g.dtype == w.dtype
            np.testing.assert_array_equal(g, w, err_msg=f"trial {trial}")


@pytest.mark.parametrize("compiled", [True, False])
def test_the_report_s_rows_equal_the_numpy_they_replaced(compiled: bool) -> None:
    fn = fk.report_rows if compiled else fk.report_rows.py
    rng = np.random.default_rng(12)
    for trial in range(300):
        r = report_case(rng, trial)
        got = fn(
            r["out_ids"], r["out_update"], r["ids"], r["tsu"], r["stamps"], r["last_kind"],
            r["s"], r["state"], r["cls"], r["coast"], r["occluded"], r["log_odds"],
            r["policy"], r["doubt"], r["min"],
        )  # fmt: skip
        want = numpy_report(r)
        in_step = want[5]
        for name, g, w in zip(("kind", "fresh", "coast", "keep"), got, want, strict=False):
            np.testing.assert_array_equal(g, w, err_msg=f"trial {trial}: {name}")
        np.testing.assert_array_equal(got[5], in_step, err_msg=f"trial {trial}: in step")
        # Where a track is not in the step, its row of the report is never read.
        np.testing.assert_array_equal(got[4][in_step], want[4][in_step], err_msg=f"trial {trial}")


POS_VEL = [0, 1, 2, 7, 8, 9]


def numpy_gather(g: dict[str, Any]) -> tuple[Any, ...]:
    """``VehicleTracker._report``'s gather as it was: whole-table arrays, then its rows."""
    n, keep, in_step, where = g["n"], g["keep"], g["in_step"], g["where"]
    rows = np.flatnonzero(keep)
    box = np.empty((n, 7))
    cov = np.empty((n, 6, 6))
    box[in_step] = g["out_params"][where[in_step]]
    cov[in_step] = g["out_cov"][where[in_step]]
    away = np.flatnonzero(~in_step & keep)
    if away.size:
        cov[away] = g["p_away"][:, POS_VEL][:, :, POS_VEL]
        pred = g["x_away"][:, :7].copy()  # motion.predicted_boxes
        yaw = np.where(pred[:, 3] >= np.pi, pred[:, 3] - 2 * np.pi, pred[:, 3])
        pred[:, 3] = np.where(yaw < -np.pi, yaw + 2 * np.pi, yaw)
        box[away] = pred
    score = np.where(g["fresh"] | g["coast"], g["match_score"], g["score"])
    t = g["t"]
    return (
        box[rows], cov[rows], score[rows], g["x"][rows, 7:10], t - g["t_birth"][rows],
        t - g["t_update"][rows],
    )  # fmt: skip


def gather_case(rng: np.random.Generator, trial: int) -> dict[str, Any]:
    n, m = int(rng.integers(0, 40)), int(rng.integers(0, 40))
    in_step = rng.random(n) < (0.7 if m else 0.0)
    keep = rng.random(n) < [0.8, 1.0, 0.3][trial % 3]
    away = int((~in_step & keep).sum())
    x_away = rng.normal(0, 5, (away, 10))
    # Yaws on both sides of each wrap, and exactly at them.
    x_away[:, 3] = rng.choice(
        [np.pi, -np.pi, 3.5, -3.5, 7.0, -7.0, 0.5, np.nextafter(np.pi, 0)], away
    )
    return {
        "n": n, "keep": keep, "in_step": in_step, "where": rng.integers(0, max(m, 1), n),
        "out_params": rng.normal(0, 5, (m, 7)), "out_cov": rng.normal(0, 1, (m, 6, 6)),
        "x_away": x_away, "p_away": rng.normal(0, 1, (away, 10, 10)),
        "fresh": rng.random(n) < 0.5, "coast": rng.random(n) < 0.2,
        "match_score": rng.random(n), "score": rng.random(n), "x": rng.normal(0, 5, (n, 10)),
        "t": float(rng.uniform(1e9, 2e9)), "t_birth": rng.uniform(1e9, 2e9, n),
        "t_update": rng.uniform(1e9, 2e9, n),
    }  # fmt: skip


@pytest.mark.parametrize("compiled", [True, False])
def test_the_report_s_gather_equals_the_numpy_it_replaced(compiled: bool) -> None:
    fn = fk.report_gather if compiled else fk.report_gather.py
    rng = np.random.default_rng(13)
    names = ("box", "covariance", "score", "velocity", "age_s", "time_since_update_s")
    for trial in range(300):
        g = gather_case(rng, trial)
        rows = np.flatnonzero(g["keep"])
        for kalman in (True, False):
            got = fn(
                rows, g["in_step"], g["where"], g["out_params"], g["out_cov"],
                g["x_away"], g["p_away"], kalman, g["fresh"], g["coast"], g["match_score"],
                g["score"], g["x"], g["t"], g["t_birth"], g["t_update"],
            )  # fmt: skip
            for name, a, b in zip(names, got, numpy_gather(g), strict=True):
                if name == "covariance" and not kalman:
                    assert a.shape == (0, 6, 6)  # motion=cv keeps none
                    continue
                assert a.dtype == b.dtype and a.flags.c_contiguous, name
                np.testing.assert_array_equal(a, b, err_msg=f"trial {trial}: {name}")


def numpy_counter_in(misses: Any, s: int) -> Any:
    """``vehicle._counter_in`` as it was."""
    if misses.shape[0] == 0:
        return np.zeros(0, dtype=np.int32)
    own = np.maximum(misses[:, s], 0)
    others = np.delete(misses, s, axis=1)
    defined = np.where(others >= 0, others, np.iinfo(np.int32).max)
    least_other = defined.min(axis=1, initial=np.iinfo(np.int32).max)
    return np.asarray(np.minimum(own, least_other - 1), dtype=np.int32)


@pytest.mark.parametrize("compiled", [True, False])
def test_the_step_s_starting_counters_equal_the_numpy_they_replaced(compiled: bool) -> None:
    fn = fk.counter_in if compiled else fk.counter_in.py
    rng = np.random.default_rng(14)
    for trial in range(300):
        n, n_s = int(rng.integers(0, 30)), int(rng.integers(1, 5))
        misses = rng.integers(-1, 6, (n, n_s)).astype(np.int32)  # -1: not in view since
        s = int(rng.integers(0, n_s))
        got = fn(misses, s)
        assert got.dtype == np.int32
        np.testing.assert_array_equal(got, numpy_counter_in(misses, s), err_msg=f"trial {trial}")
