"""A planner's subscribers drop what a fenced holder sends: once a stream has shown custody
epoch 2 (a new instance took it over), a late message with epoch 1 (the old holder, paused or
cut off, still publishing) is counted in ``stale``, not delivered (schemas/README.md,
"Custody epoch (fencing)"). The rule itself: ``StreamFilter``, unit-tested below."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

from simpletrack.client import TrackSubscriber, VehicleTrackSubscriber
from simpletrack.client.stream_filter import StreamFilter, Verdict
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import TrackArrays, encode_track_frame, encode_vehicle_track_frame
from simpletrack.wire.keys import Keys
from tests.service_helpers import wait_for

pytestmark = pytest.mark.zenoh


def _arrays(n: int = 2) -> TrackArrays:
    return TrackArrays(
        classes=("Car",),
        id=np.arange(n, dtype=np.int64),
        class_index=np.zeros(n, np.int32),
        center=np.ones((n, 3), np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.5),
        velocity=np.zeros((n, 3), np.float32),
        state=np.ones(n, np.int32),
        hits=np.ones(n, np.int32),
        age=np.ones(n, np.int32),
        time_since_update=np.zeros(n, np.int32),
        age_s=np.zeros(n),
        time_since_update_s=np.zeros(n),
    )


def sensor_frame(seq: int, stamp_ns: int, instance: str, epoch: int | None) -> bytes:
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
        tracks=_arrays(),
        epoch=epoch,
    )


def vehicle_frame(seq: int, stamp_ns: int, instance: str, epoch: int | None) -> bytes:
    n = 2
    tracks = replace(
        _arrays(n), existence=np.full(n, 0.5), sensor_stamp_ns=np.full((n, 1), stamp_ns)
    )
    return encode_vehicle_track_frame(
        vehicle="car-1",
        seq=seq,
        stamp_ns=stamp_ns,
        sensor="lidar",
        sensor_seq=seq,
        frame_id="base_link",
        pose=None,
        instance=instance,
        received_ns=stamp_ns,
        published_ns=stamp_ns,
        sensors=["lidar"],
        sensor_state=["ok"],
        tracks=tracks,
        epoch=epoch,
    )


Frame = Callable[[int, int, str, int | None], bytes]
STREAMS: list[tuple[str, type[TrackSubscriber | VehicleTrackSubscriber], str, Frame]] = [
    ("sensor", TrackSubscriber, Keys("fleet").tracks("car-1", "lidar"), sensor_frame),
    ("vehicle", VehicleTrackSubscriber, Keys("fleet").vehicle_tracks("car-1"), vehicle_frame),
]


@pytest.mark.parametrize(
    ("kind", "subscriber", "key", "frame"), STREAMS, ids=[s[0] for s in STREAMS]
)
def test_a_late_message_of_a_fenced_holder_is_dropped_and_counted(
    kind: str,
    subscriber: type[TrackSubscriber | VehicleTrackSubscriber],
    key: str,
    frame: Frame,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(mode="peer", listen=[endpoint]) as planner_side:
        sub = subscriber(planner_side, vehicle="car-1")
        with open_session(mode="peer", connect=[endpoint]) as members:
            pub = members.declare_publisher(key)
            wait_for(lambda: pub.matching_status.matching, 10, "the planner")
            pub.put(frame(0, 100, "m-a", 1))
            pub.put(frame(1, 200, "m-b", 2))  # m-b took the stream over
            pub.put(frame(2, 300, "m-a", 1))  # m-a, resumed after a pause, still publishing
            pub.put(frame(3, 400, "m-b", 2))
            got = [sub.recv(timeout=5) for _ in range(3)]
            wait_for(lambda: sub.stale == 1, 5, "the fenced message")
            time.sleep(0.3)
            assert sub.recv(timeout=0.1) is None
        assert [(m.seq, m.epoch, m.frame.instance) for m in got if m is not None] == [
            (0, 1, "m-a"),
            (1, 2, "m-b"),
            (3, 2, "m-b"),
        ]
        assert (sub.stale, sub.duplicates, sub.invalid) == (1, 0, 0)
        sub.close()


def test_messages_without_an_epoch_are_delivered_as_before() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(mode="peer", listen=[endpoint]) as planner_side:
        sub = TrackSubscriber(planner_side, vehicle="car-1")
        with open_session(mode="peer", connect=[endpoint]) as members:
            pub = members.declare_publisher(Keys("fleet").tracks("car-1", "lidar"))
            wait_for(lambda: pub.matching_status.matching, 10, "the planner")
            pub.put(sensor_frame(0, 100, "old", None))
            pub.put(sensor_frame(1, 200, "new", 5))
            pub.put(sensor_frame(2, 300, "old", None))  # a service of before epochs
            got = [sub.recv(timeout=5) for _ in range(3)]
        assert [(m.seq, m.epoch) for m in got if m is not None] == [(0, None), (1, 5), (2, None)]
        assert [m.schema_version for m in got if m is not None] == [2, 3, 2]
        assert sub.stale == 0
        sub.close()


# --- the rule, without Zenoh ---------------------------------------------------------------

DELIVER, REPEAT, STALE = Verdict.DELIVER, Verdict.REPEAT, Verdict.STALE


def test_a_lower_epoch_is_stale_an_equal_one_follows_the_repeat_rule() -> None:
    f = StreamFilter()
    k = "fleet/car-1/lidar/tracks"
    assert f.admit(k, 0, 100, 1) is DELIVER
    assert f.admit(k, 1, 200, 2) is DELIVER
    assert f.admit(k, 2, 300, 1) is STALE  # a fenced holder, whatever its seq
    assert f.admit(k, 1, 200, 2) is REPEAT  # same epoch, same (seq, stamp)
    assert f.admit(k, 1, 250, 2) is DELIVER  # same epoch, a new stamp
    assert f.admit(k, 0, 900, 2) is DELIVER  # a rebooted vehicle's seq 0 again
    assert (f.stale, f.repeats, f.highest_epoch(k)) == (1, 1, 2)


def test_a_new_holders_repeat_is_a_repeat_and_raises_the_epoch() -> None:
    f = StreamFilter()
    k = "fleet/car-1/lidar/tracks"
    assert f.admit(k, 7, 700, 3) is DELIVER
    # The new holder sends again the frame the old one had sent: not delivered twice...
    assert f.admit(k, 7, 700, 4) is REPEAT
    # ...but it holds the stream now: the old holder's next message is stale.
    assert f.admit(k, 8, 800, 3) is STALE
    assert f.highest_epoch(k) == 4


def test_a_new_holders_replay_after_a_partition_is_delivered_once() -> None:
    """Both sides of a partition answer; the taker (higher epoch) replays from the last frame
    it heard, far more frames back than the repeat window: each frame once all the same."""
    f = StreamFilter(recent_frames=4)
    k = "fleet/car-1/lidar/tracks"
    assert all(f.admit(k, q, q * 100, 1) is DELIVER for q in range(40))  # the old holder
    replay = [f.admit(k, q, q * 100, 2) for q in range(10, 45)]  # the taker, from seq 10
    assert replay == [REPEAT] * 30 + [DELIVER] * 5
    assert f.admit(k, 45, 4500, 1) is STALE  # the old holder, still on its side
    # Caught up: a stamp going back (a rebooted vehicle) is a new frame again.
    assert f.admit(k, 0, 50, 2) is DELIVER


def test_a_new_holders_message_sharing_the_last_stamp_is_delivered() -> None:
    """A fused vehicle's lidar and camera frames can share a stamp, two messages (seq 75 and
    76). The old holder's last delivered was 75; the taker sends 75 again, then 76: 76 is
    new (it was lost to a planner in a kill test when the rule looked at stamps alone)."""
    f = StreamFilter()
    k = "fleet/veh00/@vehicle/tracks"
    assert [f.admit(k, q, s, 1) for q, s in ((74, 2900), (75, 3000))] == [DELIVER] * 2
    assert f.admit(k, 75, 3000, 2) is REPEAT
    assert f.admit(k, 76, 3000, 2) is DELIVER
    assert f.admit(k, 77, 3067, 2) is DELIVER
    g = StreamFilter(recent_frames=1)  # a lower seq at the same stamp, out of the window
    assert [g.admit(k, q, 3000, 1) for q in (75, 76)] == [DELIVER] * 2
    assert g.admit(k, 75, 3000, 2) is REPEAT
    assert g.admit(k, 76, 3000, 2) is REPEAT


def test_no_epoch_is_judged_by_the_repeat_rule_only_and_keeps_the_highest() -> None:
    f = StreamFilter()
    k = "fleet/car-1/@vehicle/tracks"
    assert f.admit(k, 0, 100, None) is DELIVER
    assert f.highest_epoch(k) is None
    assert f.admit(k, 1, 200, 6) is DELIVER
    assert f.admit(k, 2, 300, None) is DELIVER
    assert f.admit(k, 2, 300, None) is REPEAT
    assert f.highest_epoch(k) == 6
    assert f.admit(k, 3, 400, 0) is STALE  # epoch 0 is an epoch, lower than 6


def test_streams_are_fenced_each_on_its_own() -> None:
    f = StreamFilter()
    assert f.admit("fleet/car-1/lidar/tracks", 0, 100, 9) is DELIVER
    assert f.admit("fleet/car-1/radar/tracks", 0, 100, 1) is DELIVER
    assert f.admit("fleet/car-2/lidar/tracks", 0, 100, 1) is DELIVER
    assert f.stale == 0


def test_memory_is_bounded_forgetting_every_stream_at_once() -> None:
    f = StreamFilter(recent_frames=2, max_keys=2)
    assert f.admit("a", 0, 0, 5) is DELIVER
    assert f.admit("b", 0, 0, 5) is DELIVER
    assert f.admit("c", 0, 0, 5) is DELIVER  # a third stream: the first two are forgotten
    assert f.highest_epoch("a") is None
    assert f.admit("a", 1, 1, 1) is DELIVER  # forgotten, so its next epoch is its highest
    for seq in (1, 2):
        assert f.admit("c", seq, seq, 5) is DELIVER
    assert f.admit("c", 0, 0, 5) is DELIVER  # out of the window of the 2 most recent


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"recent_frames": 0}, "recent_frames must be an int >= 1, got 0"),
        ({"max_keys": -3}, "max_keys must be an int >= 1, got -3"),
        ({"max_keys": 2.5}, "max_keys must be an int >= 1, got 2.5"),
    ],
)
def test_constructor_arguments_are_checked(kwargs: dict[str, object], needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        StreamFilter(**kwargs)  # type: ignore[arg-type]
