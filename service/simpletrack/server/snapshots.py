"""Sensor snapshots on disk: one msgpack ``SensorSnapshot`` per sensor,
``<state_dir>/<vehicle>/<sensor>.snap``, replaced atomically (tmp file, fsync, rename).

Workers serialise their sensors (they own the trackers); one writer thread does the disk I/O
so that a slow disk never stalls tracking.

Beside each snapshot, ``<sensor>.ids`` holds the sensor's id reservation: a number above every
id the sensor has published. It is written (atomically, fsync'd) before any id at or above
the previous reservation is published, a block of ``ID_BLOCK`` ids at a time, so that a
truncated, garbled or deleted snapshot can cost the tracks but never the ids' uniqueness.
"""

from __future__ import annotations

import os
import queue
import re
import threading
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from simpletrack.server.logs import get_logger
from simpletrack.wire.codec import DecodeLimits, Rejection, decode_message
from simpletrack.wire.models import SensorSnapshot

SUFFIX = ".snap"
IDS_SUFFIX = ".ids"
# Ids reserved per write: one fsync'd write per this many new tracks of a sensor; a crash
# skips at most this many ids (int64 leaves room for 9e15 such crashes).
ID_BLOCK = 1024
log = get_logger("snapshots")
_LIMITS = DecodeLimits(max_bytes=1 << 30, max_boxes=1 << 30)  # our own files: no cap
# "simpletrack-ids 1 <vehicle>/<sensor> <id floor> <crc32 of what precedes it, hex>"
_IDS_LINE = re.compile(r"(simpletrack-ids 1 ([^/ ]+)/([^/ ]+) ([0-9]{1,19})) ([0-9a-f]{8})\n")


def snapshot_path(state_dir: Path, vehicle: str, sensor: str) -> Path:
    return state_dir / vehicle / f"{sensor}{SUFFIX}"


def ids_path(state_dir: Path, vehicle: str, sensor: str) -> Path:
    return state_dir / vehicle / f"{sensor}{IDS_SUFFIX}"


def encode_ids(vehicle: str, sensor: str, floor: int) -> bytes:
    """The reservation file: one text line, checksummed so that damage is seen, not read."""
    body = f"simpletrack-ids 1 {vehicle}/{sensor} {floor}"
    return f"{body} {zlib.crc32(body.encode()):08x}\n".encode()


def decode_ids(data: bytes) -> tuple[str, str, int] | None:
    """(vehicle, sensor, id floor) of a reservation file; None if it is damaged."""
    m = _IDS_LINE.fullmatch(data.decode("ascii", errors="replace"))
    if m is None or int(m.group(5), 16) != zlib.crc32(m.group(1).encode()):
        return None
    floor = int(m.group(4))
    return (m.group(2), m.group(3), floor) if floor < 2**63 else None


def _read_ids(path: Path) -> tuple[str, str, int] | None:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as e:
        log.error("id_reservation_unreadable", path=str(path), error=e.strerror)
        return None
    found = decode_ids(data)
    if found is None:
        log.error("id_reservation_invalid", path=str(path), bytes=len(data))
    return found


def read_ids(state_dir: Path, vehicle: str, sensor: str) -> int | None:
    """One sensor's id floor; None without a readable reservation file."""
    found = _read_ids(ids_path(state_dir, vehicle, sensor))
    return None if found is None or found[:2] != (vehicle, sensor) else found[2]


def read_all_ids(state_dir: Path) -> Iterator[tuple[str, str, int]]:
    """(vehicle, sensor, id floor) of every readable reservation file (damage is logged)."""
    if not state_dir.is_dir():
        return
    for path in sorted(state_dir.glob(f"*/*{IDS_SUFFIX}")):
        found = _read_ids(path)
        if found is None:
            continue
        if path != ids_path(state_dir, found[0], found[1]):
            log.error("id_reservation_misplaced", path=str(path), vehicle=found[0], sensor=found[1])
            continue
        yield found


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
