"""The tracker settings the demo's service runs with: preset ``wod`` with per-class changes.

Chosen by ``python -m simpletrack.sim.sweep --seed 1`` (the core tracker on the simulated
fleet of seed 1, the candidate that scored the best MOTA); the demo reports seed 0 (its
default ``--seed``), a world the choice never saw. The simulator was not changed after the
sweep. Raising ``max_age`` lets a track coast through the detector's miss bursts (0.4 s on
average, see ``DetectorModel``) instead of ending and restarting under a new id, and
``coast_output`` reports a track for up to two predicted frames of such a burst. Sweep on seed
1, 200 frames (MOTA / IDS): wod as is 0.559 / 1169; max_age 4, coast_output 2, min_hits 2:
0.743 / 611 (the best); max_age 6, coast_output 2: 0.742 / 428.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import yaml

from simpletrack.core.config import ClassConfig, TrackerConfig, preset
from simpletrack.sim.simulator import SimConfig

DEMO_PRESET = "wod"  # the simulator's classes: vehicle, pedestrian, cyclist
SWEEP_SEED = 1  # the seed the settings were chosen on; the demo's default seed is 0

# Per class: the ClassConfig fields changed over the preset's (the sweep's winner).
DEMO_CLASS_CHANGES: dict[str, dict[str, int]] = {
    name: {"max_age": 4, "coast_output": 2, "min_hits": 2}
    for name in ("vehicle", "pedestrian", "cyclist")
}


def with_changes(changes: dict[str, dict[str, int]]) -> TrackerConfig:
    """Preset ``wod`` with ``changes`` applied to its classes."""
    config = preset(DEMO_PRESET)
    classes: dict[str, ClassConfig] = dict(config.classes)
    for name, fields in changes.items():
        classes[name] = ClassConfig.model_validate({**classes[name].model_dump(), **fields})
    return config.with_overrides(classes=classes)


def demo_tracker_config() -> TrackerConfig:
    return with_changes(DEMO_CLASS_CHANGES)


def write_class_overrides() -> Path:
    """A temporary TOML file of ``DEMO_CLASS_CHANGES`` for ``serve --class-overrides``; the
    caller removes it."""
    lines: list[str] = []
    for name, fields in DEMO_CLASS_CHANGES.items():
        lines.append(f"[{name}]")
        lines.extend(f"{key} = {value}" for key, value in fields.items())
    with tempfile.NamedTemporaryFile(
        "w", prefix="simpletrack-demo-", suffix=".toml", delete=False
    ) as f:
        f.write("\n".join(lines) + "\n")
    return Path(f.name)


# The fused vehicle's own settings (the per-sensor trackers keep DEMO_CLASS_CHANGES), chosen
# by ``python -m simpletrack.sim.sweep --seed 1 --fusion --jobs 2`` (sweep.fusion_candidate,
# sweep.PLANNER_LIMITS); the demo reports seed 0. The winner on seed 1 (54 candidates, 200
# lidar frames): MOTA 0.683, 1.26 ids per object against 4.20 for the per-sensor tracks taken
# together, 0.47 % of matched boxes doubled. The best MOTA outside the limits, 0.706, started
# tracks from the camera too: 1.41 ids per object, 2.1 % doubled.
DEMO_FUSION: dict[str, object] = {
    "max_age": 24,
    "camera_spawn": False,
    "lidar_gate": "l2_3.0",
    "camera_gate": "l2_2.5",
    "camera_r": 16.0,
    "spawn_clearance_m": 5.0,
    "min_existence": 0.65,
    "occlusion": 0.0,
}


def demo_fusion(sim: SimConfig) -> dict[str, Any]:
    """The service's ``fusion`` settings for the simulated fleet: its sensors' views and
    DEMO_FUSION; each sensor's own tracks published too (the demo scores both)."""
    from simpletrack.sim.fusion_offline import fusion_config
    from simpletrack.sim.sweep import fusion_candidate

    trust, options = fusion_candidate(**DEMO_FUSION)  # type: ignore[arg-type]
    fusion = fusion_config(sim, trust, **options).model_dump(mode="json")
    return {**fusion, "per_sensor_output": True}


def write_service_config(sim: SimConfig) -> Path:
    """A temporary YAML file for ``serve --config``: the demo's fusion settings and the
    per-class changes (the caller removes it)."""
    data = {"fusion": demo_fusion(sim)}
    with tempfile.NamedTemporaryFile(
        "w", prefix="simpletrack-demo-", suffix=".yaml", delete=False
    ) as f:
        yaml.safe_dump(data, f, sort_keys=False)
    return Path(f.name)
