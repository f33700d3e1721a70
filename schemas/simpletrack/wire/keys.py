"""Zenoh key expressions of the service (documented in docs/SERVICE.md).

Per sensor, under a configurable prefix (default ``fleet``):
    <prefix>/<vehicle>/<sensor>/detections   in:  DetectionFrame
    <prefix>/<vehicle>/<sensor>/tracks       out: TrackFrame
    <prefix>/<vehicle>/<sensor>/errors       out: FrameError
Per fused vehicle (its sensors feed one tracker):
    <prefix>/<vehicle>/@vehicle/tracks       out: VehicleTrackFrame
``@vehicle`` is a verbatim chunk: ``*`` never matches it, so a ``<prefix>/*/*/tracks``
subscriber (of sensor TrackFrames) never receives a vehicle's frames, and no sensor can be
named so (NAME_PATTERN refuses '@').
Per service instance (``@`` chunks never match ``*``, so fleet wildcards cannot hit them):
    <prefix>/@simpletrack/<instance>                               liveliness token
    <prefix>/@simpletrack/<instance>/status                        queryable: ServiceStatus
    <prefix>/@simpletrack/<instance>/snapshot/<vehicle>/<sensor>   queryable: SensorSnapshot
Between the instances of a group (docs/SCALE.md):
    <prefix>/@simpletrack/<instance>/handoff/<vehicle>/<sensor>    queryable: the holder
                                                                   releases it, SensorSnapshot
    <prefix>/@simpletrack/<standby>/checkpoint/<vehicle>/<sensor>  owner -> standby: SensorSnapshot
    <prefix>/@simpletrack/<scout>/plain/<vehicle>/<sensor>         liveliness token: a sensor
                                                                   published by plain puts;
                                                                   queryable: its frames heard
"""

from __future__ import annotations

from dataclasses import dataclass

SERVICE_CHUNK = "@simpletrack"
# The stream chunk of a vehicle's fused tracks, where a sensor's name would be; also the
# sensor name its state is checkpointed and handed off under (SensorSnapshot.sensor).
VEHICLE_STREAM = "@vehicle"
DETECTIONS, TRACKS, ERRORS = "detections", "tracks", "errors"


@dataclass(frozen=True, slots=True)
class Keys:
    prefix: str = "fleet"

    @property
    def all_detections(self) -> str:
        return f"{self.prefix}/*/*/{DETECTIONS}"

    def detections(self, vehicle: str, sensor: str) -> str:
        return f"{self.prefix}/{vehicle}/{sensor}/{DETECTIONS}"

    def tracks(self, vehicle: str, sensor: str) -> str:
        return f"{self.prefix}/{vehicle}/{sensor}/{TRACKS}"

    def errors(self, vehicle: str, sensor: str) -> str:
        return f"{self.prefix}/{vehicle}/{sensor}/{ERRORS}"

    def liveliness(self, instance: str = "*") -> str:
        return f"{self.prefix}/{SERVICE_CHUNK}/{instance}"

    def fusion_token(self, instance: str = "*") -> str:
        """The liveliness token of a member that can fuse vehicles (server/streams.py)."""
        return f"{self.prefix}/{SERVICE_CHUNK}/{instance}/fusion"

    def status(self, instance: str = "*") -> str:
        return f"{self.prefix}/{SERVICE_CHUNK}/{instance}/status"

    def snapshot(self, instance: str = "*", vehicle: str = "*", sensor: str = "*") -> str:
        return f"{self.prefix}/{SERVICE_CHUNK}/{instance}/snapshot/{vehicle}/{sensor}"

    @property
    def all_tracks(self) -> str:
        return f"{self.prefix}/*/*/{TRACKS}"

    def vehicle_tracks(self, vehicle: str) -> str:
        return f"{self.prefix}/{vehicle}/{VEHICLE_STREAM}/{TRACKS}"

    @property
    def all_vehicle_tracks(self) -> str:
        return f"{self.prefix}/*/{VEHICLE_STREAM}/{TRACKS}"

    def handoff(self, instance: str = "*", vehicle: str = "*", sensor: str = "*") -> str:
        return f"{self.prefix}/{SERVICE_CHUNK}/{instance}/handoff/{vehicle}/{sensor}"

    def told(self, standby: str) -> str:
        """What owners tell ``standby`` of the tracks they published (server/told.py)."""
        return f"{self.prefix}/{SERVICE_CHUNK}/{standby}/told"

    def checkpoint(self, standby: str, vehicle: str = "*", sensor: str = "*") -> str:
        return f"{self.prefix}/{SERVICE_CHUNK}/{standby}/checkpoint/{vehicle}/{sensor}"

    def plain(self, scout: str = "*", vehicle: str = "*", sensor: str = "*") -> str:
        """A sensor the group's scout heard from a publisher without an advanced publisher's
        token (docs/SCALE.md, "Plain publishers"): its token, and its frames' queryable."""
        return f"{self.prefix}/{SERVICE_CHUNK}/{scout}/plain/{vehicle}/{sensor}"

    def service_sensor_of(self, key: str) -> tuple[str, str] | None:
        """(vehicle, sensor) of a ``<prefix>/@simpletrack/<instance>/<kind>/<v>/<s>`` key."""
        head = f"{self.prefix}/{SERVICE_CHUNK}/"
        if not key.startswith(head):
            return None
        parts = key[len(head) :].split("/")
        if len(parts) != 4:
            return None
        return parts[2], parts[3]

    def sensor_of(self, key: str) -> tuple[str, str] | None:
        """(vehicle, sensor) of a ``.../<vehicle>/<sensor>/<leaf>`` key under this prefix; a
        vehicle's fused stream gives ``(vehicle, VEHICLE_STREAM)``, ``("veh01", "@vehicle")``."""
        head = self.prefix + "/"
        if not key.startswith(head):
            return None
        parts = key[len(head) :].split("/")
        if len(parts) != 3:
            return None
        return parts[0], parts[1]
