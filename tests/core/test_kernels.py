"""The compiled overlap kernels (core/overlap_kernels.py, via core/jit.py) against their own
uncompiled Python functions, and the fallbacks: SIMPLETRACK_JIT=0 and a missing numba."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from simpletrack.core import jit
from simpletrack.core import overlap_kernels as k
from simpletrack.core.config import Metric, VerticalOverlap
from simpletrack.core.geometry import distance_pairs, giou_3d, iou_3d_pairs

F64 = npt.NDArray[np.float64]
ROOT = Path(__file__).resolve().parents[2]
FLAGS = [(t, g, e) for t in (False, True) for g in (False, True) for e in (False, True)]


def edge_case_pairs(seed: int) -> tuple[F64, F64]:
    """Row-aligned boxes a, b: random, identical, turned 90 degrees, nested, touching along and
    across the heading and at a corner, degenerate thin or flat, far apart, far from the origin."""
    rng = np.random.default_rng(seed)
    n = 10

    def random(m: int) -> F64:
        p = np.empty((m, 7))
        p[:, 0:2] = rng.uniform(-4, 4, (m, 2))
        p[:, 2] = rng.uniform(-1, 1, m)
        p[:, 3] = rng.uniform(-np.pi, np.pi, m)
        p[:, 4:7] = rng.uniform(0.3, 5.0, (m, 3))
        return p

    a = random(10 * n)
    b = random(10 * n)
    s = slice(n, 2 * n)
    b[s] = a[s]  # identical
    s = slice(2 * n, 3 * n)
    b[s] = a[s]
    b[s, 3] += np.pi / 2  # the same footprint, turned a quarter
    b[s, 4], b[s, 5] = a[s, 5], a[s, 4]
    s = slice(3 * n, 4 * n)
    b[s] = a[s]
    b[s, 4:7] = a[s, 4:7] * 0.3  # nested, same centre
    b[s, 3] += rng.uniform(-0.2, 0.2, n)
    c, si = np.cos(a[:, 3]), np.sin(a[:, 3])
    for block, (along, across) in enumerate(((1, 0), (0, 1), (1, 1)), start=4):
        s = slice(block * n, (block + 1) * n)
        b[s, 3] = a[s, 3]  # touching: edge to edge (or corner to corner), same yaw
        du = along * (a[s, 4] + b[s, 4]) / 2
        dv = across * (a[s, 5] + b[s, 5]) / 2
        b[s, 0] = a[s, 0] + c[s] * du - si[s] * dv
        b[s, 1] = a[s, 1] + si[s] * du + c[s] * dv
    s = slice(7 * n, 8 * n)
    b[s, 5] = np.where(np.arange(n) % 2 == 0, 1e-9, 0.0)  # thin, and zero width
    b[s, 0:2] = a[s, 0:2]
    s = slice(8 * n, 9 * n)
    b[s, 0] = a[s, 0] + 1e4  # far apart
    s = slice(9 * n, 10 * n)
    a[s, 0:2] += 3.0e5  # far from the origin (UTM-like), overlapping
    b[s, 0:3] = a[s, 0:3] + rng.uniform(-0.1, 0.1, (n, 3))
    return a, b


def plain(kern: jit.Kernel[..., F64], *args: object) -> F64:
    """The kernel's Python function, without numpy's warnings on intended IEEE results (as the
    fallback runs it)."""
    with np.errstate(all="ignore"):
        return kern.py(*args)


def test_kernels_run_compiled_here() -> None:
    if os.environ.get(jit.ENV_VAR, "1") == "0":
        pytest.skip("the JIT is disabled in this run")
    a, b = edge_case_pairs(0)
    k.hull_matrix(a, b)
    assert jit.compiled() and k.hull_matrix.is_compiled


@pytest.mark.parametrize(("three_d", "generalized", "exact"), FLAGS)
def test_compiled_pairs_equal_the_python_function(
    three_d: bool, generalized: bool, exact: bool
) -> None:
    for seed in range(3):
        a, b = edge_case_pairs(seed)
        idx = np.arange(a.shape[0], dtype=np.int64)
        got = k.overlap_pairs(a, b, idx, idx, three_d, generalized, exact)
        want = plain(k.overlap_pairs, a, b, idx, idx, three_d, generalized, exact)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert np.all(np.isfinite(got))


def test_compiled_matrices_equal_the_python_functions() -> None:
    a, b = edge_case_pairs(5)
    a, b = a[::3], b[::4]  # every family, kept small for the Python side
    for three_d, generalized, exact in FLAGS:
        got = k.overlap_matrix(a, b, three_d, generalized, exact)
        want = plain(k.overlap_matrix, a, b, three_d, generalized, exact)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    for kern in (k.intersection_matrix, k.hull_matrix):
        np.testing.assert_allclose(kern(a, b), plain(kern, a, b), rtol=0, atol=1e-12)


def test_edge_cases_have_their_known_values() -> None:
    a, b = edge_case_pairs(1)
    idx = np.arange(a.shape[0], dtype=np.int64)
    iou = k.overlap_pairs(a, b, idx, idx, True, False, True)
    giou = k.overlap_pairs(a, b, idx, idx, True, True, True)
    np.testing.assert_allclose(iou[10:30], 1.0, atol=1e-12)  # identical, turned a quarter
    np.testing.assert_allclose(iou[30:40], 0.3**3, rtol=1e-9)  # nested at a third size
    assert np.all(np.abs(iou[40:70]) <= 1e-9)  # touching
    assert np.all(iou[80:90] == 0.0) and np.all(giou[80:90] < -0.9)  # far apart
    # Far from the origin: the same values as the pairs moved next to it (each pair is solved
    # in a's frame).
    far, near = slice(90, 100), np.arange(90, 100, dtype=np.int64)
    a0, b0 = a.copy(), b.copy()
    a0[far, 0:2] -= 3.0e5
    b0[far, 0:2] -= 3.0e5
    assert np.all(iou[far] > 0.0)
    moved = k.overlap_pairs(a0, b0, near, near, True, True, True)
    np.testing.assert_allclose(giou[far], moved, rtol=0, atol=1e-9)


def test_the_python_helpers_stay_plain_functions() -> None:
    # Compiling a kernel binds numba dispatchers in a copy, not in the module.
    a, b = edge_case_pairs(2)
    k.overlap_matrix(a[:3], b[:3], True, True, True)
    assert type(k._overlap).__name__ == "function"
    assert k.overlap_matrix.py.__globals__["_overlap"] is k._overlap


def _run(code: str, env: dict[str, str], modules: str = "") -> dict[str, object]:
    """Run ``code`` (which sets ``out``) in a fresh interpreter; return its JSON."""
    script = textwrap.dedent(modules) + textwrap.dedent(code) + "\nprint(json.dumps(out))\n"
    full_env = {**os.environ, **env}
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=full_env, check=True
    )
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


_FALLBACK = """
import json, sys, warnings
import numpy as np
from simpletrack.core import jit
from simpletrack.core.config import Metric, VerticalOverlap
from simpletrack.core.geometry import distance_pairs, giou_3d, iou_3d_pairs
a = np.array(A)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    g = giou_3d(a, a[::-1])
    ia = np.arange(len(a)); ib = ia[::-1].copy()
    d = distance_pairs(Metric.GIOU_BEV, a, a, ia, ib, vertical=VerticalOverlap.REFERENCE)
    r, c, iou = iou_3d_pairs(a, a)
    jit.preload()
out = {
    "giou": g.tolist(), "dist": d.tolist(), "iou": iou.tolist(), "compiled": jit.compiled(),
    "numba": "numba" in sys.modules and sys.modules["numba"] is not None,
    "warnings": [str(w.message) for w in caught],
}
"""


def _boxes() -> F64:
    a, b = edge_case_pairs(7)
    return np.concatenate([a[::5], b[::5]])


def _in_process(a: F64) -> dict[str, object]:
    ia = np.arange(len(a))
    d = distance_pairs(
        Metric.GIOU_BEV, a, a, ia, ia[::-1].copy(), vertical=VerticalOverlap.REFERENCE
    )
    return {
        "giou": giou_3d(a, a[::-1]).tolist(),
        "dist": d.tolist(),
        "iou": iou_3d_pairs(a, a)[2].tolist(),
    }


def _pythonpath() -> dict[str, str]:
    return {"PYTHONPATH": os.pathsep.join(sys.path)}


def test_disabled_jit_gives_the_same_results_without_numba() -> None:
    a = _boxes()
    out = _run(_FALLBACK, {jit.ENV_VAR: "0", **_pythonpath()}, f"A = {a.tolist()!r}\n")
    assert out["compiled"] is False and out["numba"] is False
    assert out["warnings"] == []  # asked for: nothing to warn about
    want = _in_process(a)
    for key in ("giou", "dist", "iou"):
        np.testing.assert_allclose(np.array(out[key]), np.array(want[key]), rtol=0, atol=1e-12)


def test_a_missing_numba_falls_back_with_one_warning() -> None:
    a = _boxes()
    hide = "import sys\nsys.modules['numba'] = None  # import numba now raises ImportError\n"
    out = _run(_FALLBACK, {jit.ENV_VAR: "1", **_pythonpath()}, hide + f"A = {a.tolist()!r}\n")
    assert out["compiled"] is False
    warned = out["warnings"]
    assert isinstance(warned, list) and len(warned) == 1 and "numba is unavailable" in warned[0]
    want = _in_process(a)
    for key in ("giou", "dist", "iou"):
        np.testing.assert_allclose(np.array(out[key]), np.array(want[key]), rtol=0, atol=1e-12)


def test_pair_indices_are_checked_before_the_kernel_reads_them() -> None:
    a, b = edge_case_pairs(3)
    with pytest.raises(IndexError):
        distance_pairs(Metric.GIOU_3D, a, b, [0, a.shape[0]], [0, 1])
    with pytest.raises(IndexError):
        distance_pairs(Metric.IOU_BEV, a, b, [0, -a.shape[0] - 1], [0, 1])
    # Negative indices count from the end, as numpy's do.
    np.testing.assert_array_equal(
        distance_pairs(Metric.IOU_BEV, a, b, [-1, 0], [-2, 1]),
        distance_pairs(Metric.IOU_BEV, a, b, [a.shape[0] - 1, 0], [b.shape[0] - 2, 1]),
    )
