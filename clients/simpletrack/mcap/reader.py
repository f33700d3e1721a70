"""Reading an MCAP file's messages in log-time order, for ``simpletrack replay mcap``.

A reader of its own so the light install replays recordings without the ``mcap`` package,
whose hard dependency on ``zstandard`` (24 MB) alone would take the light install past its
size budget. It reads what ``replay`` needs: the header's profile and every channel's
messages, from chunks stored plain, zstd-compressed (what ``simpletrack record`` writes;
Python 3.14's ``compression.zstd``, backported: 1.9 MB) or LZ4-compressed when ``lz4`` is
installed. Format: https://mcap.dev/spec (records: opcode u8, length u64, content;
little-endian)."""

from __future__ import annotations

import importlib
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

MAGIC = b"\x89MCAP0\r\n"
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, DATA_END = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start, end, uncompressed size, uncompressed crc


class McapError(ValueError):
    """The file is not a readable MCAP file; the message says where and why."""


@dataclass(frozen=True, slots=True)
class Channel:
    id: int
    topic: str
    message_encoding: str


@dataclass(frozen=True, slots=True)
class Message:
    channel: Channel
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass(frozen=True, slots=True)
class Recording:
    profile: str
    library: str
    messages: list[Message]  # in log-time order (file order among equal times)


def read(path: Path) -> Recording:
    """Every message of the file at ``path``, in log-time order."""
    return parse(path.read_bytes())


def parse(data: bytes) -> Recording:
    if data[:8] != MAGIC:
        raise McapError("no MCAP magic at the start")
    if len(data) < 16 or data[-8:] != MAGIC:  # a writer that did not finish: data may be cut too
        raise McapError("no MCAP magic at the end (truncated?)")
    profile = library = ""
    channels: dict[int, Channel] = {}
    found: list[tuple[int, int, Message]] = []
    ended = False
    for opcode, start, end in _records(data, 8, len(data), top=True):
        if opcode == HEADER:
            profile, at = _string(data, start)
            library, _ = _string(data, at)
        elif opcode == CHUNK:
            records = _chunk(data, start)
            for op, s, e in _records(records, 0, len(records), top=False):
                _take(op, records, s, e, channels, found)
        elif opcode in (DATA_END, FOOTER):
            ended = True
            break
        else:
            _take(opcode, data, start, end, channels, found)
    if not ended:
        raise McapError("the file ends before its data section does (truncated?)")
    found.sort(key=lambda m: (m[0], m[1]))
    return Recording(profile, library, [m for _, _, m in found])


def _records(data: bytes, at: int, stop: int, *, top: bool) -> Iterator[tuple[int, int, int]]:
    while at < stop:
        if top and data[at : at + 8] == MAGIC and at + 8 == stop:
            return
        if at + 9 > stop:
            raise McapError(f"a record header is cut off at byte {at}")
        opcode = data[at]
        (length,) = _U64.unpack_from(data, at + 1)
        start, end = at + 9, at + 9 + length
        if end > stop:
            raise McapError(f"record 0x{opcode:02x} at byte {at} runs past the end (truncated?)")
        yield opcode, start, end
        at = end


def _take(
    opcode: int,
    buf: bytes,
    start: int,
    end: int,
    channels: dict[int, Channel],
    found: list[tuple[int, int, Message]],
) -> None:
    """Keeps a channel or a message record; every other kind says nothing replay needs."""
    if opcode == CHANNEL:
        (cid,) = _U16.unpack_from(buf, start)
        topic, at = _string(buf, start + 4)  # after the schema id
        encoding, _ = _string(buf, at)
        channels[cid] = Channel(cid, topic, encoding)
    elif opcode == MESSAGE:
        cid, sequence, log_time, publish_time = _MESSAGE.unpack_from(buf, start)
        channel = channels.get(cid)
        if channel is None:
            raise McapError(f"a message at byte {start} on channel {cid}, never declared")
        body = bytes(buf[start + _MESSAGE.size : end])
        found.append(
            (log_time, len(found), Message(channel, log_time, publish_time, sequence, body))
        )


def _chunk(data: bytes, start: int) -> bytes:
    """A chunk's records, uncompressed and checked."""
    _first, _last, size, crc = _CHUNK.unpack_from(data, start)
    compression, at = _string(data, start + _CHUNK.size)
    (length,) = _U64.unpack_from(data, at)
    body = data[at + 8 : at + 8 + length]
    if compression == "":
        records = bytes(body)
    elif compression == "zstd":
        records = _zstd().decompress(body)
    elif compression == "lz4":
        try:
            import lz4.frame
        except ModuleNotFoundError:
            raise McapError(
                "its chunks are LZ4-compressed: pip install lz4 (simpletrack record writes "
                "zstd, which every install reads)"
            ) from None
        records = lz4.frame.decompress(body)
    else:
        raise McapError(f"chunk compression {compression!r} is not one MCAP defines")
    if len(records) != size:
        raise McapError(f"a chunk at byte {start} unpacks to {len(records)} bytes, not {size}")
    if crc and zlib.crc32(records) != crc:
        raise McapError(f"a chunk at byte {start} fails its CRC")
    return records


def _string(data: bytes, at: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(data, at)
    return bytes(data[at + 4 : at + 4 + n]).decode(), at + 4 + n


def _zstd() -> Any:
    """Python 3.14's zstd module, or its backport (a dependency of every install before 3.14)."""
    for name in ("compression.zstd", "backports.zstd"):
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError:
            continue
    raise McapError("its chunks are zstd-compressed: pip install backports.zstd")
