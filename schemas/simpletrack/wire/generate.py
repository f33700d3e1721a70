"""Write (or check) the generated artefacts: JSON Schemas under ``schemas/json``, golden test
vectors under ``schemas/vectors`` and the byte-exact examples in ``schemas/README.md``.

    python -m simpletrack.wire.generate           # rewrite everything
    python -m simpletrack.wire.generate --check   # exit 1 and list what differs (CI, tests)
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, get_args

import numpy as np
import numpy.typing as npt

from simpletrack.wire.codec import (
    Rejection,
    decode_detection_frame,
    decode_message,
    decode_track_frame,
    encode,
    encode_detection_frame,
    encode_track_frame,
    pack,
)
from simpletrack.wire.columns import (
    DETECTION_COLUMNS,
    TRACK_COLUMNS_OF,
    VEHICLE_TRACK_COLUMNS,
    BoxArrays,
    TrackArrays,
    covariance_to_upper,
)
from simpletrack.wire.messages import FrameError as DecodedFrameError
from simpletrack.wire.messages import to_map
from simpletrack.wire.models import MESSAGES, FrameError
from simpletrack.wire.reasons import ErrorReason, SensorCondition
from simpletrack.wire.vehicle_tracks import decode_vehicle_track_frame, encode_vehicle_track_frame

ROOT = Path(__file__).resolve().parents[2]  # schemas/
JSON_DIR = ROOT / "json"
VECTOR_DIR = ROOT / "vectors"


def json_schemas() -> dict[str, str]:
    out = {}
    for model in MESSAGES:
        schema = model.model_json_schema()
        # Each model is one version of its message: its schema_version's one Literal value.
        (version,) = get_args(model.model_fields["schema_version"].annotation)
        schema["$id"] = f"simpletrack/v{version}/{model.__name__}"
        out[f"{model.__name__}.schema.json"] = json.dumps(schema, indent=2, sort_keys=True) + "\n"
    return out


# --- golden vectors ------------------------------------------------------------------------


def _f32(values: Any) -> npt.NDArray[np.float32]:
    return np.array(values, dtype=np.float32)


def _boxes(n: int, velocity: bool = False) -> BoxArrays:
    # Values exactly representable in float32 so the JSON shows them without rounding noise.
    i = np.arange(n, dtype=np.float32)
    return BoxArrays(
        classes=("Car", "Pedestrian"),
        class_index=(np.arange(n) % 2).astype(np.int32),
        center=np.stack([10.0 + i, -2.5 * i + 0.0, 0.75 + 0 * i], axis=1).astype(np.float32),
        size=np.tile(_f32([4.5, 1.75, 1.5]), (n, 1)),
        yaw=(0.25 * i).astype(np.float32),
        score=(0.875 - 0.125 * i).astype(np.float64),
        velocity=np.stack([i, 0.0 - i], axis=1).astype(np.float32) if velocity else None,
    )


_POSE = [0.0, -1.0, 0.0, 100.0, 1.0, 0.0, 0.0, -50.0, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 1.0]
# A rear radar's mounting: turned half a circle, 3.5 m behind the vehicle's origin.
_EXTRINSIC = [-1.0, 0.0, 0.0, -3.5, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.0]
_SCALED = [2.0, 0.0, 0.0, 1.5, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 1.8, 0.0, 0.0, 0.0, 1.0]

_HEADER: dict[str, Any] = {
    "vehicle": "truck-07",
    "sensor": "lidar_top",
    "seq": 42,
    "stamp_ns": 1_700_000_000_100_000_000,
}


def _detections(**over: Any) -> bytes:
    kw: dict[str, Any] = {**_HEADER, "frame_id": "lidar_top", "boxes": _boxes(3)}
    kw.update(over)
    return encode_detection_frame(**kw)


def _raw(mutate: Callable[[dict[str, Any]], None]) -> bytes:
    import msgpack

    obj: dict[str, Any] = msgpack.unpackb(_detections(), raw=False)
    mutate(obj)
    return pack(obj)


def _raw_v2(mutate: Callable[[dict[str, Any]], None]) -> bytes:
    import msgpack

    obj: dict[str, Any] = msgpack.unpackb(_detections(extrinsic=_EXTRINSIC), raw=False)
    mutate(obj)
    return pack(obj)


def _track_arrays() -> TrackArrays:
    n = 2
    return TrackArrays(
        classes=("Car", "Pedestrian", "Cyclist"),
        id=np.array([7, 12], dtype=np.int64),
        class_index=np.array([0, 1], dtype=np.int32),
        center=_f32([[10.0, 0.0, 0.75], [11.0, -2.5, 0.75]]),
        size=_f32([[4.5, 1.75, 1.5], [0.75, 0.5, 1.75]]),
        yaw=_f32([0.0, 0.25]),
        score=np.array([0.875, 0.5]),
        velocity=_f32([[5.0, 0.0, 0.0], [1.0, -1.0, 0.0]]),
        state=np.array([1, 0], dtype=np.int32),
        hits=np.array([12, 1], dtype=np.int32),
        age=np.array([14, 1], dtype=np.int32),
        time_since_update=np.zeros(n, dtype=np.int32),
    )


def _tracks(schema_version: int = 1, covariance: bool = True, epoch: int | None = None) -> bytes:
    tracks = _track_arrays()
    if schema_version >= 2:
        # Powers of two (exact in float32): a confident car, a young pedestrian; the
        # velocity block is wider than the position block, as the filter's is.
        cov = np.zeros((2, 6, 6))
        cov[0] = np.diag([0.25, 0.25, 0.125, 1.0, 1.0, 0.5])
        cov[0, 0, 3] = cov[0, 3, 0] = 0.125
        cov[1] = np.diag([1.0, 1.0, 1.0, 8.0, 8.0, 8.0])
        tracks = replace(
            tracks,
            covariance=covariance_to_upper(cov) if covariance else None,
            age_s=np.array([1.5, 0.0]),
            time_since_update_s=np.array([0.0, 0.0]),
        )
    return encode_track_frame(
        **_HEADER,
        frame_id="lidar_top",
        pose=None,
        key_frame=True,
        instance="simpletrack-a",
        received_ns=1_700_000_000_130_000_000,
        published_ns=1_700_000_000_135_000_000,
        tracks=tracks,
        schema_version=schema_version,
        epoch=epoch,
    )


_STAMP_NS: int = _HEADER["stamp_ns"]
_SENSORS = ["lidar_top", "radar_rear"]


def _vehicle_tracks(empty: bool = False, epoch: int | None = None) -> bytes:
    """A vehicle fusing a lidar and a rear radar, after a lidar frame: the car was last
    updated by both (the radar 50 ms earlier), the young pedestrian by the lidar alone. Empty:
    three sensors in world coordinates, no tracks yet."""
    tracks = replace(
        _track_arrays(),
        covariance=covariance_to_upper(np.stack([np.eye(6) * 0.25, np.eye(6)])),
        age_s=np.array([1.5, 0.0]),
        time_since_update_s=np.array([0.0, 0.0]),
        existence=np.array([0.96875, 0.5]),
        sensor_stamp_ns=np.array([[_STAMP_NS, _STAMP_NS - 50_000_000], [_STAMP_NS, -1]]),
    )
    sensors, states = _SENSORS, [SensorCondition.OK, SensorCondition.PROBATION]
    frame_id, pose = "base_link", None
    if empty:
        none: dict[str, Any] = {c.name: getattr(tracks, c.name)[:0] for c in VEHICLE_TRACK_COLUMNS}
        none.update(covariance=None, sensor_stamp_ns=np.zeros((0, 3), np.int64))
        tracks = replace(tracks, **none)
        sensors = [*_SENSORS, "camera_front"]
        states = [SensorCondition.OK, SensorCondition.SILENT, SensorCondition.UNSEEN]
        frame_id, pose = "world", _POSE
    return encode_vehicle_track_frame(
        vehicle="truck-07",
        seq=1042,
        stamp_ns=_STAMP_NS,
        sensor="lidar_top",
        sensor_seq=42,
        frame_id=frame_id,
        pose=pose,
        instance="simpletrack-a",
        received_ns=1_700_000_000_130_000_000,
        published_ns=1_700_000_000_135_000_000,
        sensors=sensors,
        sensor_state=states,
        tracks=tracks,
        epoch=epoch,
    )


def _raw_vehicle_tracks(
    mutate: Callable[[dict[str, Any]], None], epoch: int | None = None
) -> bytes:
    import msgpack

    obj: dict[str, Any] = msgpack.unpackb(_vehicle_tracks(epoch=epoch), raw=False)
    mutate(obj)
    return pack(obj)


def _raw_tracks(
    schema_version: int, mutate: Callable[[dict[str, Any]], None], epoch: int | None = None
) -> bytes:
    import msgpack

    obj: dict[str, Any] = msgpack.unpackb(_tracks(schema_version, epoch=epoch), raw=False)
    mutate(obj)
    return pack(obj)


def _error(
    reason: ErrorReason = ErrorReason.UNKNOWN_CLASS,
    field: str | None = "boxes.classes.1",
    detail: str = "class 'Tram' is not tracked here; known: Car, Pedestrian, Cyclist",
) -> bytes:
    return encode(
        FrameError(
            schema_version=1,
            vehicle="truck-07",
            sensor="lidar_top",
            seq=42,
            stamp_ns=1_700_000_000_100_000_000,
            reason=reason,
            field=field,
            detail=detail,
            instance="simpletrack-a",
            received_ns=1_700_000_000_130_000_000,
        )
    )


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def mutate(obj: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        for p in parents:
            obj = obj[p]
        if value is _DELETE:
            del obj[last]
        else:
            obj[last] = value

    return mutate


_DELETE = object()
# One track of the basic vehicle frame, two sensors: 24 bytes where 32 belong.
_SHORT_STAMPS = np.array([[_STAMP_NS, -1], [_STAMP_NS, -1]], np.int64).tobytes()[:24]
_NAN_CENTER = _f32([[10.0, 0.0, 0.75], [np.nan, -2.5, 0.75], [12.0, -5.0, 0.75]]).tobytes()
_ZERO_SIZE = _f32([[4.5, 1.75, 1.5], [4.5, 0.0, 1.5], [4.5, 1.75, 1.5]]).tobytes()
# Finite but absurd: the largest float32, the box that used to come back as inf.
_HUGE_CENTER = _f32([[10.0, 0.0, 0.75], [11.0, -2.5, 0.75], [3.4e38, -5.0, 0.75]]).tobytes()

# name -> (message type, payload)
VECTORS: dict[str, tuple[str, Callable[[], bytes]]] = {
    "detection_basic": ("DetectionFrame", _detections),
    "detection_full": (
        "DetectionFrame",
        lambda: _detections(boxes=_boxes(2, velocity=True), pose=_POSE, key_frame=False),
    ),
    "detection_empty": ("DetectionFrame", lambda: _detections(boxes=_boxes(0))),
    "tracks_basic": ("TrackFrame", _tracks),
    "tracks_v2": ("TrackFrame", lambda: _tracks(2)),
    "tracks_v2_no_covariance": ("TrackFrame", lambda: _tracks(2, covariance=False)),
    # Version 2's columns in a frame that says version 1: refused as a version-1 reader would.
    "invalid_tracks_v1_extra_column": (
        "TrackFrame",
        lambda: _raw_tracks(2, _set("schema_version", 1)),
    ),
    "invalid_tracks_v2_missing_age": (
        "TrackFrame",
        lambda: _raw_tracks(2, _set("tracks.age_s", _DELETE)),
    ),
    # Version 4: 3 (this vector's number until TrackFrame version 3) is read now.
    "invalid_tracks_wrong_version": (
        "TrackFrame",
        lambda: _raw_tracks(2, _set("schema_version", 4)),
    ),
    # Version 3: a custody epoch (schemas/README.md, "Custody epoch (fencing)").
    "tracks_epoch": ("TrackFrame", lambda: _tracks(3, epoch=3)),
    # An epoch in a frame that says version 2: refused as a version-2 reader would.
    "invalid_tracks_v2_epoch": (
        "TrackFrame",
        lambda: _raw_tracks(3, _set("schema_version", 2), epoch=3),
    ),
    "invalid_tracks_epoch_out_of_range": (
        "TrackFrame",
        lambda: _raw_tracks(3, _set("epoch", 2**63), epoch=3),
    ),
    "error_unknown_class": ("FrameError", _error),
    "error_sensor_flagged": (
        "FrameError",
        lambda: _error(
            ErrorReason.SENSOR_FLAGGED,
            None,
            "clock: stamps 2.3 s ahead of the vehicle's other sensors; frames kept out",
        ),
    ),
    "detection_extrinsic": (
        "DetectionFrame",
        lambda: _detections(pose=_POSE, session_id=7, extrinsic=_EXTRINSIC),
    ),
    # An extrinsic in a frame that says version 1: refused as a version-1 reader would.
    "invalid_detection_v1_extrinsic": (
        "DetectionFrame",
        lambda: _raw_v2(_set("schema_version", 1)),
    ),
    "invalid_extrinsic_not_rigid": ("DetectionFrame", lambda: _raw_v2(_set("extrinsic", _SCALED))),
    "vehicle_tracks_basic": ("VehicleTrackFrame", _vehicle_tracks),
    "vehicle_tracks_empty": ("VehicleTrackFrame", lambda: _vehicle_tracks(empty=True)),
    "invalid_vehicle_tracks_sensor_stamp_width": (
        "VehicleTrackFrame",
        lambda: _raw_vehicle_tracks(_set("tracks.sensor_stamp_ns", _SHORT_STAMPS)),
    ),
    "invalid_vehicle_tracks_existence": (
        "VehicleTrackFrame",
        lambda: _raw_vehicle_tracks(_set("tracks.existence", np.array([0.5, 1.5]).tobytes())),
    ),
    "invalid_vehicle_tracks_sensor_state": (
        "VehicleTrackFrame",
        lambda: _raw_vehicle_tracks(_set("sensor_state", ["ok"])),
    ),
    # Version 3: 2 (this vector's number until VehicleTrackFrame version 2) is read now.
    "invalid_vehicle_tracks_wrong_version": (
        "VehicleTrackFrame",
        lambda: _raw_vehicle_tracks(_set("schema_version", 3)),
    ),
    # Version 2: a custody epoch, over 2**32 (a reader's integer must be 64 bits wide).
    "vehicle_tracks_epoch": ("VehicleTrackFrame", lambda: _vehicle_tracks(epoch=2**32 + 1)),
    # An epoch in a frame that says version 1: refused as a version-1 reader would.
    "invalid_vehicle_tracks_v1_epoch": (
        "VehicleTrackFrame",
        lambda: _raw_vehicle_tracks(_set("schema_version", 1), epoch=2**32 + 1),
    ),
    # Version 3: 2 (this vector's number until DetectionFrame version 2) is read now.
    "invalid_wrong_version": ("DetectionFrame", lambda: _raw(_set("schema_version", 3))),
    "invalid_missing_field": ("DetectionFrame", lambda: _raw(_set("stamp_ns", _DELETE))),
    "invalid_extra_field": ("DetectionFrame", lambda: _raw(_set("speed", 1.0))),
    "invalid_wrong_type": ("DetectionFrame", lambda: _raw(_set("seq", "42"))),
    "invalid_column_length": ("DetectionFrame", lambda: _raw(_set("boxes.yaw", b"\0" * 8))),
    "invalid_non_finite": ("DetectionFrame", lambda: _raw(_set("boxes.center", _NAN_CENTER))),
    "invalid_non_positive_size": (
        "DetectionFrame",
        lambda: _raw(_set("boxes.size", _ZERO_SIZE)),
    ),
    "invalid_out_of_bounds": (
        "DetectionFrame",
        lambda: _raw(_set("boxes.center", _HUGE_CENTER)),
    ),
    "invalid_class_index": (
        "DetectionFrame",
        lambda: _raw(_set("boxes.class_index", np.array([0, 1, 2], dtype=np.int32).tobytes())),
    ),
    "invalid_malformed": ("DetectionFrame", lambda: _detections()[:-5]),
}


def _array_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def decoded_json(kind: str, payload: bytes) -> dict[str, Any]:
    """What a conforming decoder must produce: fields with columns as (nested) number lists,
    or the rejection (reason and field) for an invalid payload."""
    if kind == "DetectionFrame":
        d = decode_detection_frame(payload)
        if isinstance(d, Rejection):
            return {"message": kind, "valid": False, "reason": d.reason.value, "field": d.field}
        msg = to_map(d.frame)
        msg["boxes"] = {
            "count": len(d.boxes),
            "classes": list(d.boxes.classes),
            **{c.name: _array_json(getattr(d.boxes, c.name)) for c in DETECTION_COLUMNS},
        }
        return {"message": kind, "valid": True, "decoded": msg}
    if kind == "VehicleTrackFrame":
        v = decode_vehicle_track_frame(payload)
        if isinstance(v, Rejection):
            return {"message": kind, "valid": False, "reason": v.reason.value, "field": v.field}
        vehicle_frame, arrays = v
        msg = to_map(vehicle_frame)
        msg["sensor_state"] = [s.value for s in vehicle_frame.sensor_state]
        msg["tracks"] = {
            "count": len(arrays),
            "classes": list(arrays.classes),
            **{c.name: _array_json(getattr(arrays, c.name)) for c in VEHICLE_TRACK_COLUMNS},
        }
        return {"message": kind, "valid": True, "decoded": msg}
    if kind == "TrackFrame":
        t = decode_track_frame(payload)
        if isinstance(t, Rejection):
            return {"message": kind, "valid": False, "reason": t.reason.value, "field": t.field}
        frame, arrays = t
        msg = to_map(frame)
        msg["tracks"] = {
            "count": len(arrays),
            "classes": list(arrays.classes),
            **{
                c.name: _array_json(getattr(arrays, c.name))
                for c in TRACK_COLUMNS_OF[frame.schema_version]
            },
        }
        return {"message": kind, "valid": True, "decoded": msg}
    e = decode_message(payload, DecodedFrameError)
    if isinstance(e, Rejection):
        return {"message": kind, "valid": False, "reason": e.reason.value, "field": e.field}
    return {"message": kind, "valid": True, "decoded": {**to_map(e), "reason": e.reason.value}}


_NUMBER_LIST = re.compile(r"\[[-+0-9.eE,\s]*\]")


def _dumps(obj: Any) -> str:
    """Indented JSON with innermost number lists kept on one line (readable column rows)."""
    text = json.dumps(obj, indent=1)
    return (
        _NUMBER_LIST.sub(lambda m: re.sub(r"\s+", "", m.group(0)).replace(",", ", "), text) + "\n"
    )


# The README's byte-exact examples: one message of each kind, as annotated hex.
EXAMPLES = (
    "detection_basic",
    "tracks_basic",
    "tracks_v2",
    "vehicle_tracks_basic",
    "error_unknown_class",
)
README = ROOT / "README.md"
_EXAMPLES_BEGIN = "<!-- generated:examples (python -m simpletrack.wire.generate) -->"
_EXAMPLES_END = "<!-- end generated:examples -->"


def hex_dump(payload: bytes) -> str:
    """``xxd``-style lines: offset, 16 bytes in hex, the printable ones as text."""
    lines = []
    for off in range(0, len(payload), 16):
        chunk = payload[off : off + 16]
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        lines.append(f"{off:08x}: {chunk.hex(' '):<47}  {text}")
    return "\n".join(lines)


def examples_section(vectors: dict[str, bytes]) -> str:
    parts = [_EXAMPLES_BEGIN]
    for name in EXAMPLES:
        payload = vectors[name]
        parts.append(
            f"`vectors/{name}.msgpack` ({len(payload)} bytes; decoded: `vectors/{name}.json`):\n"
            f"```\n{hex_dump(payload)}\n```"
        )
    parts.append(_EXAMPLES_END)
    return "\n".join(parts)


def readme_with_examples(text: str, vectors: dict[str, bytes]) -> str:
    begin, end = text.find(_EXAMPLES_BEGIN), text.find(_EXAMPLES_END)
    if begin < 0 or end < begin:
        raise ValueError(f"{README} lacks the markers {_EXAMPLES_BEGIN!r} ... {_EXAMPLES_END!r}")
    return text[:begin] + examples_section(vectors) + text[end + len(_EXAMPLES_END) :]


def artefacts() -> dict[Path, bytes]:
    out: dict[Path, bytes] = {JSON_DIR / n: s.encode() for n, s in json_schemas().items()}
    payloads = {}
    for name, (kind, make) in VECTORS.items():
        payload = payloads[name] = make()
        out[VECTOR_DIR / f"{name}.msgpack"] = payload
        text = _dumps(decoded_json(kind, payload))
        out[VECTOR_DIR / f"{name}.json"] = text.encode()
    out[README] = readme_with_examples(README.read_text(), payloads).encode()
    return out


def drift() -> list[str]:
    """Generated files that are missing, stale, or no longer generated."""
    want = artefacts()
    bad = [str(p.relative_to(ROOT)) for p, data in want.items() if not _same(p, data)]
    for d, pattern in ((JSON_DIR, "*.json"), (VECTOR_DIR, "*")):
        bad += [str(p.relative_to(ROOT)) for p in d.glob(pattern) if p not in want]
    return sorted(bad)


def _same(path: Path, data: bytes) -> bool:
    return path.is_file() and path.read_bytes() == data


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m simpletrack.wire.generate", description=__doc__
    )
    parser.add_argument("--check", action="store_true", help="only report drift (exit 1)")
    args = parser.parse_args(argv)
    if args.check:
        bad = drift()
        for p in bad:
            print(f"stale: schemas/{p}", file=sys.stderr)
        if bad:
            print("run: python -m simpletrack.wire.generate", file=sys.stderr)
        return 1 if bad else 0
    JSON_DIR.mkdir(exist_ok=True)
    VECTOR_DIR.mkdir(exist_ok=True)
    for d, pattern in ((JSON_DIR, "*.json"), (VECTOR_DIR, "*")):
        for stale in d.glob(pattern):
            stale.unlink()
    for path, data in artefacts().items():
        path.write_bytes(data)
    print(f"wrote {len(artefacts())} files under {ROOT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
