"""Deterministic score orderings for NMS.

NumPy's default ``argsort`` is an unstable sort whose order among equal keys depends on the
NumPy version and on the CPU's SIMD dispatch. Detection scores are often rounded (ties are
common), and the order of tied boxes decides which box NMS keeps and which ID a track gets,
so the tracker never leaves it to the machine:
- ``STABLE``: descending score, ties in input order (the default).
- ``REFERENCE``: the order the reference implementation saw, i.e. ``np.argsort(s)[::-1]`` with
  NumPy's classic introsort (before SIMD sorting), reproduced exactly here.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import F64

I64 = npt.NDArray[np.int64]
_SMALL = 16  # NumPy's SMALL_QUICKSORT


def descending_stable(scores: F64) -> I64:
    return np.argsort(-scores, kind="stable").astype(np.int64)


def descending_reference(scores: F64) -> I64:
    return classic_argsort(scores)[::-1].copy()


def classic_argsort(values: F64) -> I64:
    """NumPy's classic ``aquicksort`` (median-of-3 introsort, insertion sort below 17)."""
    v = values.tolist()
    n = len(v)
    idx = list(range(n))
    stack: list[tuple[int, int, int]] = []
    lo, hi, depth = 0, n - 1, 2 * (max(n, 1).bit_length() - 1)
    while True:
        if depth < 0:  # heapsort fallback in NumPy; any correct sort of the slice will do
            idx[lo : hi + 1] = sorted(idx[lo : hi + 1], key=v.__getitem__)
        else:
            while hi - lo > _SMALL:
                mid = lo + ((hi - lo) >> 1)
                if v[idx[mid]] < v[idx[lo]]:
                    idx[mid], idx[lo] = idx[lo], idx[mid]
                if v[idx[hi]] < v[idx[mid]]:
                    idx[hi], idx[mid] = idx[mid], idx[hi]
                if v[idx[mid]] < v[idx[lo]]:
                    idx[mid], idx[lo] = idx[lo], idx[mid]
                pivot = v[idx[mid]]
                i, j = lo, hi - 1
                idx[mid], idx[j] = idx[j], idx[mid]
                while True:
                    i += 1
                    while v[idx[i]] < pivot:
                        i += 1
                    j -= 1
                    while pivot < v[idx[j]]:
                        j -= 1
                    if i >= j:
                        break
                    idx[i], idx[j] = idx[j], idx[i]
                idx[i], idx[hi - 1] = idx[hi - 1], idx[i]
                depth -= 1
                if i - lo < hi - i:
                    stack.append((i + 1, hi, depth))
                    hi = i - 1
                else:
                    stack.append((lo, i - 1, depth))
                    lo = i + 1
            for i in range(lo + 1, hi + 1):
                item = idx[i]
                key = v[item]
                j = i
                while j > lo and key < v[idx[j - 1]]:
                    idx[j] = idx[j - 1]
                    j -= 1
                idx[j] = item
        if not stack:
            break
        lo, hi, depth = stack.pop()
    return np.array(idx, dtype=np.int64)
