"""Sensor snapshots on disk: one msgpack ``SensorSnapshot`` per sensor,
``<state_dir>/<vehicle>/<sensor>.snap``, replaced atomically (tmp file, fsync, rename).

Workers serialise their sensors (they own the trackers); one writer thread does the disk I/O
so that a slow disk never stalls tracking.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from simpletrack.server.logs import get_logger
from simpletrack.wire.codec import DecodeLimits, Rejection, decode_message
from simpletrack.wire.models import SensorSnapshot

SUFFIX = ".snap"
log = get_logger("snapshots")
_LIMITS = DecodeLimits(max_bytes=1 << 30, max_boxes=1 << 30)  # our own files: no cap


def snapshot_path(state_dir: Path, vehicle: str, sensor: str) -> Path:
    return state_dir / vehicle / f"{sensor}{SUFFIX}"


def write_atomic(path: Path, data: bytes) -> None:
    """Readers see the old file or the new one, never a torn write, even after a crash."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)  # make the rename itself durable
    finally:
        os.close(dir_fd)


def read_all(state_dir: Path) -> Iterator[SensorSnapshot]:
    """Every readable snapshot; unreadable ones are logged and skipped (never fatal)."""
    if not state_dir.is_dir():
        return
    for path in sorted(state_dir.glob(f"*/*{SUFFIX}")):
        try:
            data = path.read_bytes()
        except OSError as e:
            log.error("snapshot_unreadable", path=str(path), error=e.strerror)
            continue
        snap = decode_message(data, SensorSnapshot, _LIMITS)
        if isinstance(snap, Rejection):
            log.error("snapshot_invalid", path=str(path), reason=snap.reason, field=snap.field)
            continue
        if path != snapshot_path(state_dir, snap.vehicle, snap.sensor):
            log.error(
                "snapshot_misplaced", path=str(path), vehicle=snap.vehicle, sensor=snap.sensor
            )
            continue
        yield snap


@dataclass(frozen=True, slots=True)
class Batch:
    files: list[tuple[Path, bytes]]
    on_done: Callable[[int, int], None]  # (written, failed)


class SnapshotWriter:
    """A thread writing batches of snapshot files in submission order."""

    def __init__(self) -> None:
        self._queue: queue.Queue[Batch | None] = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="snapshot-writer", daemon=True)
        self._thread.start()

    def submit(self, batch: Batch) -> None:
        self._queue.put(batch)

    def close(self, timeout: float) -> bool:
        """Write what was submitted, then stop. False if that took longer than ``timeout``."""
        self._queue.put(None)
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while (batch := self._queue.get()) is not None:
            written = failed = 0
            for path, data in batch.files:
                try:
                    write_atomic(path, data)
                    written += 1
                except OSError as e:
                    failed += 1
                    log.error("snapshot_write_failed", path=str(path), error=str(e))
            batch.on_done(written, failed)
