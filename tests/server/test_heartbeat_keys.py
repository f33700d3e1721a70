"""A member hears each subscribed vehicle publisher's heartbeats, and the checkpoints of the
streams it holds, by key expressions declared for them (server/subscriptions.py). Through
the subscribers' wildcards alone, Zenoh tested each such message against every subscriber of
the member's session: at 600 sensors heartbeats cost a member 0.29 cores, 0.05 with their
keys declared (docs/BENCHMARKS.md, "Why, and the cure")."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack

import pytest
import zenoh

from simpletrack.client import DetectionPublisher
from simpletrack.server.group import Membership
from simpletrack.server.sensor_tokens import SensorTokens, heartbeat_keys
from simpletrack.server.subscriptions import Subscriptions
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import free_port
from simpletrack.wire.keys import Keys
from tests.service_helpers import moving_cars, stamp, wait_for

KEYS = Keys("hb")
TOKEN = "hb/car/lidar/detections/@adv/pub/{zid}/{eid}/_"


@pytest.mark.parametrize(
    ("tokens", "subscribed", "plain", "keys"),
    [
        ({"v/a": {"ka"}, "v/b": {"kb"}}, {"v/a", "v/b"}, set(), {"ka", "kb"}),
        ({"v/a": {"ka", "ka2"}}, {"v/a"}, set(), {"ka", "ka2"}),  # a reboot: both, for now
        ({"v/a": {"ka"}, "v/b": {"kb"}}, {"v/a"}, set(), {"ka"}),  # not held: no key
        ({"v/a": {"ka"}}, {"v/a"}, {"v/a"}, set()),  # a plain subscription hears no beats
        ({}, {"v/a"}, set(), set()),  # its token gone (in the grace after it)
    ],
)
def test_which_heartbeat_keys_a_member_declares(
    tokens: dict[str, set[str]], subscribed: set[str], plain: set[str], keys: set[str]
) -> None:
    assert heartbeat_keys(tokens, subscribed, plain) == keys


@pytest.fixture
def member() -> Iterator[tuple[str, zenoh.Session, Subscriptions]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(ZenohOptions(listen=[endpoint])) as session:
        tokens = SensorTokens(session, KEYS)
        tokens.start(plain=False)
        subs = Subscriptions(
            session,
            KEYS,
            Membership("m1", KEYS),
            tokens,
            lambda: lambda _: None,
            lambda _: None,
            1,
        )
        subs.start()
        try:
            yield endpoint, session, subs
        finally:
            subs.close()


def beat_keys(subs: Subscriptions) -> set[str]:
    return {k for k in subs.exact_keys if "/@adv/pub/" in k}


def _publisher(stack: ExitStack, endpoint: str) -> tuple[DetectionPublisher, str]:
    session = stack.enter_context(open_session(ZenohOptions(connect=[endpoint])))
    pub = DetectionPublisher(
        session, "car", "lidar", classes=("Car",), prefix="hb", heartbeat_s=0.05
    )
    stack.callback(pub.close)
    pub.publish(moving_cars(0), stamp_ns=stamp(0))  # heartbeats start with the first frame
    return pub, TOKEN.format(zid=session.info.zid(), eid="*")


def test_a_rebooted_publishers_heartbeats_come_by_its_own_declared_key(
    member: tuple[str, zenoh.Session, Subscriptions],
) -> None:
    endpoint, session, subs = member
    beats: list[str] = []
    # Declared after the keys are: a heartbeat by a declared key still reaches it.
    beat_sub = session.declare_subscriber(
        "hb/car/lidar/detections/@adv/pub/**", lambda s: beats.append(str(s.key_expr))
    )
    try:
        with ExitStack() as first:
            _, pattern = _publisher(first, endpoint)
            wait_for(lambda: len(beat_keys(subs)) == 1, 10, "the first publisher's key")
            (key,) = beat_keys(subs)
            assert zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key))
            wait_for(lambda: key in beats, 5, "a heartbeat by its declared key")
        with ExitStack() as second:  # the vehicle rebooted: a new session, a new publisher
            _, pattern = _publisher(second, endpoint)
            wait_for(
                lambda: len(beat_keys(subs)) == 1 and key not in beat_keys(subs),
                10,
                "the old key undeclared, the new one declared",
            )
            (new_key,) = beat_keys(subs)
            assert zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(new_key))
            n = len(beats)
            time.sleep(0.3)
            assert beats[n:] and set(beats[n:]) == {new_key}
    finally:
        beat_sub.undeclare()


def test_a_checkpoint_for_a_held_stream_comes_by_its_declared_key(
    member: tuple[str, zenoh.Session, Subscriptions],
) -> None:
    endpoint, session, subs = member
    key = KEYS.checkpoint("m1", "car", "lidar")
    got: list[str] = []
    sub = session.declare_subscriber(
        KEYS.checkpoint("m1", "*", "*"), lambda s: got.append(str(s.key_expr))
    )
    try:
        with ExitStack() as stack:
            _publisher(stack, endpoint)
            wait_for(lambda: key in subs.exact_keys, 10, "the held stream's checkpoint key")
            owner = stack.enter_context(open_session(ZenohOptions(connect=[endpoint])))
            wait_for(lambda: (owner.put(key, b"state"), key in got)[1], 5, "the checkpoint")
        # The vehicle gone, its sensor stays held for the grace after its token: so does its key.
        assert key in subs.exact_keys and not beat_keys(subs)
    finally:
        sub.undeclare()
