"""The vehicle and planner client library: publish detection frames, subscribe to tracks.

    from simpletrack.client import DetectionPublisher, TrackSubscriber, ZenohOptions

This package and what it imports (``simpletrack.wire``, ``simpletrack.session``) need only
zenoh, msgpack and numpy: the light install (``pip install simpletrack``).
"""

from simpletrack.client.publisher import Box, DetectionPublisher, Undelivered
from simpletrack.client.subscriber import (
    TrackMessage,
    TrackSubscriber,
    VehicleTrackMessage,
    VehicleTrackSubscriber,
)
from simpletrack.session import ZenohOptions

__all__ = [
    "Box",
    "DetectionPublisher",
    "TrackMessage",
    "TrackSubscriber",
    "Undelivered",
    "VehicleTrackMessage",
    "VehicleTrackSubscriber",
    "ZenohOptions",
]
