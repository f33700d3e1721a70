"""Writing tracks to files beside the client's JSON lines (``simpletrack.client.jsonl``): the
simulator's ground truth in that layout, and the KITTI tracking result format (for
``simpletrack eval kitti --results``).

Ground truth uses the JSON lines layout (``tracks`` holding the true objects, ``state`` "truth", or
"ignored" for the mostly hidden ones the scorer ignores), so ``simpletrack plot`` reads both.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.client.jsonl import rounded
from simpletrack.core.boxes import Boxes
from simpletrack.datasets.kitti import Calib, ResultRows, format_results, read_calib, tracks_to_rows
from simpletrack.wire import TrackArrays, TrackFrame
from simpletrack.wire.convert import track_boxes_from_wire


def truth_to_json(
    vehicle: str,
    sensor: str,
    seq: int,
    stamp_ns: int,
    ids: npt.NDArray[np.int64],
    boxes: Boxes,
    class_names: Sequence[str],
    ignore: npt.NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """The simulator's truth of one sensor frame; ``ignore`` marks objects the scorer ignores
    (state "ignored", the others "truth")."""
    hidden = [False] * len(ids) if ignore is None else ignore.tolist()
    return {
        "vehicle": vehicle,
        "sensor": sensor,
        "seq": seq,
        "stamp_ns": stamp_ns,
        "frame_id": "world",
        "tracks": [
            {"id": i, "cls": class_names[c], "box": b, "state": "ignored" if h else "truth"}
            for i, c, b, h in zip(
                ids.tolist(), boxes.cls.tolist(), rounded(boxes.params), hidden, strict=True
            )
        ],
    }


class KittiWriter:
    """KITTI tracking results, one file per stream: ``out/data_0/<name>.txt`` where the name is
    the stream's sensor id (``replay kitti`` names sensors by sequence, e.g. ``0001``).

    Rows are buffered per stream and each file is rewritten sorted by frame on ``flush()``
    and ``close()``. The 2D boxes need the sequence's camera calibration: from
    ``calib_dir/<name>.txt`` when given, else all-zero boxes (the evaluator's 2D rules then
    cannot apply: give the calibration when the files are to be scored)."""

    def __init__(self, out_dir: Path, calib_dir: Path | None) -> None:
        self.out_dir = out_dir
        self.calib_dir = calib_dir
        self._rows: dict[str, list[ResultRows]] = {}
        self._calib: dict[str, Calib | None] = {}
        self.frames = 0

    def calib_for(self, name: str) -> Calib | None:
        if name not in self._calib:
            calib = None
            if self.calib_dir is not None:
                path = self.calib_dir / f"{name}.txt"
                if not path.is_file():
                    raise FileNotFoundError(f"no calibration for stream {name!r}: {path}")
                calib = read_calib(path)
            self._calib[name] = calib
        return self._calib[name]

    def write(self, frame: TrackFrame, tracks: TrackArrays) -> None:
        name = frame.sensor
        self.calib_for(name)
        boxes = track_boxes_from_wire(tracks)
        rows = tracks_to_rows(frame.seq, tracks.id.astype(np.int64), boxes, tracks.classes)
        self._rows.setdefault(name, []).append(rows)
        self.frames += 1

    def flush(self) -> list[Path]:
        paths = []
        for name, parts in self._rows.items():
            rows = ResultRows.concat(parts)
            self._rows[name] = [rows]
            ordered = rows.by_frame()
            path = self.out_dir / "data_0" / f"{name}.txt"
            path.parent.mkdir(parents=True, exist_ok=True)
            calib = self._calib.get(name)
            text = (
                format_results(ordered, calib) if calib is not None else _format_no_calib(ordered)
            )
            tmp = path.with_suffix(".tmp")
            tmp.write_text(text)
            tmp.replace(path)
            paths.append(path)
        return paths

    def close(self) -> list[Path]:
        return self.flush()


def _format_no_calib(rows: ResultRows) -> str:
    from simpletrack.datasets.kitti import observation_angle

    alpha = observation_angle(rows.cam)
    nums = np.column_stack([alpha, np.zeros((len(alpha), 4)), rows.cam, rows.score])
    return "".join(
        f"{int(f)} {int(i)} {t} 0 0 " + " ".join(f"{v:.6f}" for v in vals) + "\n"
        for f, i, t, vals in zip(rows.frame, rows.track_id, rows.type_name, nums, strict=True)
    )
