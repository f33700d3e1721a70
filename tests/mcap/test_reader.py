"""The light install's MCAP reader (simpletrack.mcap.reader) reads what the mcap package writes,
message for message, and refuses a damaged file with where and why."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from simpletrack.mcap.reader import McapError, parse, read


def _written(compression: CompressionType, chunk_size: int = 256) -> bytes:
    buf = io.BytesIO()
    w = Writer(buf, compression=compression, chunk_size=chunk_size)
    w.start(profile="simpletrack", library="test")
    schema = w.register_schema("S", "jsonschema", b"{}")
    a = w.register_channel("fleet/v/lidar/detections", "msgpack", schema)
    b = w.register_channel("fleet/v/cam/detections", "msgpack", schema)
    # Log times out of file order across channels and chunks: the reader must sort them.
    for k in range(40):
        w.add_message(
            a, log_time=1000 + 10 * k, data=bytes([k]) * (k + 1), publish_time=k, sequence=k
        )
        w.add_message(b, log_time=1000 + 10 * k - 5, data=b"c%d" % k, publish_time=k, sequence=k)
    w.finish()
    return buf.getvalue()


def _official(data: bytes) -> list[tuple[str, str, int, int, int, bytes]]:
    reader = make_reader(io.BytesIO(data))
    return [
        (c.topic, c.message_encoding, m.log_time, m.publish_time, m.sequence, m.data)
        for _s, c, m in reader.iter_messages(log_time_order=True)
    ]


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
def test_every_message_as_the_mcap_package_reads_it(compression: CompressionType) -> None:
    data = _written(compression)
    got = parse(data)
    mine = [
        (
            m.channel.topic,
            m.channel.message_encoding,
            m.log_time,
            m.publish_time,
            m.sequence,
            m.data,
        )
        for m in got.messages
    ]
    assert got.profile == "simpletrack" and got.library == "test"
    assert len(mine) == 80 and mine == _official(data)
    assert [m[2] for m in mine] == sorted(m[2] for m in mine)


def test_a_file_cut_short_is_refused(tmp_path: Path) -> None:
    data = _written(CompressionType.ZSTD)
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(McapError, match="truncated"):
        read(path)


def test_a_damaged_chunk_is_refused() -> None:
    data = bytearray(_written(CompressionType.NONE, chunk_size=1 << 20))
    at = data.index(b"c17")  # inside the one uncompressed chunk
    data[at : at + 3] = b"XYZ"
    with pytest.raises(McapError, match="CRC"):
        parse(bytes(data))


def test_not_mcap_is_refused() -> None:
    with pytest.raises(McapError, match="magic"):
        parse(b'{"vehicle": "veh00"}\n')
