"""A fused vehicle for the real-process tests: the parked vehicle and cars of
``tests/core/fusion_helpers`` (a 10 Hz lidar, a 15 Hz front camera mounted 1.5 m ahead),
its frames as the wire carries them (with their sensor->vehicle extrinsics), a service
configured to fuse them, and the tracks the core gives on the same frames in stamp order:
what the service must publish."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from simpletrack.core.fusion_config import FusionConfig
from simpletrack.core.vehicle import SensorInput, VehicleTracker, VehicleTracks
from simpletrack.server.settings import load_settings
from simpletrack.wire import BoxArrays, TrackArrays
from simpletrack.wire.codec import encode_detection_frame
from simpletrack.wire.convert import boxes_from_wire, boxes_to_wire, vehicle_tracks_to_wire
from tests.core.fusion_helpers import CAMERA, LIDAR, World, crossing, schedule

CLASSES = ("Car", "Pedestrian", "Cyclist")
VEHICLE = "veh01"
CONFIG = """\
[fusion]
window_s = {window_s}
history_s = {history_s}
silent_after_s = {silent_after_s}

[fusion.sensors.lidar]
max_range_m = 50.0

[fusion.sensors.camera]
fov_deg = 90.0
max_range_m = 70.0
verify = {verify}
"""


def write_config(
    tmp: Path,
    window_s: float = 0.3,
    history_s: float = 1.0,
    silent_after_s: float = 1.0,
    verify: bool = False,
) -> Path:
    path = tmp / "fusion.toml"
    path.write_text(
        CONFIG.format(
            window_s=window_s,
            history_s=history_s,
            silent_after_s=silent_after_s,
            verify=str(verify).lower(),
        )
    )
    return path


@dataclass(frozen=True)
class WireFrame:
    sensor: str
    seq: int
    stamp_ns: int
    boxes: BoxArrays
    extrinsic: np.ndarray

    def payload(self, vehicle: str = VEHICLE, **changes: object) -> bytes:
        f = replace(self, **changes)  # type: ignore[arg-type]
        return encode_detection_frame(
            vehicle=vehicle,
            sensor=f.sensor,
            seq=f.seq,
            stamp_ns=f.stamp_ns,
            frame_id=f.sensor,
            boxes=f.boxes,
            extrinsic=f.extrinsic,
        )


def frames(
    seconds: float, t0_ns: int, world: World | None = None, **frame: object
) -> list[WireFrame]:
    """Both sensors' frames in stamp order (lidar first on ties), stamped from ``t0_ns``;
    ``frame`` options (``shift``, ``capture_t``) go to the camera's frames."""
    w = world or crossing()
    config = load_settings(None, {}).tracker_config()
    out = []
    for sensor, seq, t in schedule(seconds):
        options = frame if sensor == "camera" else {}
        inp = w.frame(sensor, seq, t, **options)  # type: ignore[arg-type]
        boxes = boxes_to_wire(inp.boxes, config.class_names)
        out.append(
            WireFrame(
                sensor,
                seq,
                t0_ns + round(t * 1e9),
                boxes,
                LIDAR if sensor == "lidar" else CAMERA,
            )
        )
    return out


def expected(
    wire: list[WireFrame], fusion: FusionConfig, skip: str | None = None
) -> list[TrackArrays]:
    """The core's fused tracks on these frames in stamp order (as the service decodes them:
    float32 columns), as wire columns; ``skip``: a sensor whose frames are left out."""
    config = load_settings(None, {}).tracker_config()
    v = VehicleTracker(config, fusion)
    out = []
    for f in sorted(wire, key=lambda f: (f.stamp_ns, f.sensor != "lidar")):
        if f.sensor == skip:
            continue
        boxes = boxes_from_wire(f.boxes)
        r = v.apply(SensorInput(f.sensor, f.seq, f.stamp_ns, boxes, f.extrinsic))
        if r.tracks is not None:
            out.append(_wire(r.tracks, config.class_names))
    return out


def _wire(t: VehicleTracks, classes: tuple[str, ...]) -> TrackArrays:
    return vehicle_tracks_to_wire(t.tracks, t.existence, t.sensor_stamp_ns, classes)


def fusion_of(config_path: Path) -> FusionConfig:
    settings = load_settings(config_path, {})
    fusion = settings.fusion.config()
    assert fusion is not None
    return fusion


def same_tracks(got: TrackArrays, want: TrackArrays) -> None:
    for name in ("id", "class_index", "center", "size", "yaw", "score", "state", "hits"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
