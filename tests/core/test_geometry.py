"""Box geometry against an independent brute-force oracle (shapely), plus overlap properties."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from simpletrack.core.config import Metric, VerticalOverlap
from simpletrack.core.geometry import (
    bev_corners,
    bev_hull_area,
    bev_intersection_area,
    distance_matrix,
    distance_pairs,
    giou_3d,
    giou_bev,
    iou_3d,
    iou_3d_pairs,
    iou_bev,
    l2_distance,
    mahalanobis,
)

F64 = npt.NDArray[np.float64]
EXACT, REFERENCE = VerticalOverlap.EXACT, VerticalOverlap.REFERENCE
RTOL = 1e-9


# ---------------------------------------------------------------- oracle
def _polygon_corners(p: F64) -> F64:
    """Corners by an explicit rotation matrix per box (independent of the code under test)."""
    out = np.empty((len(p), 4, 2))
    for k, (x, y, _z, yaw, length, width, _h) in enumerate(p):
        rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [length / 2, width / 2]
        out[k] = local @ rot.T + [x, y]
    return out


def oracle(a: F64, b: F64, *, aligned: bool = False) -> dict[str, F64]:
    """Row-aligned pairs: shapely areas and the spec's formulas with the exact vertical overlap.
    ``aligned`` (pairs with equal yaws) takes the intersection from aligned_intersection."""
    ca, cb = _polygon_corners(a), _polygon_corners(b)
    if aligned:
        inter = aligned_intersection(a, b)
    else:
        inter = shapely.area(shapely.intersection(shapely.polygons(ca), shapely.polygons(cb)))
    hull = shapely.area(shapely.convex_hull(shapely.multipoints(np.concatenate([ca, cb], 1))))
    top_a, bot_a = a[:, 2] + a[:, 6] / 2, a[:, 2] - a[:, 6] / 2
    top_b, bot_b = b[:, 2] + b[:, 6] / 2, b[:, 2] - b[:, 6] / 2
    z_overlap = np.maximum(0, np.minimum(top_a, top_b) - np.maximum(bot_a, bot_b))
    z_union = np.maximum(top_a, top_b) - np.minimum(bot_a, bot_b)
    area_a, area_b = a[:, 4] * a[:, 5], b[:, 4] * b[:, 5]
    union_bev = area_a + area_b - inter
    i3 = inter * z_overlap
    u3 = area_a * a[:, 6] + area_b * b[:, 6] - i3
    c3 = hull * z_union
    return {
        "inter": inter,
        "hull": hull,
        "scale": np.maximum(area_a, area_b),
        "iou_bev": inter / union_bev,
        "giou_bev": inter / union_bev - (hull - union_bev) / hull,
        "iou_3d": i3 / u3,
        "giou_3d": i3 / u3 - (c3 - u3) / c3,
    }


def aligned_intersection(a: F64, b: F64) -> F64:
    """Exact BEV intersection of row-aligned pairs with equal yaws: the product of the 1D overlaps.

    Needed because shapely (GEOS 3.14) returns a MULTIPOINT instead of the overlap polygon for
    some boxes whose long edges are exactly collinear."""
    c, s = np.cos(a[:, 3]), np.sin(a[:, 3])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    along, across = c * dx + s * dy, c * dy - s * dx

    def overlap(d: F64, ha: F64, hb: F64) -> F64:
        return np.maximum(0.0, np.minimum(ha, d + hb) - np.maximum(-ha, d - hb))

    return overlap(along, a[:, 4] / 2, b[:, 4] / 2) * overlap(across, a[:, 5] / 2, b[:, 5] / 2)


def ours(a: F64, b: F64, vertical: VerticalOverlap = EXACT) -> dict[str, F64]:
    """The code under test on row-aligned pairs: diagonals of its matrices over small blocks."""

    def diag(f: Callable[..., F64], **kw: VerticalOverlap) -> F64:
        blocks = [np.diagonal(f(a[k : k + 50], b[k : k + 50], **kw)) for k in range(0, len(a), 50)]
        return np.concatenate(blocks)

    return {
        "inter": diag(bev_intersection_area),
        "hull": diag(bev_hull_area),
        "iou_bev": diag(iou_bev),
        "giou_bev": diag(giou_bev),
        "iou_3d": diag(iou_3d, vertical=vertical),
        "giou_3d": diag(giou_3d, vertical=vertical),
    }


def assert_matches_oracle(a: F64, b: F64, want: dict[str, F64] | None = None) -> None:
    want, got = want or oracle(a, b), ours(a, b)
    scale = want["scale"]
    np.testing.assert_array_less(np.abs(got["inter"] - want["inter"]), RTOL * scale)
    np.testing.assert_array_less(np.abs(got["hull"] - want["hull"]), RTOL * want["hull"])
    for key in ("iou_bev", "giou_bev", "iou_3d", "giou_3d"):
        np.testing.assert_allclose(got[key], want[key], rtol=0, atol=RTOL, err_msg=key)


# ---------------------------------------------------------------- box families
def random_boxes(rng: np.random.Generator, n: int, spread: float = 4.0) -> F64:
    p = np.empty((n, 7))
    p[:, 0:2] = rng.uniform(-spread, spread, (n, 2))
    p[:, 2] = rng.uniform(-1.0, 1.0, n)
    p[:, 3] = rng.uniform(-2 * np.pi, 2 * np.pi, n)
    p[:, 4:7] = rng.uniform(0.2, 6.0, (n, 3))
    return p


def turned(a: F64, dyaw: F64) -> F64:
    b = a.copy()
    b[:, 3] += dyaw
    return b


def shifted_along_heading(a: F64, along: F64, across: F64, b: F64) -> F64:
    """b re-centred at a's centre + along * heading + across * left normal (b keeps a's yaw)."""
    out = b.copy()
    c, s = np.cos(a[:, 3]), np.sin(a[:, 3])
    out[:, 0] = a[:, 0] + along * c - across * s
    out[:, 1] = a[:, 1] + along * s + across * c
    out[:, 3] = a[:, 3]
    return out


N = 600


def test_random_pairs_match_the_oracle() -> None:
    rng = np.random.default_rng(1)
    a, b = random_boxes(rng, 5 * N), random_boxes(rng, 5 * N)
    assert (oracle(a, b)["inter"] > 0).mean() > 0.3  # the family really exercises overlaps
    assert_matches_oracle(a, b)


def test_identical_and_same_footprint_boxes_have_iou_one() -> None:
    rng = np.random.default_rng(2)
    a = random_boxes(rng, N, spread=3000.0)  # world-frame coordinates far from the origin
    b = a.copy()
    for x in (iou_bev(a, b), iou_3d(a, b), giou_bev(a, b), giou_3d(a, b)):
        np.testing.assert_allclose(np.diagonal(x), 1.0, rtol=0, atol=1e-9)
    # Turned by pi, or by pi/2 with length and width swapped: the same footprint.
    half_turn = turned(a, np.full(N, np.pi))
    quarter = turned(a, np.full(N, np.pi / 2))
    quarter[:, [4, 5]] = a[:, [5, 4]]
    for b in (half_turn, quarter):
        np.testing.assert_allclose(np.diagonal(iou_3d(a, b)), 1.0, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.diagonal(giou_3d(a, b)), 1.0, rtol=0, atol=1e-9)
        assert_matches_oracle(a, b)


def test_rotated_copies_match_the_oracle() -> None:
    rng = np.random.default_rng(3)
    a = random_boxes(rng, N)
    steps = rng.choice([np.pi / 2, np.pi, -np.pi / 2, 1e-12, -1e-9, np.pi / 4], N)
    assert_matches_oracle(a, turned(a, steps + rng.normal(0, 1e-3, N) * (rng.random(N) < 0.5)))


def test_touching_boxes_have_zero_overlap_and_exact_hull() -> None:
    rng = np.random.default_rng(4)
    a, b = random_boxes(rng, N), random_boxes(rng, N)
    # Edge to edge along the heading, and side by side across it, same yaw.
    along = shifted_along_heading(a, (a[:, 4] + b[:, 4]) / 2, rng.uniform(-1, 1, N), b)
    across = shifted_along_heading(a, rng.uniform(-1, 1, N), (a[:, 5] + b[:, 5]) / 2, b)
    corner = shifted_along_heading(a, (a[:, 4] + b[:, 4]) / 2, (a[:, 5] + b[:, 5]) / 2, b)
    for touching in (along, across, corner):
        got = ours(a, touching)
        assert np.all(got["inter"] <= RTOL * np.maximum(a[:, 4] * a[:, 5], b[:, 4] * b[:, 5]))
        assert_matches_oracle(a, touching, oracle(a, touching, aligned=True))


def test_parallel_partly_overlapping_boxes_match_the_oracle() -> None:
    rng = np.random.default_rng(5)
    a, b = random_boxes(rng, N), random_boxes(rng, N)
    # Same yaw, offsets along one axis only: pairs of collinear edges.
    along = shifted_along_heading(a, rng.uniform(-4, 4, N), np.zeros(N), b)
    across = shifted_along_heading(a, np.zeros(N), rng.uniform(-3, 3, N), b)
    same_width = along.copy()
    same_width[:, 5] = a[:, 5]  # both long edges coincide
    for b2 in (along, across, same_width):
        want = oracle(a, b2, aligned=True)
        assert (want["inter"] > 0).mean() > 0.5
        assert_matches_oracle(a, b2, want)


def test_nested_boxes_match_the_oracle() -> None:
    rng = np.random.default_rng(6)
    a = random_boxes(rng, N)
    inradius = np.minimum(a[:, 4], a[:, 5]) / 2
    b = random_boxes(rng, N)
    # b's circumscribed circle (radius r) fits inside a's inscribed one, off-centre by <= slack.
    r = inradius * rng.uniform(0.1, 0.9, N)
    ratio = rng.uniform(0.2, 5.0, N)
    b[:, 4] = 2 * r * np.cos(np.arctan(1 / ratio))
    b[:, 5] = 2 * r * np.sin(np.arctan(1 / ratio))
    slack = (inradius - r) * rng.uniform(0, 1, N)
    angle = rng.uniform(0, 2 * np.pi, N)
    b[:, 0] = a[:, 0] + slack * np.cos(angle)
    b[:, 1] = a[:, 1] + slack * np.sin(angle)
    got = ours(a, b)
    np.testing.assert_allclose(got["inter"], b[:, 4] * b[:, 5], rtol=RTOL)
    np.testing.assert_allclose(got["hull"], a[:, 4] * a[:, 5], rtol=RTOL)
    assert_matches_oracle(a, b)
    assert_matches_oracle(b, a)


def test_far_apart_boxes_have_zero_iou_and_exact_giou() -> None:
    rng = np.random.default_rng(7)
    a = random_boxes(rng, N)
    b = random_boxes(rng, N)
    direction = rng.uniform(0, 2 * np.pi, N)
    distance = rng.uniform(20.0, 2000.0, N)
    b[:, 0] = a[:, 0] + distance * np.cos(direction)
    b[:, 1] = a[:, 1] + distance * np.sin(direction)
    got = ours(a, b)
    assert np.all(got["iou_3d"] == 0.0)
    assert np.all(got["giou_3d"] < -0.5)
    assert_matches_oracle(a, b)


def test_full_matrix_entries_match_the_oracle() -> None:
    rng = np.random.default_rng(8)
    a, b = random_boxes(rng, 45, spread=6.0), random_boxes(rng, 37, spread=6.0)
    ia, ib = np.meshgrid(np.arange(45), np.arange(37), indexing="ij")
    want = oracle(a[ia.ravel()], b[ib.ravel()])
    for f, key in ((iou_3d, "iou_3d"), (giou_3d, "giou_3d"), (giou_bev, "giou_bev")):
        got = f(a, b)
        assert got.shape == (45, 37) and got.dtype == np.float64
        np.testing.assert_allclose(got.ravel(), want[key], rtol=0, atol=RTOL, err_msg=key)


def test_large_matrices_computed_in_blocks_equal_row_by_row_results() -> None:
    rng = np.random.default_rng(15)
    a, b = random_boxes(rng, 300, spread=30.0), random_boxes(rng, 200, spread=30.0)
    for f in (giou_3d, iou_3d, bev_intersection_area):
        whole = f(a, b)
        rows = np.concatenate([f(a[i : i + 1], b) for i in range(0, 300, 7)])
        np.testing.assert_allclose(whole[::7], rows, rtol=1e-12, atol=1e-12)


def test_a_vertically_contained_box_shows_where_the_reference_formula_is_wrong() -> None:
    rng = np.random.default_rng(9)
    a = random_boxes(rng, N)
    b = a.copy()  # same footprint, b's height range inside a's
    b[:, 6] = a[:, 6] * rng.uniform(0.1, 0.9, N)
    # Off-centre, but at least a quarter of the free height away from either end of a.
    b[:, 2] = a[:, 2] + (a[:, 6] - b[:, 6]) / 2 * rng.uniform(-0.5, 0.5, N)
    want = oracle(a, b, aligned=True)
    np.testing.assert_allclose(want["iou_3d"], b[:, 6] / a[:, 6], rtol=1e-9)
    exact, reference = ours(a, b, EXACT), ours(a, b, REFERENCE)
    np.testing.assert_allclose(exact["iou_3d"], want["iou_3d"], rtol=0, atol=RTOL)
    np.testing.assert_allclose(exact["giou_3d"], want["giou_3d"], rtol=0, atol=RTOL)
    # The reference's overlap min(top_a - bot_b, top_b - bot_a) exceeds b's own height by the
    # smaller gap between the ends of a and b (here >= 2.5% of a's height).
    assert np.all(reference["iou_3d"] > exact["iou_3d"] + 0.02)
    assert np.all(reference["giou_3d"] > exact["giou_3d"] + 0.02)


def test_reference_mode_reproduces_the_reference_formulas() -> None:
    # Unit footprints (area 1): a spans z in [0, 4], b spans [1, 2] -> contained.
    a = np.array([[0.0, 0.0, 2.0, 0.3, 1.0, 1.0, 4.0]])
    b = np.array([[0.0, 0.0, 1.5, 0.3, 1.0, 1.0, 1.0]])
    # Reference: overlap = min(4 - 1, 2 - 0) = 2, union = max(3, 2) = 3; I = 2, U = 4 + 1 - 2.
    assert iou_3d(a, b, vertical=REFERENCE)[0, 0] == pytest.approx(2 / (3 + 1e-5), abs=1e-12)
    assert giou_3d(a, b, vertical=REFERENCE)[0, 0] == pytest.approx(2 / 3 - (3 - 3) / 3, abs=1e-12)
    assert iou_3d(a, b)[0, 0] == pytest.approx(1 / 4, abs=1e-12)
    assert giou_3d(a, b)[0, 0] == pytest.approx(1 / 4 - (4 - 4) / 4, abs=1e-12)
    # BEV measures have no vertical part: both modes agree.
    assert iou_bev(a, b, vertical=REFERENCE)[0, 0] == iou_bev(a, b)[0, 0] == pytest.approx(1.0)


def test_sparse_iou_pairs_agree_with_the_dense_matrix() -> None:
    rng = np.random.default_rng(10)
    a = random_boxes(rng, 80, spread=10.0)
    groups = rng.integers(0, 3, 80)
    for vertical in VerticalOverlap:
        dense = iou_3d(a, a, vertical=vertical)
        rows, cols, iou = iou_3d_pairs(a, a, vertical=vertical, groups_a=groups, groups_b=groups)
        assert np.all(groups[rows] == groups[cols]) and np.all(np.diff(rows) >= 0)
        np.testing.assert_array_equal(iou, dense[rows, cols])
        rest = np.ones_like(dense, dtype=bool)
        rest[rows, cols] = False
        same_group = groups[:, None] == groups[None, :]
        assert np.all(dense[rest & same_group] == 0.0)


def test_empty_inputs_give_empty_matrices() -> None:
    rng = np.random.default_rng(11)
    some = random_boxes(rng, 3)
    none = np.zeros((0, 7))
    for f in (
        bev_intersection_area,
        bev_hull_area,
        iou_bev,
        giou_bev,
        iou_3d,
        giou_3d,
        l2_distance,
    ):
        assert f(none, some).shape == (0, 3)
        assert f(some, none).shape == (3, 0)
        assert f(none, none).shape == (0, 0)
    assert bev_corners(none).shape == (0, 4, 2)
    assert mahalanobis(some, none, np.zeros((0, 7, 7))).shape == (3, 0)


def test_zero_size_boxes_give_finite_results_without_warnings() -> None:
    rng = np.random.default_rng(12)
    a = random_boxes(rng, 5)
    flat = a.copy()
    flat[:, 5] = 0.0  # zero width
    with np.errstate(all="raise"):
        for f in (iou_bev, giou_bev, iou_3d, giou_3d):
            assert np.all(np.isfinite(f(flat, flat)))
            assert np.all(np.isfinite(f(a, flat)))


def test_bad_shapes_are_rejected_with_the_shape_in_the_message() -> None:
    with pytest.raises(ValueError, match=r"\(5,\)"):
        iou_3d(np.zeros(5), np.zeros((1, 7)))


# ---------------------------------------------------------------- distances
def test_l2_distance_is_the_centre_distance() -> None:
    a = np.array([[0.0, 0.0, 0.0, 0.0, 1, 1, 1]])
    b = np.array([[3.0, 4.0, 12.0, 2.0, 5, 5, 5], [0.0, 0.0, 0.0, 1.0, 2, 2, 2]])
    np.testing.assert_allclose(l2_distance(a, b), [[13.0, 0.0]])


def test_mahalanobis_matches_a_per_pair_solve_with_folded_yaw() -> None:
    rng = np.random.default_rng(13)
    a, b = random_boxes(rng, 6), random_boxes(rng, 4)
    m = rng.normal(size=(4, 7, 7))
    s = m @ m.transpose(0, 2, 1) + 7 * np.eye(7)
    got = mahalanobis(a, b, s)
    for i in range(6):
        for j in range(4):
            d = a[i] - b[j]
            d[3] = (d[3] + np.pi / 2) % np.pi - np.pi / 2  # any fold of yaw into a pi range
            if d[3] == -np.pi / 2:
                d[3] = np.pi / 2
            want = np.sqrt(d @ np.linalg.solve(s[j], d))
            assert got[i, j] == pytest.approx(want, rel=1e-9)
    # A box turned by pi is at distance 0 from itself.
    assert mahalanobis(a[:1], turned(a[:1], np.array([np.pi])), np.eye(7)[None])[0, 0] < 1e-9


def test_distance_matrix_dispatches_every_metric() -> None:
    rng = np.random.default_rng(14)
    a, b = random_boxes(rng, 7), random_boxes(rng, 5)
    s = np.broadcast_to(np.eye(7), (5, 7, 7))
    expected = {
        Metric.GIOU_3D: 1 - giou_3d(a, b),
        Metric.IOU_3D: 1 - iou_3d(a, b),
        Metric.GIOU_BEV: 1 - giou_bev(a, b),
        Metric.IOU_BEV: 1 - iou_bev(a, b),
        Metric.L2: l2_distance(a, b),
        Metric.MAHALANOBIS: mahalanobis(a, b, s),
    }
    for metric, want in expected.items():
        np.testing.assert_array_equal(distance_matrix(metric, a, b, innovation=s), want)
    ref = distance_matrix(Metric.GIOU_3D, a, b, vertical=REFERENCE)
    np.testing.assert_array_equal(ref, 1 - giou_3d(a, b, vertical=REFERENCE))
    with pytest.raises(ValueError, match="innovation"):
        distance_matrix(Metric.MAHALANOBIS, a, b)


def test_distance_pairs_equal_the_matrix_entries_bit_for_bit() -> None:
    # The tracker scores only same-class pairs, all classes in one call: same values.
    rng = np.random.default_rng(21)
    a, b = random_boxes(rng, 40, spread=6.0), random_boxes(rng, 30, spread=6.0)
    s = np.broadcast_to(np.eye(7) * 1.5, (30, 7, 7))
    ia, ib = np.nonzero(rng.random((40, 30)) < 0.4)
    for metric in Metric:
        for vertical in VerticalOverlap:
            dense = distance_matrix(metric, a, b, vertical=vertical, innovation=s)
            pairs = distance_pairs(metric, a, b, ia, ib, vertical=vertical, innovation=s)
            np.testing.assert_array_equal(pairs, dense[ia, ib])
    assert distance_pairs(Metric.GIOU_3D, a, b, [], []).shape == (0,)
    with pytest.raises(ValueError, match="det indices"):
        distance_pairs(Metric.GIOU_3D, a, b, [0, 1], [0])


# ---------------------------------------------------------------- properties
coord = st.floats(-15, 15, allow_nan=False)
size = st.floats(0.05, 8, allow_nan=False)
box = st.tuples(coord, coord, st.floats(-2, 2), st.floats(-7, 7), size, size, size)
boxes = st.lists(box, min_size=1, max_size=6).map(lambda rows: np.array(rows, dtype=np.float64))


@settings(max_examples=150, deadline=None)
@given(a=boxes, b=boxes, vertical=st.sampled_from(list(VerticalOverlap)))
def test_overlap_properties(a: F64, b: F64, vertical: VerticalOverlap) -> None:
    for iou_f, giou_f in ((iou_bev, giou_bev), (iou_3d, giou_3d)):
        iou, iou_t = iou_f(a, b, vertical=vertical), iou_f(b, a, vertical=vertical)
        np.testing.assert_allclose(iou, iou_t.T, rtol=0, atol=1e-9)
        assert np.all((iou >= 0) & (iou <= 1 + 1e-12))
        if vertical is EXACT or iou_f is iou_bev:
            giou = giou_f(a, b, vertical=vertical)
            np.testing.assert_allclose(giou, giou_f(b, a, vertical=vertical).T, atol=1e-9)
            assert np.all((giou > -1) & (giou <= 1 + 1e-12))
            assert np.all(giou <= iou + 1e-12)
            np.testing.assert_allclose(np.diagonal(giou_f(a, a)), 1.0, rtol=0, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(p=arrays(np.float64, (1, 7), elements=st.floats(0.1, 5)))
def test_a_box_against_itself_is_a_perfect_match(p: F64) -> None:
    for f in (iou_bev, giou_bev, iou_3d, giou_3d):
        assert f(p, p)[0, 0] == pytest.approx(1.0, abs=1e-9)
    assert bev_intersection_area(p, p)[0, 0] == pytest.approx(p[0, 4] * p[0, 5], rel=1e-9)
    assert bev_hull_area(p, p)[0, 0] == pytest.approx(p[0, 4] * p[0, 5], rel=1e-9)
