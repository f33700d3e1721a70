"""How a vehicle's sensors are fused into one tracker: per-sensor trust and the vehicle's
timing rules. Typed, validated, frozen; the names and meanings are docs/SERVICE.md's
("Vehicle fusion").
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

Probability = Annotated[float, Field(ge=0.0, le=1.0)]
# Where the existence probability is clamped: one miss or one hit can always move it.
EXISTENCE_FLOOR = 1e-3


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


class SensorTrust(_Frozen):
    """What the vehicle's tracker takes from one sensor (Autoware's input-channel flags,
    per sensor here)."""

    spawn: bool = Field(
        True, description="may start tracks (false: only updates tracks others started)"
    )
    spawn_classes: tuple[str, ...] | None = Field(
        None, description="classes it may start (None: every class, when spawn is true)"
    )
    spawn_clearance_m: Annotated[float, Field(ge=0.0)] = Field(
        0.0,
        description="it starts no track within this distance (BEV, metres) of a track of the "
        "same class that its frame did not update: a noisy sensor's second box of an object "
        "is not a second object (0: off)",
    )
    existence: bool = Field(
        True,
        description="its scores count as evidence toward a track's existence probability "
        "(false: a detection counts as the fixed evidence hit_probability)",
    )
    hit_probability: Probability = Field(
        0.7,
        description="without trusted scores: how likely a detection of this sensor is a real "
        "object (the evidence of one update)",
    )
    detection_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = Field(
        0.8,
        description="how likely this sensor detects a real object in its view: a miss "
        "counts as evidence against existence by log(1 - this)",
    )
    min_score: Probability | dict[str, Probability] = Field(
        0.0, description="boxes scoring below this (per class if a map) are dropped first"
    )
    r: Annotated[float, Field(gt=0.0)] | None = Field(
        None,
        description="measurement noise of its updates, R = r I (None: the tracker's "
        "kalman.r): a noisier sensor moves a track less",
    )
    fov_deg: Annotated[float, Field(gt=0.0, le=360.0)] = Field(
        360.0, description="horizontal field of view, centred on the sensor's +x axis"
    )
    min_range_m: Annotated[float, Field(ge=0.0)] = 0.0
    max_range_m: Annotated[float, Field(gt=0.0)] = math.inf
    classes: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="per class, ClassConfig fields this sensor's frames use instead of the "
        "tracker's (e.g. a camera's wider gate: {metric: l2, max_distance: 3.0})",
    )
    verify: bool | None = Field(
        None,
        description="hold its frames out of the tracks until its detections agree with "
        "the tracks of the vehicle's trusted sensors (None: every sensor but the first "
        "listed, the vehicle's reference)",
    )

    @model_validator(mode="after")
    def _ranges(self) -> SensorTrust:
        if self.min_range_m >= self.max_range_m:
            raise ValueError(
                f"min_range_m ({self.min_range_m}) must be below max_range_m ({self.max_range_m})"
            )
        return self

    def min_score_of(self, classes: tuple[str, ...]) -> tuple[float, ...]:
        """The minimum score of each class code."""
        if isinstance(self.min_score, float | int):
            return tuple(float(self.min_score) for _ in classes)
        return tuple(float(self.min_score.get(name, 0.0)) for name in classes)


class FusionConfig(_Frozen):
    """A fused vehicle: its sensors (in this order in every message) and its timing rules."""

    sensors: dict[str, SensorTrust] = Field(min_length=1, max_length=64)
    window_s: Annotated[float, Field(ge=0.0, le=10.0)] = Field(
        0.3,
        description="a frame waits at most this long for the vehicle's other live sensors "
        "to pass its stamp; frames then go to the tracker in stamp order",
    )
    silent_after_s: Annotated[float, Field(gt=0.0)] = Field(
        1.0,
        description="a sensor silent this long is not waited for (and is reported silent)",
    )
    history_s: Annotated[float, Field(ge=0.0, le=60.0)] = Field(
        1.0,
        description="a frame older than the last applied one is re-processed from the "
        "stored states when within this much of it; older ones are refused (late)",
    )
    clock_tolerance_s: Annotated[float, Field(gt=0.0)] = Field(
        0.1,
        description="a sensor's clock offset beyond this flags it (0.1 s is 2 m at 20 m/s)",
    )
    extrinsic_tolerance_m: Annotated[float, Field(gt=0.0)] = Field(
        1.0,
        description="a sensor whose detections sit further than this from the tracks "
        "of the vehicle's other sensors, all shifted alike, is flagged",
    )
    fov_margin_m: Annotated[float, Field(ge=0.0)] = Field(
        1.5, description="tracks this close outside a sensor's view still count as in it"
    )
    verify_frames: Annotated[int, Field(ge=1, le=1000)] = Field(
        3, description="frames of agreement a sensor under verification needs"
    )
    occlusion: Probability = Field(
        0.0,
        description="a track hidden behind nearer tracks, seen from a sensor, by more than "
        "this share of its outline is not missed by that sensor's frame (0: off; the sensors "
        "are line of sight)",
    )
    occluded_max_frames: Annotated[int, Field(ge=0, le=10_000)] = Field(
        30, description="frames a track may go unmissed for being hidden, then it ages again"
    )
    min_existence: Probability = Field(
        0.0,
        description="a tentative track is reported only once its existence probability is "
        "this high (a confirmed one as the output policy says)",
    )

    @model_validator(mode="after")
    def _names(self) -> FusionConfig:
        for name in self.sensors:
            if not name or name.startswith("@"):
                raise ValueError(f"sensor name {name!r} must be a sensor's name")
        return self

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.sensors)

    def verifies(self, sensor: str) -> bool:
        trust = self.sensors[sensor]
        if trust.verify is not None:
            return trust.verify
        return sensor != self.names[0]


__all__ = ["EXISTENCE_FLOOR", "FusionConfig", "SensorTrust"]
