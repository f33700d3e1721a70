"""A planner's ``TrackSubscriber`` delivers each frame once: the same sensor, seq and stamp
sent twice (two members of a group racing at a takeover) is counted, not delivered again;
the same seq with a new stamp (a rebooted vehicle starting at seq 0 again) is delivered."""

from __future__ import annotations

import time

import numpy as np

from simpletrack.client import TrackSubscriber
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import TrackArrays
from simpletrack.wire.codec import encode_track_frame
from tests.service_helpers import wait_for


def track_frame(seq: int, stamp_ns: int, instance: str) -> bytes:
    n = 2
    tracks = TrackArrays(
        classes=("Car",),
        id=np.arange(n, dtype=np.int64),
        class_index=np.zeros(n, np.int32),
        center=np.ones((n, 3), np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.5, np.float32),
        velocity=np.zeros((n, 3), np.float32),
        state=np.ones(n, np.int32),
        hits=np.ones(n, np.int32),
        age=np.ones(n, np.int32),
        time_since_update=np.zeros(n, np.int32),
    )
    return encode_track_frame(
        vehicle="car-1",
        sensor="lidar",
        seq=seq,
        stamp_ns=stamp_ns,
        frame_id="lidar",
        pose=None,
        key_frame=True,
        instance=instance,
        received_ns=stamp_ns,
        published_ns=stamp_ns,
        tracks=tracks,
    )


def test_a_frame_sent_twice_is_delivered_once_and_a_reused_seq_with_a_new_stamp_is_not_lost() -> (
    None
):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(mode="peer", listen=[endpoint]) as planner_side:
        sub = TrackSubscriber(planner_side, vehicle="car-1")
        with open_session(mode="peer", connect=[endpoint]) as members:
            key = "fleet/car-1/lidar/tracks"
            pub = members.declare_publisher(key)
            wait_for(lambda: pub.matching_status.matching, 10, "the planner")
            pub.put(track_frame(0, 100, "m-a"))
            pub.put(track_frame(1, 200, "m-a"))
            pub.put(track_frame(1, 200, "m-b"))  # the new owner's copy
            pub.put(track_frame(2, 300, "m-b"))
            pub.put(track_frame(0, 900, "m-b"))  # the vehicle rebooted: seq 0 again
            got = [sub.recv(timeout=5) for _ in range(4)]
            time.sleep(0.3)
            assert sub.recv(timeout=0.1) is None
        assert [(m.seq, m.frame.stamp_ns) for m in got if m is not None] == [
            (0, 100),
            (1, 200),
            (2, 300),
            (0, 900),
        ]
        assert sub.duplicates == 1
        sub.close()
