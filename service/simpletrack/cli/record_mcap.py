"""``simpletrack record --format mcap``: every sample of the chosen sensors' detections, tracks
and errors keys, its payload bytes unchanged, into one MCAP file (layout in mcap_format)."""

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
    schemas are registered on a key's first sample."""

    def __init__(self, path: Path, prefix: str) -> None:
        try:
            self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise UserError(f"--out {path}: {exc.strerror}") from None
        self.path = path
        self._writer = Writer(self._file)
        self._writer.start(profile="", library=f"simpletrack {version()}")
        self._writer.add_metadata(
            METADATA_NAME, {"tool": TOOL, "version": version(), "prefix": prefix}
        )
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._closed = False
        self.messages = 0
        self.last_ns: int | None = None

    def _channel(self, key: str, leaf: str) -> int:
        channel = self._channels.get(key)
        if channel is None:
            schema = self._schemas.get(leaf)
            if schema is None:
                schema = self._writer.register_schema(
                    SCHEMA_NAMES[leaf], SCHEMA_ENCODING, schema_data(leaf)
                )
                self._schemas[leaf] = schema
            channel = self._writer.register_channel(key, MESSAGE_ENCODING, schema)
            self._channels[key] = channel
        return channel

    def on_sample(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        key = str(sample.key_expr)
        parts = split_key(key)
        if parts is None:
            return
        payload = sample.payload.to_bytes()
        seq, stamp = peek_header(payload)
        with self._lock:
            if self._closed:
                return
            self._writer.add_message(
                self._channel(key, parts[3]),
                log_time=received,
                data=payload,
                publish_time=received if stamp is None else stamp,
                # MCAP's sequence is 32 bits: wire seqs past that wrap.
                sequence=0 if seq is None else seq % _UINT32,
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
