"""The fleet-unique name of a track, built from what every TrackFrame already carries.

A track id is unique per sensor and never reused, across resets and restarts (the service
keeps a durable id floor per sensor, ``server/registry.py`` ``reserve_ids``), and vehicle and
sensor names are unique in a fleet; so ``<vehicle>/<sensor>/<id>`` names one track of the
whole fleet for good (schemas/README.md, "Track identity").

A vehicle's fused track (VehicleTrackFrame) is named the same way with the vehicle stream in
the sensor's place, ``<vehicle>/@vehicle/<id>`` (``global_id(vehicle, VEHICLE_STREAM, id)``):
its ids are unique per vehicle stream and never reused, and no sensor is named ``@vehicle``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def global_id(vehicle: str, sensor: str, track_id: int) -> str:
    """``<vehicle>/<sensor>/<id>``: '/' cannot occur in either name (NAME_PATTERN); a fused
    track's ``sensor`` is ``keys.VEHICLE_STREAM``."""
    return f"{vehicle}/{sensor}/{int(track_id)}"


def global_ids(vehicle: str, sensor: str, ids: npt.NDArray[np.int64]) -> list[str]:
    head = f"{vehicle}/{sensor}/"
    return [head + str(i) for i in ids.tolist()]


__all__ = ["global_id", "global_ids"]
