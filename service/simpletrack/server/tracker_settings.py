"""The service's tracker settings: a preset from the core's registry, top-level tracker options
over it, per-class changes over its classes. ``resolve_tracker_config`` turns them into the
validated ``TrackerConfig`` when the settings load, so settings that load always make a tracker.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from simpletrack.core.config import (
    PRESETS,
    ClassConfig,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    VerticalOverlap,
    known_preset,
    preset,
)
from simpletrack.server.messages import format_error


@dataclass(frozen=True)
class OneOf:
    """Annotation metadata: the values a ``str`` setting accepts, for the docs table."""

    values: tuple[str, ...]


PresetName = Annotated[str, AfterValidator(known_preset), OneOf(tuple(PRESETS))]


class _Unset(BaseModel):
    """Options over a preset: one left out (None) keeps the preset's value. Bounds are checked
    once, by ``TrackerConfig``, when the options are applied."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class KalmanOptions(_Unset):
    p0_measured: float | None = Field(
        default=None, description="initial variance of the measured states (x y z yaw l w h)"
    )
    p0_velocity: float | None = Field(
        default=None, description="initial variance of the velocity states"
    )
    q: float | None = Field(default=None, description="process noise: Q = q I")
    r: float | None = Field(default=None, description="measurement noise: R = r I")


class NonKeyOptions(_Unset):
    score_high: float | None = Field(
        default=None, description="stage-1 score threshold (>=) on frames flagged non-key"
    )
    score_low: float | None = Field(
        default=None, description="stage-2 score threshold (>) on frames flagged non-key"
    )


class TrackerOptions(_Unset):
    """Every top-level ``TrackerConfig`` option but ``classes`` (tests/server/test_settings.py
    fails when the core gains one that is not here)."""

    motion: MotionModel | None = Field(
        default=None, description="kalman, or constant_velocity from the detections' velocities"
    )
    kalman: KalmanOptions = Field(default_factory=KalmanOptions)
    output: OutputPolicy | None = Field(
        default=None,
        description="which live tracks a frame reports: paper (confirmed and matched), "
        "reference (also tentative), nuscenes (every live track)",
    )
    vertical_overlap: VerticalOverlap | None = Field(
        default=None, description="3D overlap height: exact, or reference (parity runs only)"
    )
    tie_order: TieOrder | None = Field(
        default=None,
        description="order of equal-score boxes in NMS: stable, or reference (parity runs only)",
    )
    coast_score_decay: float | None = Field(
        default=None, description="a coasting track's score is multiplied by this each frame"
    )
    non_key: NonKeyOptions = Field(default_factory=NonKeyOptions)


def _merge(base: dict[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in changes.items():
        out[key] = _merge(out[key], value) if isinstance(value, Mapping) else value
    return out


def resolve_tracker_config(
    preset_name: str,
    options: TrackerOptions,
    class_changes: Mapping[str, Any],
    source: str,
) -> TrackerConfig:
    """The preset with ``options`` and the per-class ``class_changes`` (read from ``source``)
    applied. ValueError names the option, or the source, class and value."""
    config = preset(preset_name)
    try:
        config = TrackerConfig.model_validate(
            _merge(config.model_dump(), options.model_dump(exclude_none=True))
        )
    except ValidationError as e:
        raise ValueError(format_error(e, "tracker.")) from None
    classes: dict[str, ClassConfig] = dict(config.classes)
    for name, changes in class_changes.items():
        if name not in classes:
            raise ValueError(
                f"{source}: class {name!r} is not in preset {preset_name!r} ({', '.join(classes)})"
            )
        if not isinstance(changes, Mapping):
            raise ValueError(f"{source}: {name} must be a table of fields (got {changes!r})")
        try:
            classes[name] = ClassConfig.model_validate({**classes[name].model_dump(), **changes})
        except ValidationError as e:
            raise ValueError(f"{source}: {name}: {format_error(e)}") from None
    return config.with_overrides(classes=classes)
