"""Clients of the SimpleTrack service: the vehicle-side publisher, the planner-side subscriber,
the simulated fleet, and the tools behind ``simpletrack demo|replay|record|watch|plot``.

    from clients import DetectionPublisher, TrackSubscriber, ZenohOptions

Names are imported on first use, so ``import clients.kitti_io`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "Box": "clients.publisher",
    "DetectionPublisher": "clients.publisher",
    "TrackMessage": "clients.subscriber",
    "TrackSubscriber": "clients.subscriber",
    "ZenohOptions": "service.zenoh_config",
    "FleetSimulator": "clients.simulator",
    "SimConfig": "clients.simulator",
    "MotScorer": "clients.mot_scorer",
}

if TYPE_CHECKING:
    from clients.mot_scorer import MotScorer
    from clients.publisher import Box, DetectionPublisher
    from clients.simulator import FleetSimulator, SimConfig
    from clients.subscriber import TrackMessage, TrackSubscriber
    from service.zenoh_config import ZenohOptions

__all__ = [
    "Box",
    "DetectionPublisher",
    "FleetSimulator",
    "MotScorer",
    "SimConfig",
    "TrackMessage",
    "TrackSubscriber",
    "ZenohOptions",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'clients' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
