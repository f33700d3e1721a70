"""An MCAP recording of Zenoh samples: every sample of the chosen keys, its payload bytes
unchanged (layout in format.py), and unless told not to, the same messages in forms Foxglove
shows (foxglove.py). Used by ``simpletrack record --format mcap`` and ``simpletrack demo --mcap``."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import BinaryIO

import zenoh
from mcap.writer import Writer

from simpletrack.mcap.format import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    SCHEMA_NAMES,
    TOOL,
    schema_data,
    split_key,
    version,
)
from simpletrack.mcap.foxglove import JSON_ENCODING, Derived, FoxgloveChannels, foxglove_schema
from simpletrack.wire.header import peek_header

_UINT32 = 1 << 32


class McapRecorder:
    """Writes samples as they arrive (from Zenoh's threads, hence the lock); channels and
    schemas are registered on a topic's first message. ``messages`` counts the raw samples."""

    def __init__(self, path: Path, prefix: str, foxglove: bool = True) -> None:
        self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 (closed in close())
        self.path = path
        self._writer = Writer(self._file)
        self._writer.start(profile="", library=f"simpletrack {version()}")
        self._writer.add_metadata(
            METADATA_NAME,
            {
                "tool": TOOL,
                "version": version(),
                "prefix": prefix,
                "foxglove": str(foxglove).lower(),
            },
        )
        self._lock = threading.Lock()
        self._foxglove = FoxgloveChannels() if foxglove else None
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[str, int] = {}
        self._closed = False
        self.messages = 0
        self.last_ns: int | None = None

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

    def _raw_channel(self, key: str, leaf: str) -> int:
        return self._channel(key, MESSAGE_ENCODING, SCHEMA_NAMES[leaf], schema_data(leaf))

    def _derived_channel(self, d: Derived) -> int:
        return self._channel(d.topic, JSON_ENCODING, d.schema, foxglove_schema(d.schema))

    def on_sample(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        key = str(sample.key_expr)
        parts = split_key(key)
        if parts is None:
            return
        payload = sample.payload.to_bytes()
        seq, stamp = peek_header(payload)
        publish = received if stamp is None else stamp
        # MCAP's sequence is 32 bits: wire seqs past that wrap.
        sequence = 0 if seq is None else seq % _UINT32
        with self._lock:
            if self._closed:
                return
            # Under the lock: the scene converter keeps per-sensor state.
            derived = (
                self._foxglove.derive(key, parts[3], parts[1], parts[2], payload)
                if self._foxglove is not None
                else []
            )
            channels = [(self._raw_channel(key, parts[3]), payload)]
            channels += [(self._derived_channel(d), d.data) for d in derived]
            for channel, data in channels:
                self._writer.add_message(
                    channel, log_time=received, data=data, publish_time=publish, sequence=sequence
                )
            self.messages += 1
            self.last_ns = received

    def close(self) -> None:
        """Writes the summary: the file is complete and indexed."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()  # type: ignore[no-untyped-call]
            finally:
                self._file.close()


def subscribe(
    session: zenoh.Session,
    prefix: str,
    sensors: list[tuple[str, str]],
    what: list[str],
    recorder: McapRecorder,
) -> list[zenoh.Subscriber[None]]:
    return [
        session.declare_subscriber(f"{prefix}/{v}/{s}/{leaf}", recorder.on_sample)
        for v, s in sensors
        for leaf in what
    ]
