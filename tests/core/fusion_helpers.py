"""A tiny two-sensor world for the vehicle tracker's tests: a parked vehicle at the origin
with a 360-degree lidar (10 Hz, 50 m) and a front camera (90 degrees, 70 m) mounted 1.5 m
ahead, and cars driving straight past it. Deterministic; noise only where a test asks."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import ClassConfig, OutputPolicy, TrackerConfig
from simpletrack.core.fusion_config import FusionConfig, SensorTrust
from simpletrack.core.vehicle import SensorInput

F64 = npt.NDArray[np.float64]
T0_NS = 1_700_000_000_000_000_000


def mount(x: float, y: float = 0.0, yaw: float = 0.0) -> F64:
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = [x, y]
    return m


LIDAR = mount(0.0)
CAMERA = mount(1.5)


def tracker_config(output: OutputPolicy = OutputPolicy.REFERENCE, **cls: object) -> TrackerConfig:
    base: dict[str, object] = {
        "score_high": 0.5,
        "score_low": 0.1,
        "min_hits": 2,
        "max_age": 3,
        "nms_iou": 0.25,
    }
    base.update(cls)
    c = ClassConfig.model_validate(base)
    return TrackerConfig(classes={"car": c, "pedestrian": c}, output=output)


def fusion(
    camera: SensorTrust | None = None, lidar: SensorTrust | None = None, **options: object
) -> FusionConfig:
    return FusionConfig.model_validate(
        {
            "sensors": {
                "lidar": lidar or SensorTrust(max_range_m=50.0),
                "camera": camera or SensorTrust(fov_deg=90.0, max_range_m=70.0, verify=False),
            },
            **options,
        }
    )


@dataclass
class World:
    """Cars at ``start`` (N, 2) moving at ``velocity`` (N, 2) m/s."""

    start: F64
    velocity: F64
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def at(self, t: float) -> F64:
        return self.start + self.velocity * t

    def frame(
        self,
        sensor: str,
        seq: int,
        t: float,
        *,
        seen: npt.ArrayLike | None = None,
        noise: float = 0.0,
        shift: tuple[float, float] = (0.0, 0.0),
        capture_t: float | None = None,
        lead_s: float | None = None,
        fov_deg: float | None = None,
        max_range: float | None = None,
    ) -> SensorInput:
        """What ``sensor`` detects at ``t`` (every car in its view unless ``seen`` says
        otherwise), stamped ``t``; ``capture_t`` when its clock is off; ``shift`` moves
        every detection (an extrinsic error) in the sensor frame."""
        tf = LIDAR if sensor == "lidar" else CAMERA
        fov = fov_deg if fov_deg is not None else (360.0 if sensor == "lidar" else 90.0)
        rng_max = max_range if max_range is not None else (50.0 if sensor == "lidar" else 70.0)
        xy = self.at(t if capture_t is None else capture_t)
        local = xy - tf[:2, 3]
        r = np.hypot(local[:, 0], local[:, 1])
        bearing = np.abs(np.arctan2(local[:, 1], local[:, 0]))
        view = (r <= rng_max) & (bearing <= math.radians(fov) / 2)
        if seen is not None:
            view &= np.asarray(seen, dtype=bool)
        rows = np.flatnonzero(view)
        p = np.zeros((rows.size, 7))
        p[:, :2] = local[rows] + np.asarray(shift)
        if noise:
            p[:, :2] += self.rng.normal(scale=noise, size=(rows.size, 2))
        p[:, 2] = 0.75
        heading = np.arctan2(self.velocity[rows, 1], self.velocity[rows, 0])
        p[:, 3] = heading
        p[:, 4:7] = [4.5, 1.9, 1.5]
        boxes = Boxes(params=p, score=np.full(rows.size, 0.9), cls=np.zeros(rows.size, np.int32))
        return SensorInput(sensor, seq, T0_NS + round(t * 1e9), boxes, transform=tf, lead_s=lead_s)


def crossing(n: int = 6, seed: int = 0) -> World:
    """Cars on lanes ahead and behind, some inside both views, some only the lidar's, one
    far ahead only the camera's."""
    rng = np.random.default_rng(seed)
    start = np.array(
        [[12.0, -20.0], [25.0, 15.0], [-20.0, -8.0], [-10.0, 30.0], [62.0, -4.0], [35.0, 30.0]]
    )[:n]
    velocity = np.array(
        [[0.0, 6.0], [0.0, -5.0], [3.0, 0.0], [0.0, -4.0], [-1.0, 0.0], [0.0, -6.0]]
    )[:n]
    return World(start, velocity, rng)


def schedule(
    seconds: float, lidar_hz: float = 10.0, camera_hz: float = 15.0
) -> list[tuple[str, int, float]]:
    """(sensor, seq, t) of both sensors' frames in stamp order (lidar first on ties)."""
    out = [("lidar", k, k / lidar_hz) for k in range(int(seconds * lidar_hz))]
    out += [("camera", k, k / camera_hz) for k in range(int(seconds * camera_hz))]
    return sorted(out, key=lambda f: (f[2], f[0] != "lidar"))
