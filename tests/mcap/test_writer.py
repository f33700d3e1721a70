"""The MCAP writer never holds Zenoh's thread: samples queue for one writer thread; what the
queue cannot take is counted as unrecorded, and the file is complete either way."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import pytest
from mcap.reader import make_reader

from simpletrack.mcap import writer as writer_module
from simpletrack.mcap.writer import McapRecorder
from simpletrack.wire import encode_detection_frame, encode_track_frame
from tests.client.test_epoch_fencing import _arrays
from tests.service_helpers import moving_cars, stamp


@dataclass
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class _Sample:
    key_expr: str
    payload: _Payload


def _sample(seq: int) -> _Sample:
    payload = encode_detection_frame(
        vehicle="veh",
        sensor="lidar",
        seq=seq,
        stamp_ns=stamp(seq),
        frame_id="lidar",
        boxes=moving_cars(seq, 2),
    )
    return _Sample("fleet/veh/lidar/detections", _Payload(payload))


def test_a_stalled_writer_costs_counted_samples_not_the_callback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(writer_module, "QUEUE_SAMPLES", 5)
    held = threading.Event()
    release = threading.Event()
    real_write = McapRecorder._write

    def slow_write(self: McapRecorder, *item: object) -> None:
        held.set()
        release.wait()  # the disk, or a huge frame's conversion, stalls here
        real_write(self, *item)  # type: ignore[arg-type]

    monkeypatch.setattr(McapRecorder, "_write", slow_write)
    out = tmp_path / "stalled.mcap"
    rec = McapRecorder(out, "fleet")
    rec.on_sample(_sample(0))  # type: ignore[arg-type]
    assert held.wait(10)
    # The writer holds sample 0; 5 more fill the queue, 14 more find it full. Every call
    # returns (a blocking callback would hang this test, which has a timeout).
    for seq in range(1, 20):
        rec.on_sample(_sample(seq))  # type: ignore[arg-type]
    assert rec.unrecorded == 14
    release.set()
    rec.close()
    assert (rec.messages, rec.unrecorded) == (6, 14)
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        seqs = [m.sequence for _, c, m in reader.iter_messages() if c.topic.endswith("detections")]
    assert summary is not None  # complete, indexed
    assert seqs == list(range(6))


def test_a_sample_the_writer_cannot_write_is_counted_and_the_rest_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_peek = writer_module.peek_header

    def peek(payload: bytes) -> tuple[int | None, int | None]:
        if payload == b"boom":
            raise ValueError("a sample the writer chokes on")
        return real_peek(payload)

    monkeypatch.setattr(writer_module, "peek_header", peek)
    out = tmp_path / "bad.mcap"
    rec = McapRecorder(out, "fleet")
    rec.on_sample(_sample(0))  # type: ignore[arg-type]
    rec.on_sample(_Sample("fleet/veh/lidar/detections", _Payload(b"boom")))  # type: ignore[arg-type]
    rec.on_sample(_sample(1))  # type: ignore[arg-type]
    rec.close()
    assert (rec.messages, rec.unrecorded) == (2, 1)
    with open(out, "rb") as f:
        seqs = [m.sequence for _, c, m in make_reader(f).iter_messages() if "json" not in c.topic]
    assert seqs == [0, 0, 1, 1]  # each frame's raw message and its scene (no json filter hit)


def _tracks(seq: int, epoch: int, instance: str) -> _Sample:
    payload = encode_track_frame(
        vehicle="veh", sensor="lidar", seq=seq, stamp_ns=stamp(seq), frame_id="lidar",
        pose=None, key_frame=True, instance=instance, received_ns=stamp(seq),
        published_ns=stamp(seq), tracks=_arrays(), schema_version=3, epoch=epoch,
    )  # fmt: skip
    return _Sample("fleet/veh/lidar/tracks", _Payload(payload))


def test_a_fenced_holders_tracks_are_left_out_and_counted(tmp_path: Path) -> None:
    """The epoch rule of schemas/README.md: a message of a lower epoch than the stream has
    shown is a fenced holder's; a repeat of the new holder's is recorded as it came."""
    out = tmp_path / "fenced.mcap"
    rec = McapRecorder(out, "fleet", foxglove=False)
    for sample in (
        _tracks(0, 1 << 16, "a"),
        _tracks(1, 2 << 16, "b"),  # b took the stream over
        _tracks(1, 1 << 16, "a"),  # a, stopped, resumed: stale
        _tracks(1, 2 << 16, "b"),  # b again (a failover's repeat)
        _tracks(2, 2 << 16, "b"),
    ):
        rec.on_sample(sample)  # type: ignore[arg-type]
    rec.close()
    assert (rec.messages, rec.stale) == (4, 1)
    with open(out, "rb") as f:
        seqs = [m.sequence for _, c, m in make_reader(f).iter_messages()]
    assert seqs == [0, 1, 1, 2]
