"""Reading recorded boxes for plots: tracks, ground truth and detections, in the formats the
project writes or reads.

- JSON lines, one frame per line (what ``simpletrack record --format jsonl`` writes):
  ``{"vehicle", "sensor", "seq", "stamp_ns", "tracks": [{"id", "cls", "box", "score", ...}]}``;
  entries with ``"state": "ignored"`` (the demo's mostly hidden truth) are skipped.
- JSON lines, one box per line (the reference's nuScenes files):
  ``{"scene", "frame", "cls", "id", "box", "score"}``; ``scene`` names the stream.
- KITTI tracking results and labels (space separated, camera frame), ``DontCare`` skipped.
- KITTI-style detection files (comma separated, camera frame; no ids).

Everything comes back in the tracker's z-up frame as ``FrameBoxes`` keyed by frame index.
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.datasets.kitti import camera_to_tracker

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Str = npt.NDArray[np.str_]


class FileFormat(StrEnum):
    AUTO = "auto"
    JSONL = "jsonl"
    KITTI = "kitti"  # tracking results or labels
    KITTI_DETECTIONS = "kitti-detections"


@dataclass(frozen=True, slots=True)
class FrameBoxes:
    """Boxes of one frame: ids (-1 when the source has none), z-up params (N, 7), class
    names, scores (NaN when the source has none)."""

    ids: I64
    params: F64
    cls: Str
    score: F64

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def only(self, classes: set[str] | None) -> FrameBoxes:
        if not classes:
            return self
        keep = np.isin(np.char.lower(self.cls), [c.lower() for c in classes])
        return FrameBoxes(self.ids[keep], self.params[keep], self.cls[keep], self.score[keep])


Sequence = dict[int, FrameBoxes]


class TrackFileError(ValueError):
    """A file that cannot be read as the format it claims (message names file and line)."""


# Detector type codes of the KITTI-style detection files (data/README.md).
KITTI_DET_TYPES = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}


def _build(rows: dict[int, list[tuple[int, list[float], str, float]]]) -> Sequence:
    out: Sequence = {}
    for frame in sorted(rows):
        items = rows[frame]
        out[frame] = FrameBoxes(
            ids=np.array([i for i, _, _, _ in items], dtype=np.int64),
            params=np.array([b for _, b, _, _ in items], dtype=np.float64).reshape(-1, 7),
            cls=np.array([c for _, _, c, _ in items], dtype=np.str_),
            score=np.array([s for _, _, _, s in items], dtype=np.float64),
        )
    return out


def detect_format(path: Path) -> FileFormat:
    with path.open() as f:
        for line in f:
            text = line.strip()
            if not text:
                continue
            if text.startswith("{"):
                return FileFormat.JSONL
            return FileFormat.KITTI_DETECTIONS if "," in text else FileFormat.KITTI
    raise TrackFileError(f"{path}: empty file")


def read_jsonl(path: Path) -> dict[str, Sequence]:
    """Every stream of a JSON-lines file: ``"vehicle/sensor"`` (or the scene) → frames."""
    streams: dict[str, dict[int, list[tuple[int, list[float], str, float]]]] = defaultdict(
        lambda: defaultdict(list)
    )
    with path.open() as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                obj: dict[str, Any] = json.loads(line)
                if "tracks" in obj:
                    stream = f"{obj['vehicle']}/{obj['sensor']}"
                    frame = int(obj["seq"])
                    items = obj["tracks"]
                    target = streams[stream][frame]
                    # Truth the scorer ignores (mostly hidden) is not drawn either.
                    target.extend(_jsonl_box(t) for t in items if t.get("state") != "ignored")
                else:
                    stream = str(obj.get("scene", "-"))
                    streams[stream][int(obj["frame"])].append(_jsonl_box(obj))
            except (ValueError, KeyError, TypeError) as exc:
                raise TrackFileError(f"{path}:{n}: not a track record ({exc})") from None
    return {name: _build(rows) for name, rows in streams.items()}


def _jsonl_box(t: dict[str, Any]) -> tuple[int, list[float], str, float]:
    box = [float(v) for v in t["box"]]
    if len(box) != 7:
        raise ValueError(f"box has {len(box)} values, expected 7")
    score = t.get("score")
    return (
        int(t.get("id", -1)),
        box,
        str(t.get("cls", "?")),
        float("nan" if score is None else score),
    )


def read_kitti(path: Path) -> Sequence:
    """KITTI tracking results (18 columns) or labels (17 columns); DontCare rows skipped."""
    rows: dict[int, list[tuple[int, list[float], str, float]]] = defaultdict(list)
    with path.open() as f:
        for n, line in enumerate(f, 1):
            parts = line.split()
            if not parts:
                continue
            if len(parts) < 17:
                raise TrackFileError(f"{path}:{n}: {len(parts)} columns, expected 17 or 18")
            if parts[2] == "DontCare":
                continue
            try:
                cam = np.array([float(p) for p in parts[10:17]])
                box = camera_to_tracker(cam)[0].tolist()
                score = float(parts[17]) if len(parts) > 17 else float("nan")
                rows[int(parts[0])].append((int(parts[1]), box, parts[2], score))
            except ValueError as exc:
                raise TrackFileError(f"{path}:{n}: {exc}") from None
    return _build(rows)


def read_kitti_detections(path: Path, types: dict[int, str] | None = None) -> Sequence:
    """KITTI-style detection CSV (``frame, type, x1, y1, x2, y2, score, h, w, l, x, y, z,
    rot_y, alpha``); ``types`` maps the type column to names (KITTI's by default)."""
    names = types or KITTI_DET_TYPES
    try:
        raw = np.loadtxt(path, delimiter=",", ndmin=2)
    except ValueError as exc:
        raise TrackFileError(f"{path}: not a detection file ({exc})") from None
    if raw.size == 0:
        return {}
    if raw.shape[1] < 14:
        raise TrackFileError(f"{path}: {raw.shape[1]} columns, expected 15")
    params = camera_to_tracker(raw[:, 7:14])
    frames = raw[:, 0].astype(np.int64)
    cls = np.array([names.get(int(t), str(int(t))) for t in raw[:, 1]], dtype=np.str_)
    out: Sequence = {}
    for k in np.unique(frames).tolist():
        rows = np.flatnonzero(frames == k)
        out[k] = FrameBoxes(
            ids=np.full(rows.shape[0], -1, dtype=np.int64),
            params=params[rows],
            cls=cls[rows],
            score=raw[rows, 6].copy(),
        )
    return out


def read_sequence(
    path: Path, fmt: FileFormat = FileFormat.AUTO, stream: str | None = None
) -> Sequence:
    """One sequence of boxes from a file. JSON-lines files with several streams need
    ``stream`` (``vehicle/sensor`` or a scene name)."""
    if not path.is_file():
        raise TrackFileError(f"{path}: no such file")
    if fmt is FileFormat.AUTO:
        fmt = detect_format(path)
    if fmt is FileFormat.KITTI:
        return read_kitti(path)
    if fmt is FileFormat.KITTI_DETECTIONS:
        return read_kitti_detections(path)
    streams = read_jsonl(path)
    if stream is not None:
        if stream not in streams:
            raise TrackFileError(
                f"{path}: no stream {stream!r}; it has {', '.join(sorted(streams)) or 'none'}"
            )
        return streams[stream]
    if len(streams) > 1:
        raise TrackFileError(
            f"{path} holds {len(streams)} streams ({', '.join(sorted(streams)[:6])}"
            f"{', ...' if len(streams) > 6 else ''}): choose one with --stream"
        )
    return next(iter(streams.values()), {})


def merge(sequences: list[Sequence]) -> Sequence:
    """Frame-wise union of several sequences (e.g. one detection file per class)."""
    frames = sorted({k for s in sequences for k in s})
    out: Sequence = {}
    for k in frames:
        parts = [s[k] for s in sequences if k in s]
        out[k] = FrameBoxes(
            ids=np.concatenate([p.ids for p in parts]),
            params=np.concatenate([p.params for p in parts]),
            cls=np.concatenate([p.cls for p in parts]),
            score=np.concatenate([p.score for p in parts]),
        )
    return out
