"""The calibration monitor's compiled pair loops (core/calibration_kernels.py) give what the
vectorised numpy they replaced gave, compiled and as Python, ties and empty sides included."""

from __future__ import annotations

import numpy as np
import pytest

from simpletrack.core import calibration_kernels as ck
from simpletrack.core.calibration import BIN_M, DECAY, PAIR_GATE_M, SEARCH_M


def numpy_pairs(det, det_cls, trk, trk_cls):  # type: ignore[no-untyped-def]
    d = det[:, None, :] - trk[None, :, :]
    near = (det_cls[:, None] == trk_cls[None, :]) & (np.abs(d) < SEARCH_M).all(axis=2)
    return d[near]


def numpy_fit(det, det_cls, trk, vel, trk_cls, shift):  # type: ignore[no-untyped-def]
    """The normal equations over mutual nearest pairs, as the vectorised monitor built them."""
    if det.size == 0 or trk.size == 0:
        return np.zeros(14)
    d = det[:, None, :] - trk[None, :, :]
    r = d - np.asarray(shift)
    dist = np.where(det_cls[:, None] == trk_cls[None, :], np.hypot(r[..., 0], r[..., 1]), np.inf)
    best_t, best_d = np.argmin(dist, axis=1), np.argmin(dist, axis=0)
    rows = np.arange(dist.shape[0])
    mutual = (best_d[best_t] == rows) & (dist[rows, best_t] <= PAIR_GATE_M)
    di, ti = rows[mutual], best_t[mutual]
    res, v, k = d[di, ti], vel[ti], di.size
    a = np.zeros((2 * k, 3))
    a[:k, 0], a[k:, 1], a[:k, 2], a[k:, 2] = 1.0, 1.0, v[:, 0], v[:, 1]
    y = np.concatenate([res[:, 0], res[:, 1]])
    return np.concatenate([(a.T @ a).ravel(), a.T @ y, [y @ y, y.size]])


def cases(count: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    for trial in range(count):
        n, m = int(rng.integers(0, 30)), int(rng.integers(0, 30))
        det, trk = rng.uniform(-60, 60, (n, 2)), rng.uniform(-60, 60, (m, 2))
        k = min(n, m)
        if trial % 2:  # a sensor seeing the tracks, some metres off
            det[:k] = trk[:k] + rng.normal(0, 0.3, (k, 2)) + trial % 7
        if trial % 5 == 0:  # equal distances: the first index wins, as argmin's
            det, trk = np.round(det), np.round(trk)
        yield (
            det,
            rng.integers(0, 3, n).astype(np.int32),
            trk,
            rng.normal(0, 8, (m, 2)),
            rng.integers(0, 3, m).astype(np.int32),
        )


@pytest.mark.parametrize("compiled", [True, False])
def test_pairs_and_fit_equal_the_vectorised_monitor(compiled: bool) -> None:
    pairs = ck.voting_pairs if compiled else ck.voting_pairs.py
    fit = ck.time_fit if compiled else ck.time_fit.py
    for det, dc, trk, vel, tc in cases(400):
        assert np.array_equal(pairs(det, dc, trk, tc, SEARCH_M), numpy_pairs(det, dc, trk, tc))
        shift = (1.5, -0.5)
        got = fit(det, dc, trk, vel, tc, shift[0], shift[1], PAIR_GATE_M)
        assert np.allclose(got, numpy_fit(det, dc, trk, vel, tc, shift), rtol=1e-12, atol=1e-9)


def numpy_votes(off, before):  # type: ignore[no-untyped-def]
    """The offset votes as ``calibration.observe`` computed them in numpy."""
    bins = before.shape[0]
    centre = bins // 2

    def region(v, i, j):  # type: ignore[no-untyped-def]
        return float(v[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2].sum())

    cells = np.floor(off / BIN_M).astype(np.int64) + centre
    frame = np.zeros((bins, bins))
    np.add.at(frame, (cells[:, 0], cells[:, 1]), 1.0)
    votes = before * DECAY + frame
    pi, pj = np.unravel_index(int(np.argmax(votes)), votes.shape)
    sel = (np.abs(cells[:, 0] - pi) <= 1) & (np.abs(cells[:, 1] - pj) <= 1)
    mean = off[sel].mean(axis=0) if sel.any() else np.zeros(2)
    fi, fj = np.unravel_index(int(np.argmax(frame)), frame.shape)
    return votes, [
        pi, pj, region(votes, pi, pj),
        region(votes, centre, centre) + region(votes, centre - 1, centre - 1),
        int(sel.sum()), float(mean[0]), float(mean[1]), fi, fj,
        region(frame, centre, centre) + region(frame, centre - 1, centre - 1),
    ]  # fmt: skip


@pytest.mark.parametrize("compiled", [True, False])
def test_the_offset_votes_equal_the_numpy_they_replaced(compiled: bool) -> None:
    votes_of = ck.offset_votes if compiled else ck.offset_votes.py
    rng = np.random.default_rng(8)
    bins = int(2 * SEARCH_M / BIN_M)
    for sequence in range(60):
        before = np.zeros((bins, bins))
        shift = rng.uniform(-29, 29, 2) if sequence % 3 else np.zeros(2)
        for _ in range(12):  # frames of one sensor: the votes carried and decayed
            k = int(rng.integers(0, 80))
            off = rng.uniform(-29.999, 29.999, (k, 2))
            near = rng.random(k) < 0.6  # a pile around the sensor's offset
            off[near] = np.clip(shift + rng.normal(0, 0.6, (int(near.sum()), 2)), -29.999, 29.999)
            if sequence % 4 == 0:  # whole-metre offsets: cell edges, and ties between peaks
                off = np.clip(np.round(off), -29.0, 29.0)  # voting_pairs': under 30 m
            if sequence % 5 == 0:  # the corner cells: regions cut by the grid's edge
                off[: k // 2] = rng.choice([-29.5, 29.5], (k // 2, 2))
            votes, got = votes_of(np.ascontiguousarray(off), before, DECAY, BIN_M)
            want_votes, want = numpy_votes(off, before)
            assert np.array_equal(votes, want_votes)
            assert got.tolist() == [float(w) for w in want], (sequence, got, want)
            before = votes
