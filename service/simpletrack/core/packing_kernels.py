"""The reported tracks as the bytes of a TrackFrame's ``tracks`` map, in one compiled call.

A service frame used to go from the step's output to its message in three hops, each paying
the interpreter per column: ``track_columns`` (14 arrays boxed on the way out), the
``TrackArrays`` they fill, and ``encode_track_frame`` (a check, ``tobytes`` and a dict entry
per column, then msgpack). ``pack_columns`` computes the same columns (``track_columns``
inlined: the same IEEE casts) and writes them as msgpack writes that map: the entries in the
table's order, ``count`` as its smallest integer form, each column a ``bin`` with the smallest
header that holds it, the values little-endian. tests/wire/test_convert.py holds the
bytes equal to ``encode_track_frame``'s.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel
from simpletrack.core.output_kernels import F64, I8, I32, I64, track_columns

__all__ = ["COLUMN_ORDER", "pack_columns"]

U8 = npt.NDArray[np.uint8]

# The columns as a TrackFrame lists them (wire/columns.py TRACK_COLUMNS); ``keys`` holds their
# names packed as msgpack strings in this order and ``include`` says which a message carries.
COLUMN_ORDER = (
    "id",
    "class_index",
    "center",
    "size",
    "yaw",
    "score",
    "velocity",
    "state",
    "hits",
    "age",
    "time_since_update",
    "covariance",
    "age_s",
    "time_since_update_s",
)

# "count" as msgpack packs it (a fixstr of 5).
_COUNT_KEY = (0xA5, 0x63, 0x6F, 0x75, 0x6E, 0x74)

_SIGNATURE = (
    "Tuple((uint8[::1], int64, int64))"
    "(int64[:], int64, float64[:, :], float64[:], int32[:], float64[:, :], int8[:], int32[:],"
    " int32[:], int32[:], float64[:, :, :], boolean, float64[:], float64[:],"
    " uint8[:], uint8[:], int64[:], boolean[:])"
)


@helper
def _bytes_of(a: npt.NDArray[np.generic]) -> U8:
    """A C-contiguous array's bytes, in the machine's order (the caller checks it is little)."""
    return a.reshape(a.size).view(np.uint8)


@helper
def _put_be(out: U8, at: int, value: int, width: int) -> int:
    """``value`` big-endian in ``width`` bytes at ``at`` (msgpack's lengths and integers)."""
    for k in range(width):
        out[at + k] = (value >> (8 * (width - 1 - k))) & 0xFF
    return at + width


@helper
def _uint_size(value: int) -> int:
    """Bytes msgpack takes for a non-negative integer: fixint, uint8, 16, 32 or 64."""
    if value < 0x80:
        return 1
    if value <= 0xFF:
        return 2
    if value <= 0xFFFF:
        return 3
    if value <= 0xFFFFFFFF:
        return 5
    return 9


@helper
def _put_uint(out: U8, at: int, value: int) -> int:
    if value < 0x80:
        out[at] = value
        return at + 1
    if value <= 0xFF:
        out[at] = 0xCC
        return _put_be(out, at + 1, value, 1)
    if value <= 0xFFFF:
        out[at] = 0xCD
        return _put_be(out, at + 1, value, 2)
    if value <= 0xFFFFFFFF:
        out[at] = 0xCE
        return _put_be(out, at + 1, value, 4)
    out[at] = 0xCF
    return _put_be(out, at + 1, value, 8)


@helper
def _bin_header_size(n: int) -> int:
    if n <= 0xFF:
        return 2
    if n <= 0xFFFF:
        return 3
    return 5


@helper
def _put_bin(out: U8, at: int, data: U8) -> int:
    n = data.size
    if n <= 0xFF:
        out[at] = 0xC4
        at = _put_be(out, at + 1, n, 1)
    elif n <= 0xFFFF:
        out[at] = 0xC5
        at = _put_be(out, at + 1, n, 2)
    else:
        out[at] = 0xC6
        at = _put_be(out, at + 1, n, 4)
    out[at : at + n] = data
    return at + n


@kernel(_SIGNATURE)
def pack_columns(
    ids: I64,
    id_base: int,
    params: F64,
    score: F64,
    cls: I32,
    velocity: F64,
    state: I8,
    tsu: I32,
    hits: I32,
    age: I32,
    cov: F64,
    has_cov: bool,
    age_s: F64,
    tsu_s: F64,
    classes: U8,
    keys: U8,
    key_at: I64,
    include: npt.NDArray[np.bool_],
) -> tuple[U8, int, int]:
    """(the map's bytes, -1, -1), or (no bytes, the index in ``NON_FINITE_ORDER`` of the
    first column holding NaN or inf, its first such row): such tracks are never published,
    and the caller's guard takes them the way it always has. ``classes`` is the ``classes``
    entry packed (its key and the list), ``keys`` the column names packed in ``COLUMN_ORDER``
    (name ``c`` is ``keys[key_at[c]:key_at[c + 1]]``), ``include`` the columns the message
    carries (the covariance only with ``has_cov``)."""
    cols = track_columns(
        ids, id_base, params, score, cls, velocity, state, tsu, hits, age, cov, has_cov,
        age_s, tsu_s,
    )  # fmt: skip
    column, row = cols[14], cols[15]
    if column >= 0:
        return np.empty(0, np.uint8), column, row
    data = (
        _bytes_of(cols[0]), _bytes_of(cols[1]), _bytes_of(cols[2]), _bytes_of(cols[3]),
        _bytes_of(cols[4]), _bytes_of(cols[5]), _bytes_of(cols[6]), _bytes_of(cols[7]),
        _bytes_of(cols[8]), _bytes_of(cols[9]), _bytes_of(cols[10]), _bytes_of(cols[11]),
        _bytes_of(cols[12]), _bytes_of(cols[13]),
    )  # fmt: skip
    n = ids.shape[0]
    entries = 2
    size = 6 + _uint_size(n) + classes.size  # "count" is 6 bytes packed
    for c in range(14):
        if include[c]:
            entries += 1
            nbytes = data[c].size
            size += key_at[c + 1] - key_at[c] + _bin_header_size(nbytes) + nbytes
    size += 1 if entries <= 15 else 3
    out = np.empty(size, np.uint8)
    if entries <= 15:
        out[0] = 0x80 | entries
        at = 1
    else:
        out[0] = 0xDE
        at = _put_be(out, 1, entries, 2)
    for k in range(6):
        out[at + k] = _COUNT_KEY[k]
    at = _put_uint(out, at + 6, n)
    out[at : at + classes.size] = classes
    at += classes.size
    for c in range(14):
        if include[c]:
            k0, k1 = key_at[c], key_at[c + 1]
            out[at : at + k1 - k0] = keys[k0:k1]
            at = _put_bin(out, at + k1 - k0, data[c])
    return out, -1, -1
