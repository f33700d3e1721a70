"""What an owner tells a sensor's standby of the tracks it published (server/told.py), and
how the standby keeps it beside the newest message a checkpoint brings (server/heard.py):
what it is told never hides that message while it is the newest, and anything malformed
teaches nothing."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import msgpack
import pytest

from simpletrack.server.heard import HeardStreams
from simpletrack.server.told import FLUSH_S, Teller, Told, read_told, told_payload, word_of
from simpletrack.wire import generate
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from tests.server.fake_clock import Clock
from tests.server.test_heard import OWN, message


def test_what_is_told_is_each_published_message_s_stamp_next_id_and_epoch() -> None:
    word = word_of("v1", "lidar", message(7, [4, 11], epoch=5))
    assert word == ("v1", "lidar", 7, 12, 5)
    assert word_of("v1", "lidar", b"\x93garbage") is None
    payload = told_payload([word, ("v2", "radar", 8, 0, None)], "member-a")
    assert len(payload) < 64
    assert read_told(payload) == [
        Told("v1", "lidar", 7, 12, 5, "member-a"),
        Told("v2", "radar", 8, 0, None, "member-a"),
    ]


def test_a_fused_vehicle_s_word_tells_its_message_seq_too() -> None:
    word = word_of("truck-07", VEHICLE_STREAM, generate._vehicle_tracks(epoch=2))
    assert word == ("truck-07", VEHICLE_STREAM, generate._STAMP_NS, 13, 2, 1042)
    assert word_of("truck-07", VEHICLE_STREAM, b"\x93garbage") is None
    told = read_told(told_payload([word], "member-a"))
    assert told == [Told("truck-07", VEHICLE_STREAM, generate._STAMP_NS, 13, 2, "member-a", 1042)]
    heard = HeardStreams(OWN, batch=1, clock=Clock())
    heard.told(told[0])
    got = heard.get("truck-07/@vehicle")
    assert got is not None and (got.seq, got.next_id, got.epoch) == (1042, 13, 2)
    assert got.payload is None


GOOD = ["v1", "lidar", 7, 12, 5]


@pytest.mark.parametrize(
    "obj",
    [
        ["a", [GOOD[:4]]],  # a field short
        ["a", [["v1", "li/dar", 7, 12, 5]]],  # not a name
        ["a", [["v1", "@vehicle", 7, 12, 5]]],  # a fused vehicle's word without its seq
        ["a", [["v1", "lidar", 7, 12, 5, 3]]],  # a seq in a sensor's word
        ["a", [["v1", "@vehicle", 7, 12, 5, -1]]],
        ["a", [["v1", "@vehicle", 7, 12, 5, "3"]]],
        ["a", [["v1", "@vehicle", 7, 12, 5, 3, 0]]],
        ["a", [["v1", "lidar", -1, 12, 5]]],
        ["a", [["v1", "lidar", 7, 2**63, 5]]],
        ["a", [["v1", "lidar", 7, 12, "5"]]],
        ["a", [GOOD, ["v1", "lidar", 7, 12, "5"]]],  # one bad word: the message is refused
        [None, [GOOD]],
        ["a", GOOD],
        ["a", [GOOD] * 10_001],
        {"vehicle": "v1"},
    ],
)
def test_a_malformed_told_message_teaches_nothing(obj: Any) -> None:
    assert read_told(msgpack.packb(obj)) is None


def test_not_msgpack_teaches_nothing() -> None:
    assert read_told(b"\xc1") is None
    assert read_told(b"") is None


def test_the_checkpoint_s_message_stays_while_nothing_newer_is_told() -> None:
    heard = HeardStreams(OWN, batch=1, clock=Clock())
    heard.told(Told("v", "lidar", 5, 3, 2, "a"))
    kept = message(5, [1, 2], epoch=2)
    heard.add("v/lidar", kept)  # the checkpoint of the same frame, with its message
    heard.told(Told("v", "lidar", 5, 3, 2, "a"))  # told late: the same frame again
    got = heard.get("v/lidar")
    assert got is not None and got.payload == kept and got.stamp_ns == 5
    heard.told(Told("v", "lidar", 4, 3, 2, "a"))  # an older word changes nothing
    got = heard.get("v/lidar")
    assert got is not None and got.payload == kept and got.stamp_ns == 5
    heard.told(Told("v", "lidar", 6, 9, 3, "a"))  # a newer frame: its message is not here
    got = heard.get("v/lidar")
    assert got is not None and (got.stamp_ns, got.next_id, got.epoch, got.payload) == (
        6,
        9,
        3,
        None,
    )
    heard.add("v/lidar", message(5, [1, 2], epoch=2))  # an older checkpoint's message
    got = heard.get("v/lidar")
    assert got is not None and got.stamp_ns == 6 and got.payload is None


def test_the_told_word_waits_for_its_batch_and_a_reader_sees_it() -> None:
    heard = HeardStreams(OWN, batch=64, batch_s=10.0, clock=Clock())
    heard.told(Told("v", "lidar", 5, 3, None, "a"))
    got = heard.get("v/lidar")
    assert got is not None and (got.stamp_ns, got.next_id, got.epoch) == (5, 3, None)


class _Session:
    def __init__(self) -> None:
        self.declared: list[str] = []
        self.put: list[tuple[str, list[Told]]] = []

    def declare_publisher(self, key: str, **_: Any) -> Any:
        self.declared.append(key)
        return _Publisher(self, key)


class _Publisher:
    def __init__(self, session: _Session, key: str) -> None:
        self.session, self.key = session, key

    def put(self, payload: bytes) -> None:
        words = read_told(payload)
        assert words is not None
        self.session.put.append((self.key, words))

    def undeclare(self) -> None:
        pass


STANDBYS = {
    "v/lidar": "member-b",
    "v/radar": "member-c",
    "w/lidar": "member-b",
    "truck-07/@vehicle": "member-b",
}


def _teller(clock: Clock) -> tuple[Teller, _Session]:
    session = _Session()
    outbox = SimpleNamespace(session=session, keys=Keys("fleet"), congestion=None)
    outbox.instance = "member-a"
    return Teller(outbox, STANDBYS.get, clock=clock), session  # type: ignore[arg-type]


def _said(session: _Session) -> list[tuple[str, list[tuple[str, int]]]]:
    return [(k.split("/")[2], [(w.stream, w.stamp_ns) for w in ws]) for k, ws in session.put]


def test_words_wait_and_go_together_one_message_per_standby() -> None:
    clock = Clock()
    teller, session = _teller(clock)
    teller.published("v", "lidar", message(1, [1]))
    teller.published("v", "radar", message(2, [1]))
    teller.published("w", "lidar", message(3, [1]))
    teller.published("v", "camera", message(4, [1]))  # no standby (alone): nobody told
    assert session.put == [] and not teller.due()
    assert teller.deadline() == clock.t + FLUSH_S  # the worker wakes for them then
    clock.t += FLUSH_S / 2
    assert not teller.due()
    clock.t += FLUSH_S
    assert teller.due()
    teller.flush()
    assert _said(session) == [
        ("member-b", [("v/lidar", 1), ("w/lidar", 3)]),
        ("member-c", [("v/radar", 2)]),
    ]
    assert sorted(session.declared) == [
        "fleet/@simpletrack/member-b/told",
        "fleet/@simpletrack/member-c/told",
    ]
    teller.flush()  # nothing waits: nothing said
    assert len(session.put) == 2 and not teller.due() and teller.deadline() is None


def test_a_stream_s_second_word_sends_the_first_before_it_waits() -> None:
    """At most one word of a stream unsaid: a killed owner's stream is repeated at most
    twice (its last word's frame, and the one after)."""
    teller, session = _teller(Clock())
    teller.published("v", "lidar", message(1, [1]))
    teller.published("v", "radar", message(1, [1]))
    teller.published("v", "lidar", message(2, [1]))
    assert _said(session) == [("member-b", [("v/lidar", 1)]), ("member-c", [("v/radar", 1)])]
    teller.close()  # the worker's end: what waits is said
    assert _said(session)[-1] == ("member-b", [("v/lidar", 2)])


def test_a_fused_vehicle_s_words_go_in_a_message_of_their_own() -> None:
    """A member of before vehicle words refuses a whole message for one word it cannot
    read: its sensors' words must not ride with a vehicle's."""
    teller, session = _teller(Clock())
    teller.published("v", "lidar", message(1, [1]))
    teller.published("truck-07", VEHICLE_STREAM, generate._vehicle_tracks())
    teller.published("w", "lidar", message(3, [1]))
    teller.flush()
    assert _said(session) == [
        ("member-b", [("v/lidar", 1), ("w/lidar", 3)]),
        ("member-b", [("truck-07/@vehicle", generate._STAMP_NS)]),
    ]
    assert [w.seq for w in session.put[1][1]] == [1042]


def test_a_message_behind_notices_is_told_alone() -> None:
    teller, _ = _teller(Clock())
    told = teller.message("v", "lidar", message(7, [1]))
    assert told is not None and told[0] == "fleet/@simpletrack/member-b/told"
    assert read_told(told[1]) == [Told("v", "lidar", 7, 2, 3, "member-a")]
    assert teller.message("v", "camera", message(7, [1])) is None
