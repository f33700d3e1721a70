"""An MCAP recording of Zenoh samples: every sample of the chosen keys (sensors' and fused
vehicles'), its payload bytes unchanged (layout in format.py), and unless told not to, the
same messages in forms Foxglove shows (foxglove.py); when given a ``Ros2Bag``, their Autoware
messages in a ROS 2 bag next to it (ros2.py). Used by ``simpletrack record --format mcap``
and ``simpletrack demo --mcap``."""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import BinaryIO

import zenoh
from mcap.writer import Writer

from simpletrack.client.stream_filter import StreamFilter, Verdict
from simpletrack.mcap.format import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    TOOL,
    recorded_keys,
    schema_data,
    schema_name,
    split_key,
    version,
)
from simpletrack.mcap.foxglove import JSON_ENCODING, Derived, FoxgloveChannels, foxglove_schema
from simpletrack.mcap.ros2 import Ros2Bag
from simpletrack.wire.header import peek_custody, peek_header
from simpletrack.wire.keys import TRACKS

_UINT32 = 1 << 32


QUEUE_SAMPLES = 10_000  # samples waiting for the writer: ~1 min of a 30-sensor fleet at 10 Hz


class McapRecorder:
    """Zenoh's callback only queues the sample (received time, key, payload); one writer
    thread converts (the Foxglove twins cost ~3 ms for a 100-box frame) and writes, so a
    slow disk or a big frame never holds Zenoh's thread. Channels and schemas are registered
    on a topic's first message. ``messages`` counts the raw samples written; ``unrecorded``
    those refused because the writer was ``QUEUE_SAMPLES`` behind, or that it could not
    write (said in the summary: never a silent loss). ``ros2``: the bag that each written
    detections and tracks sample also goes to (the recorder closes it)."""

    def __init__(
        self, path: Path, prefix: str, foxglove: bool = True, ros2: Ros2Bag | None = None
    ) -> None:
        self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 (closed in close())
        self.path = path
        self._writer = Writer(self._file)
        self._writer.start(profile="", library=f"simpletrack {version()}")
        metadata = {
            "tool": TOOL,
            "version": version(),
            "prefix": prefix,
            "foxglove": str(foxglove).lower(),
        }
        if ros2 is not None:
            metadata["ros2"] = ros2.path.name
        self._writer.add_metadata(METADATA_NAME, metadata)
        self._ros2 = ros2
        self._lock = threading.Lock()
        self._foxglove = FoxgloveChannels() if foxglove else None
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[str, int] = {}
        self._closed = False
        self.messages = 0
        self.unrecorded = 0
        self.stale = 0  # tracks messages of fenced holders, left out
        # Epochs only: every exact repeat on the wire is recorded as it came.
        self._epochs = StreamFilter(recent_frames=1)
        self.last_ns: int | None = None
        self._queue: queue.Queue[tuple[int, str, bytes] | None] = queue.Queue(QUEUE_SAMPLES)
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._thread.start()

    def _channel(self, topic: str, encoding: str, name: str, data: bytes) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get((name, encoding))
            if schema is None:
                schema = self._writer.register_schema(name, SCHEMA_ENCODING, data)
                self._schemas[(name, encoding)] = schema
            channel = self._writer.register_channel(topic, encoding, schema)
            self._channels[topic] = channel
        return channel

    def _raw_channel(self, key: str, name: str) -> int:
        return self._channel(key, MESSAGE_ENCODING, name, schema_data(name))

    def _derived_channel(self, d: Derived) -> int:
        return self._channel(d.topic, JSON_ENCODING, d.schema, foxglove_schema(d.schema))

    def on_sample(self, sample: zenoh.Sample) -> None:
        item = (time.time_ns(), str(sample.key_expr), sample.payload.to_bytes())
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self.unrecorded += 1
        else:
            self.last_ns = item[0]

    def _write_loop(self) -> None:
        while (item := self._queue.get()) is not None:
            try:
                self._write(*item)
            except Exception:  # one bad sample must not end the recording
                with self._lock:
                    self.unrecorded += 1

    def _write(self, received: int, key: str, payload: bytes) -> None:
        parts = split_key(key)
        if parts is None:
            return
        seq, stamp = peek_header(payload)
        if parts[3] == TRACKS and seq is not None and stamp is not None:
            # A fenced holder's message (an epoch below the stream's highest) is not what
            # planners got: not recorded (schemas/README.md, "Custody epoch").
            epoch = peek_custody(payload)[1]
            if self._epochs.admit(key, seq, stamp, epoch) is Verdict.STALE:
                with self._lock:
                    self.stale += 1
                return
        publish = received if stamp is None else stamp
        # MCAP's sequence is 32 bits: wire seqs past that wrap.
        sequence = 0 if seq is None else seq % _UINT32
        derived = (
            self._foxglove.derive(key, parts[3], parts[1], parts[2], payload)
            if self._foxglove is not None
            else []
        )
        channels = [(self._raw_channel(key, schema_name(parts[2], parts[3])), payload)]
        channels += [(self._derived_channel(d), d.data) for d in derived]
        for channel, data in channels:
            self._writer.add_message(
                channel, log_time=received, data=data, publish_time=publish, sequence=sequence
            )
        with self._lock:
            self.messages += 1
        if self._ros2 is not None:
            self._ros2.add(
                parts[3],
                parts[1],
                parts[2],
                payload,
                log_time=received,
                publish_time=publish,
                sequence=sequence,
            )

    def close(self) -> None:
        """Writes what is queued, then the summary: the file is complete and indexed. Samples
        that arrive after this are not recorded."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._queue.put(None)  # after everything queued so far
        self._thread.join()
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
            if self._ros2 is not None:
                self._ros2.close()


def subscribe(
    session: zenoh.Session,
    prefix: str,
    sensors: list[tuple[str, str]],
    what: list[str],
    recorder: McapRecorder,
) -> list[zenoh.Subscriber[None]]:
    """Subscribes the recorder to ``recorded_keys(prefix, sensors, what)``: a whole vehicle
    or the fleet brings the fused vehicles' tracks (``<vehicle>/@vehicle/tracks``) too."""
    return [
        session.declare_subscriber(key, recorder.on_sample)
        for key in recorded_keys(prefix, sensors, what)
    ]
