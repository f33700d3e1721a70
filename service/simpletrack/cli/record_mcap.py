"""``simpletrack record --format mcap``: every sample of the chosen sensors' detections, tracks
and errors keys, its payload bytes unchanged, into one MCAP file (layout in mcap_format), and
unless told not to, the same messages in forms Foxglove shows (mcap_foxglove)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import BinaryIO

import zenoh
from mcap.writer import Writer

from simpletrack.cli.errors import UserError
from simpletrack.cli.mcap_format import (
    MESSAGE_ENCODING,
    METADATA_NAME,
    SCHEMA_ENCODING,
    SCHEMA_NAMES,
    TOOL,
    schema_data,
    split_key,
    version,
)
from simpletrack.cli.mcap_foxglove import JSON_ENCODING, Derived, FoxgloveChannels, foxglove_schema
from simpletrack.client.publisher import check_name
from simpletrack.wire.header import peek_header

_UINT32 = 1 << 32


def parse_sensors(values: list[str] | None) -> list[tuple[str, str]]:
    """``vehicle/sensor`` pairs (``*`` allowed in either place), comma- or space-separated."""
    items = [s.strip() for v in values or ["*/*"] for s in v.split(",") if s.strip()]
    out = []
    for item in items:
        vehicle, _, sensor = item.partition("/")
        try:
            for kind, name in (("vehicle", vehicle), ("sensor", sensor)):
                if name != "*":
                    check_name(kind, name)
        except ValueError as exc:
            raise UserError(f"--sensors {item!r}: expected vehicle/sensor; {exc}") from None
        out.append((vehicle, sensor))
    return out


def parse_what(text: str, choices: tuple[str, ...]) -> list[str]:
    what = [w.strip() for w in text.split(",") if w.strip()]
    for w in what:
        if w not in choices:
            raise UserError(f"--what {w!r}: choose from {', '.join(choices)}")
    if not what:
        raise UserError("--what is empty")
    return list(dict.fromkeys(what))


class McapRecorder:
    """Writes samples as they arrive (from Zenoh's threads, hence the lock); channels and
    schemas are registered on a topic's first message. ``messages`` counts the raw samples."""

    def __init__(self, path: Path, prefix: str, foxglove: bool = True) -> None:
        try:
            self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise UserError(f"--out {path}: {exc.strerror}") from None
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
