"""Where a fused vehicle's DetectedObjects are, and what the bridge sends with them.

The service fuses a vehicle's sensors in one frame (docs/SERVICE.md, "Vehicle fusion", 3):
every fused frame carries its sensor->vehicle ``extrinsic`` (the vehicle is tracked in the
vehicle frame) or its sensor->world ``pose`` (tracked in the world frame), never a mix. A
DetectedObjects says only the name of its frame (``header.frame_id``); the bridge has no tf,
so it is told the transforms, like static transforms, and looks each message's frame up:

    vehicle mode (the default)
        ``vehicle_frame`` (``--vehicle-frame``, default ``base_link``): the objects are in the
        vehicle frame already; sent with the identity extrinsic.
        a frame named in ``extrinsics`` (``--extrinsic FRAME=16 numbers``, the frame->vehicle
        transform, 4x4 row-major): sent with that extrinsic; the service moves the boxes.
    world mode (``world_frame``, ``--world-frame map``)
        the objects are in that world-fixed frame; sent with the identity pose. Only that
        frame: the service refuses a vehicle whose frames mix poses and extrinsics.

A message in any other frame is refused by the bridge (``unknown_frame``), never sent as if
it were in the vehicle frame. The fused tracks come back in the frame every box was put in:
the TrackedObjects' ``header.frame_id`` is ``output_frame`` (the vehicle or world frame).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

from simpletrack.client.publisher import check_extrinsic

IDENTITY: tuple[float, ...] = tuple(float(i == j) for i in range(4) for j in range(4))
DEFAULT_VEHICLE_FRAME = "base_link"


class FrameMode(StrEnum):
    VEHICLE = "vehicle"  # extrinsics: the service tracks in the vehicle frame
    WORLD = "world"  # poses: the service tracks in the world frame


@dataclass(frozen=True, slots=True)
class Placement:
    """What goes with a message's boxes: exactly one of the two is set."""

    extrinsic: tuple[float, ...] | None = None  # sensor->vehicle, 4x4 row-major
    pose: tuple[float, ...] | None = None  # sensor->world, 4x4 row-major


@dataclass(frozen=True, slots=True)
class FrameTable:
    vehicle_frame: str = DEFAULT_VEHICLE_FRAME
    extrinsics: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    world_frame: str | None = None

    def __post_init__(self) -> None:
        if not self.vehicle_frame:
            raise ValueError("the vehicle frame needs a name")
        if self.world_frame is not None:
            if not self.world_frame:
                raise ValueError("the world frame needs a name")
            if self.extrinsics:
                raise ValueError(
                    "--world-frame and --extrinsic exclude each other: the service tracks a "
                    "vehicle in the world frame (poses) or in the vehicle frame (extrinsics), "
                    "never both"
                )
        for frame, matrix in self.extrinsics.items():
            if not frame:
                raise ValueError("an extrinsic needs the name of its frame")
            if frame == self.vehicle_frame:
                raise ValueError(
                    f"{frame!r} is the vehicle frame (its extrinsic is the identity): "
                    "give --vehicle-frame another name or leave this extrinsic out"
                )
            check_extrinsic(list(matrix))

    @property
    def mode(self) -> FrameMode:
        return FrameMode.VEHICLE if self.world_frame is None else FrameMode.WORLD

    @property
    def output_frame(self) -> str:
        """The frame the fused tracks are in: the one every box was sent into."""
        return self.world_frame if self.world_frame is not None else self.vehicle_frame

    def place(self, frame_id: str) -> Placement | None:
        """What to send with a message in ``frame_id``; None: a frame the bridge has no
        transform for."""
        if self.world_frame is not None:
            return Placement(pose=IDENTITY) if frame_id == self.world_frame else None
        if frame_id == self.vehicle_frame:
            return Placement(extrinsic=IDENTITY)
        matrix = self.extrinsics.get(frame_id)
        return None if matrix is None else Placement(extrinsic=matrix)

    def describe(self) -> str:
        """The frames it takes, for the log and refusals."""
        if self.world_frame is not None:
            return f"{self.world_frame} (world, identity pose)"
        named = [f"{self.vehicle_frame} (vehicle frame)"]
        named += [f"{f} (extrinsic)" for f in sorted(self.extrinsics)]
        return ", ".join(named)


def parse_extrinsic(spec: str) -> tuple[str, tuple[float, ...]]:
    """``FRAME=m00,m01,...,m33``: a frame and its frame->vehicle transform (16 numbers,
    row-major, rigid: docs/VEHICLES.md, "Fused sensors: the extrinsic")."""
    frame, sep, numbers = spec.partition("=")
    frame = frame.strip()
    if not sep or not frame:
        raise ValueError(
            f"--extrinsic {spec!r} must be FRAME=16 numbers (row-major 4x4 frame->vehicle)"
        )
    try:
        values = tuple(float(v) for v in numbers.replace(" ", ",").split(",") if v)
    except ValueError:
        raise ValueError(f"--extrinsic {spec!r}: not a list of numbers") from None
    if len(values) != 16 or not all(math.isfinite(v) for v in values):
        raise ValueError(
            f"--extrinsic {spec!r}: {len(values)} numbers, a 4x4 transform has 16 (finite)"
        )
    try:
        check_extrinsic(list(values))
    except ValueError as e:
        raise ValueError(f"--extrinsic {frame}: {e}") from None
    return frame, values
