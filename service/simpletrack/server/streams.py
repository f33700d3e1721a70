"""What a detection frame belongs to: its sensor's own stream, or its vehicle's fused one.

A stream is the unit of custody: one tracker state, one owner in the group, one worker, one
snapshot, one checkpoint, one hand-off. An unfused sensor is the stream ``<vehicle>/<sensor>``
(as always); the sensors named in ``fusion.sensors`` of a vehicle are together the stream
``<vehicle>/@vehicle`` (docs/SERVICE.md, "Vehicle fusion").

Every member of a group must agree on which streams exist, or one sensor could be owned
twice (as its own stream by one member, inside its vehicle's by another). So fusion is on
only while every member in the view can fuse: each such member holds a second liveliness
token ``<prefix>/@simpletrack/<instance>/fusion``, which members of before fusion never
see (``*`` matches one chunk) and never hold. During a rolling upgrade the fleet is tracked
per sensor until the last old member is gone, then per vehicle.

The worker a frame goes to is the vehicle's for every configured sensor, fused or not, so
that a change of the gate never leaves one vehicle's state on two workers.
"""

from __future__ import annotations

from collections.abc import Callable

from simpletrack.wire.keys import VEHICLE_STREAM, Keys


class Streams:
    def __init__(
        self,
        keys: Keys,
        sensors: frozenset[str],
        vehicles: frozenset[str] = frozenset(),
        gate: Callable[[], bool] = lambda: True,
    ) -> None:
        """``sensors``: the sensor names that fuse; ``vehicles``: the vehicles that do
        (empty: every vehicle); ``gate``: whether the whole group can fuse now."""
        self.keys, self.sensors, self.vehicles, self._gate = keys, sensors, vehicles, gate

    @property
    def enabled(self) -> bool:
        return bool(self.sensors)

    def configured(self, vehicle: str, sensor: str) -> bool:
        """The sensor is one of those its vehicle fuses (whatever the gate says now)."""
        return sensor in self.sensors and (not self.vehicles or vehicle in self.vehicles)

    def fusing(self) -> bool:
        return self.enabled and self._gate()

    def stream(self, vehicle: str, sensor: str) -> str:
        """The stream key a frame of (vehicle, sensor) belongs to now."""
        if self.configured(vehicle, sensor) and self._gate():
            return f"{vehicle}/{VEHICLE_STREAM}"
        return f"{vehicle}/{sensor}"

    def route(self, key: str) -> str:
        """What picks a detection key's worker: the vehicle's key for a configured sensor."""
        names = self.keys.sensor_of(key)
        if names is not None and self.configured(*names):
            return self.keys.detections(names[0], VEHICLE_STREAM)
        return key


def is_vehicle_stream(stream: str) -> bool:
    return stream.endswith(f"/{VEHICLE_STREAM}")


__all__ = ["Streams", "is_vehicle_stream"]
