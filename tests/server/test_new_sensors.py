"""Which subscriptions take a vehicle's whole cache: a sensor first published while the member
runs, however late its subscription comes (server/sensor_tokens.py ``NewSensors``).

Until 2026-12-06 that held only within 5 s of the sensor's first token. A member whose
subscriptions thread was late past that (seen once in CI: ``simpletrack replay kitti --rate
max`` against a fresh service, the second sequence's sensor) took only ``history_frames`` (1)
from the cache: 7 of its 8 frames were never tracked and never announced. Reproduced by hand
with a 6 s delay before that subscription: the same 13 tracked and 7 unanswered."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from simpletrack.server.sensor_tokens import NewSensors, fresh_of

S = "truck-07/lidar"

Step = Callable[[NewSensors], None]


def token(running: bool = True, back: bool = False, sensor: str = S) -> Step:
    return lambda n: n.token(sensor, running=running, back=back)


def others(*sensors: str) -> Step:
    return lambda n: n.others(set(sensors))


def take(sensor: str = S) -> Step:
    def step(n: NewSensors) -> None:
        n.take(sensor)

    return step


CASES: list[tuple[str, list[Step], bool]] = [
    ("first published while running: whole cache", [token()], True),
    (
        "subscribed late, after other sensors came and went: still the whole cache",
        [token(), token(sensor="truck-07/cam"), others("truck-07/cam")],
        True,
    ),
    ("seen while the start settled (a restored sensor): history_frames", [token(False)], False),
    ("its tokens back after an outage: history_frames", [token(back=True)], False),
    (
        "published again after being known (a restarted publisher)",
        [token(), take(), token()],
        False,
    ),
    (
        "found another member's: a later takeover is the custody machine's",
        [token(), others(S)],
        False,
    ),
    (
        "another sensor found another member's leaves this one new",
        [token(), others("truck-07/cam")],
        True,
    ),
    ("taken once: a second subscription (a role change) is not new", [token(), take()], False),
]


@pytest.mark.parametrize(("steps", "fresh"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_new_sensors_subscription_takes_the_whole_cache(steps: list[Step], fresh: bool) -> None:
    new = NewSensors()
    for step in steps:
        step(new)
    assert new.take(S) is fresh


@pytest.mark.parametrize(
    ("fresh", "stream", "claimed"),
    [
        ({"car/lidar", "car/cam"}, "car/lidar", {"car/lidar"}),  # a sensor's own stream
        ({"car/lidar", "car/cam", "bus/lidar"}, "car/@vehicle", {"car/lidar", "car/cam"}),
        ({"car/lidar"}, "car/cam", set()),  # not fresh: starts at its first frame
        ({"carx/lidar"}, "car/@vehicle", set()),  # another vehicle, a longer name
    ],
)
def test_which_fresh_sensors_a_streams_takeover_claims(
    fresh: set[str], stream: str, claimed: set[str]
) -> None:
    assert fresh_of(fresh, stream) == claimed
