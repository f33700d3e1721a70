"""A small CDR (XCDR1, "plain CDR") reader and writer: what ROS 2 puts on the wire.

A serialized message is a 4-byte encapsulation header, then the fields in order:
    00 01 00 00   CDR_LE (``00 00 00 00`` is CDR_BE, read too); the last two bytes are options
    primitives    little-endian, each aligned to its own size (1, 2, 4 or 8) counted from the
                  first byte after the header: float64 and int64 align to 8, as Fast CDR and
                  Cyclone DDS do for XCDR1
    string        uint32 length including the terminating NUL, the bytes, the NUL
    T[] / T[<=N]  uint32 element count, then the elements
    T[N]          the N elements, no count
The writer always writes CDR_LE. The reader refuses, as ``CdrError``, a payload that ends
early, a string without its NUL or not UTF-8, a bool other than 0/1, a count larger than the
bytes left could hold, and more than 3 trailing bytes (XCDR1 allows padding to 4).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from typing import TypeVar

T = TypeVar("T")

CDR_BE = b"\x00\x00"
CDR_LE = b"\x00\x01"
HEADER_SIZE = 4
MAX_TRAILING_PADDING = 3


class CdrError(ValueError):
    """A payload that is not a valid CDR serialization of the expected type."""


def _formats(order: str) -> dict[str, struct.Struct]:
    return {code: struct.Struct(order + code) for code in "BbHhIiQqfd"}


_LE = _formats("<")
_BE = _formats(">")


class CdrReader:
    """Reads one message from ``data`` (the encapsulation header included)."""

    def __init__(self, data: bytes | memoryview) -> None:
        self._buf = bytes(data)
        if len(self._buf) < HEADER_SIZE:
            raise CdrError(f"payload of {len(self._buf)} bytes is shorter than the CDR header")
        kind = bytes(self._buf[0:2])
        if kind == CDR_LE:
            self._fmt = _LE
        elif kind == CDR_BE:
            self._fmt = _BE
        else:
            raise CdrError(f"encapsulation {kind.hex()} is not plain CDR (0000 or 0001)")
        self._pos = HEADER_SIZE

    @property
    def remaining(self) -> int:
        return len(self._buf) - self._pos

    def _align(self, size: int) -> None:
        self._pos += -(self._pos - HEADER_SIZE) % size

    def _unpack(self, code: str) -> int | float:
        s = self._fmt[code]
        self._align(s.size)
        end = self._pos + s.size
        if end > len(self._buf):
            raise CdrError(f"payload ends at byte {len(self._buf)}, a value needs byte {end}")
        (value,) = s.unpack_from(self._buf, self._pos)
        self._pos = end
        return value  # type: ignore[no-any-return]

    def uint8(self) -> int:
        return int(self._unpack("B"))

    def boolean(self) -> bool:
        v = self.uint8()
        if v > 1:
            raise CdrError(f"bool byte {v} at {self._pos - 1} is neither 0 nor 1")
        return v == 1

    def int32(self) -> int:
        return int(self._unpack("i"))

    def uint32(self) -> int:
        return int(self._unpack("I"))

    def float32(self) -> float:
        return float(self._unpack("f"))

    def float64(self) -> float:
        return float(self._unpack("d"))

    def float64s(self, n: int) -> tuple[float, ...]:
        """A fixed array of ``n`` float64 (e.g. a 6x6 covariance, row-major)."""
        self._align(8)
        end = self._pos + 8 * n
        if end > len(self._buf):
            raise CdrError(f"payload ends at byte {len(self._buf)}, {n} doubles need byte {end}")
        order = "<" if self._fmt is _LE else ">"
        values = struct.unpack_from(f"{order}{n}d", self._buf, self._pos)
        self._pos = end
        return tuple(float(v) for v in values)

    def octets(self, n: int) -> bytes:
        end = self._pos + n
        if end > len(self._buf):
            raise CdrError(f"payload ends at byte {len(self._buf)}, {n} octets need byte {end}")
        out = bytes(self._buf[self._pos : end])
        self._pos = end
        return out

    def string(self) -> str:
        n = self.uint32()
        if n == 0:
            raise CdrError(f"string at byte {self._pos - 4} has length 0 (no NUL terminator)")
        raw = self.octets(n)
        if raw[-1] != 0:
            raise CdrError(f"string ending at byte {self._pos} lacks its NUL terminator")
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError as e:
            raise CdrError(f"string ending at byte {self._pos} is not UTF-8: {e.reason}") from None

    def count(self, min_element_bytes: int) -> int:
        """A sequence length, checked against the bytes left: a hostile count cannot make
        the reader allocate more than the payload could hold."""
        n = self.uint32()
        if n * min_element_bytes > self.remaining:
            raise CdrError(
                f"sequence of {n} elements at byte {self._pos - 4} cannot fit in the "
                f"{self.remaining} bytes left"
            )
        return n

    def finish(self) -> None:
        if self.remaining > MAX_TRAILING_PADDING:
            raise CdrError(f"{self.remaining} bytes left after the message (at most 3 of padding)")


class CdrWriter:
    """Builds one CDR_LE message; ``bytes()`` returns it, header included."""

    def __init__(self) -> None:
        self._buf = bytearray(CDR_LE + b"\x00\x00")

    def _align(self, size: int) -> None:
        self._buf.extend(b"\x00" * (-(len(self._buf) - HEADER_SIZE) % size))

    def _pack(self, code: str, value: int | float) -> None:
        s = _LE[code]
        self._align(s.size)
        self._buf.extend(s.pack(value))

    def uint8(self, v: int) -> None:
        self._pack("B", v)

    def boolean(self, v: bool) -> None:
        self._pack("B", 1 if v else 0)

    def int32(self, v: int) -> None:
        self._pack("i", v)

    def uint32(self, v: int) -> None:
        self._pack("I", v)

    def float32(self, v: float) -> None:
        self._pack("f", v)

    def float64(self, v: float) -> None:
        self._pack("d", v)

    def float64s(self, values: tuple[float, ...] | list[float], n: int) -> None:
        if len(values) != n:
            raise ValueError(f"fixed array of {n} doubles given {len(values)} values")
        self._align(8)
        self._buf.extend(struct.pack(f"<{n}d", *values))

    def octets(self, raw: bytes) -> None:
        self._buf.extend(raw)

    def string(self, v: str) -> None:
        raw = v.encode("utf-8")
        if b"\x00" in raw:
            raise ValueError(f"string {v!r} holds a NUL, which CDR cannot carry")
        self.uint32(len(raw) + 1)
        self._buf.extend(raw + b"\x00")

    def sequence(self, items: Sequence[T], write: Callable[[T], None]) -> None:
        self.uint32(len(items))
        for item in items:
            write(item)

    def __bytes__(self) -> bytes:
        return bytes(self._buf)
