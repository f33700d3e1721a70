"""What a planner reads from a vehicle's fused message (``VehicleTrackMessage``), on the
golden vector: the stream's name and ids, the frame it answers, existence and contributors,
and the columns as a sensor's message gives them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simpletrack.client.subscriber import VehicleTrackMessage
from simpletrack.wire import Rejection, decode_vehicle_track_frame
from simpletrack.wire.reasons import SensorCondition

VECTOR = Path(__file__).parents[2] / "schemas" / "vectors" / "vehicle_tracks_basic.msgpack"


def test_a_fused_message_names_its_stream_its_source_and_each_tracks_sensors() -> None:
    decoded = decode_vehicle_track_frame(VECTOR.read_bytes())
    assert not isinstance(decoded, Rejection), decoded
    msg = VehicleTrackMessage("fleet/truck-07/@vehicle/tracks", *decoded, received_ns=0)
    assert (msg.vehicle, msg.sensor, msg.seq, msg.source) == (
        "truck-07",
        "@vehicle",
        1042,
        ("lidar_top", 42),
    )
    assert msg.global_ids == ["truck-07/@vehicle/7", "truck-07/@vehicle/12"]
    assert msg.global_id(1) == "truck-07/@vehicle/12"
    assert msg.class_names() == ["Car", "Pedestrian"]
    assert msg.ids(("Pedestrian",)).tolist() == [12]
    assert msg.sensor_state == {
        "lidar_top": SensorCondition.OK,
        "radar_rear": SensorCondition.PROBATION,
    }
    np.testing.assert_array_equal(msg.existence, [0.96875, 0.5])
    stamp = msg.stamp_ns
    assert msg.contributors(0) == {"lidar_top": stamp, "radar_rear": stamp - 50_000_000}
    assert msg.contributors(1) == {"lidar_top": stamp}
    assert msg.latency_s == -stamp * 1e-9
