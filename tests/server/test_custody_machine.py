"""The custody machine's table: each guarantee docs/SCALE.md and docs/SERVICE.md state about a
stream changing hands, as events in and actions out (no Zenoh, no clock, no data).

Guarantees, one table test (or a group) each:
 G1  an owned, held stream's frame is tracked and published; not owned: kept by its standby,
     ignored (counted) by the others; held but no longer owned: released to the owner.
 G2  owned, not held: the first frame asks the group (alone with nothing released: no
     question); every frame waits behind the answer and is tracked after it, in order.
 G3  the state taken over is the holder's (hand-off), else the newest of the standby's
     checkpoint and this member's own snapshot, else new; tracks heard without a state:
     ``lost`` (new ids above every id heard).
 G4  replay: frames the state holds are skipped; frames planners have tracks of are
     tracked without publishing, except after a failover the last one heard (at least
     once: the dead member may have been killed halfway through that put).
 G4b a failover whose checkpoint holds the newest frame heard answered publishes that
     message again, as the new owner's (the dead holder may have written it to the
     standby's link but not to the planners'); not when the replay publishes it anyway
     (an older checkpoint), nor after a hand-off or from a final checkpoint (its holder
     stopped cleanly, having published all it heard: a stop answers each frame once).
 G5  kept, cached and waiting frames overlap: each frame is tracked once, in stamp order.
 G6  a gap after the state is asked of the vehicle's cache (restore, failover, hand-off):
     its newest frames back to the state (all it keeps when that was not enough); filled: ids exactly as an uninterrupted run (no floor raised); not filled: the hole is
     announced as missed and new ids start above every id heard and reserved.
 G7  a lone instance restarted from its snapshot replays the gap since it first (the
     crash costs planners nothing when the vehicle's cache covers it).
 G8  bounded memory: a standby keeps at most ``standby_frames`` per stream, trimmed by each
     checkpoint (an older checkpoint overtaken on the way is ignored); a takeover's waiting
     frames beyond it are kept on the member's byte budget (``burst_bytes``, shared with the
     queues), given back when they are tracked; past it, dropped oldest first, announced.
 G9  a stream released to a member this one does not see yet is stood by for (its frames
     kept) for ``RELEASE_GUARD_S``; asked again, the same state.
 G10 fencing: a member stopped past ``fence_after_s`` in a group publishes nothing from its
     streams: each is stashed, its frames wait until the member reaches the group again plus
     ``fence_hold_s``, then the group is asked; the holder's state wins, its own stash is used
     only when nobody holds the stream (and its last message is sent again: the stop may
     have cut it off). A higher epoch heard on a held stream fences it the same way. Alone,
     nothing is fenced. Epochs grow by one takeover each, ordered by instance on a tie.
 G11 a fused vehicle's stream replays through its reorder buffer (marked replayed); taken up
     when its group starts to fuse, the frames a sensor's own key was answered for by a
     member of before fusion are skipped, whether kept as its standby or waiting (the
     vehicle's cache hands a new subscription its last frames).
 G12 an evicted stream asks again at its next frame; a cache answer after the takeover
     finished is ignored.
 G13 the group changed: a stream stood by for and owned now, whose kept frames the old
     owner never answered, is asked for at once (those frames wait for no next frame); one
     whose frames were all answered, or still stood by for, or asked already, or that its
     sensors' frames no longer go to (its vehicle fuses now), is not.
 G14 a fresh start of sensors first published while this member runs asks their vehicle's
     cache for all it keeps first: the frames a new subscription's history dropped are
     tracked, in stamp order, each once; a fused vehicle's other sensors' cached frames
     (published before this member started) are not tracked again.
 G15 a held stream whose restarted publisher's first frame heard is not its first (a
     vehicle rebooted while its router was away) asks the vehicle's cache for all it keeps,
     its frames waiting meanwhile: the frames before it are tracked first, in stamp order,
     each once; those the cache no longer keeps (by the cached samples' Zenoh sequence
     numbers, from the publisher's first, 0) are announced as missed on the restarted
     sensor; each publisher session is asked once, and only of a stream held (a fused
     vehicle still catching up on a silent sensor too; a takeover's frames are its own).
"""

from __future__ import annotations

import pytest

from simpletrack.server.custody_machine import (
    FETCH_SLACK,
    RELEASE_GUARD_S,
    AnnounceMissed,
    Ask,
    CustodyMachine,
    Drop,
    FetchCache,
    Heard,
    Keep,
    Limits,
    NotOwned,
    Phase,
    RaiseIds,
    Release,
    Republish,
    Resend,
    Resolve,
    RestartCoverage,
    Role,
    SensorCoverage,
    Skip,
    Source,
    Stash,
    Takeover,
    Track,
    View,
    epoch_tag,
    next_epoch,
)
from simpletrack.wire.models import SensorSnapshot
from simpletrack.wire.reasons import ErrorReason

Frame = tuple[str, int, int]  # (detection key, seq, stamp_ns)
S = "car/lidar"
KEY = "fleet/car/lidar/detections"
ME, OTHER = "a", "b"


def f(seq: int, key: str = KEY) -> Frame:
    return (key, seq, seq * 100)


def peek(fr: Frame) -> tuple[str, int | None, int | None]:
    return fr[:3]  # type: ignore[return-value]  # a restart's frames carry their sn too


def machine(**limits: float) -> CustodyMachine[Frame]:
    return CustodyMachine(peek, Limits(**limits))  # type: ignore[arg-type]


def view(role: Role = Role.OWNER, members: tuple[str, ...] = (ME, OTHER)) -> View:
    owner = ME if role is Role.OWNER else OTHER
    return View(ME, frozenset(members), role, owner)


def snap(last_seq: int | None, written_ns: int = 1, stream: str = S) -> SensorSnapshot:
    vehicle, sensor = stream.split("/")
    return SensorSnapshot(
        schema_version=1, vehicle=vehicle, sensor=sensor, config_digest="d",
        written_ns=written_ns, last_seq=last_seq,
        last_stamp_ns=None if last_seq is None else last_seq * 100,
        id_base=0, id_next=5, frames=0, tracker=b"t",
    )  # fmt: skip


def nobody(_: str) -> Heard | None:
    return None


def heard(stamp_seq: int, next_id: int = 9) -> object:
    return lambda _: Heard(stamp_seq * 100, next_id)


def tracked(acts: list[object]) -> list[tuple[int, bool]]:
    """(seq, published) of each Track."""
    return [(a.frame[1], a.publish) for a in acts if isinstance(a, Track)]


def take(
    m: CustodyMachine[Frame],
    replies: list[SensorSnapshot],
    state: SensorSnapshot | None,
    heard_fn: object = nobody,
    stream: str = S,
) -> list[object]:
    """What the worker does after an answer: adopt the state the machine chose."""
    t = m.answered(stream, replies, heard_fn)  # type: ignore[arg-type]
    assert (t.snapshot is None) == (state is None) or state is None
    cov = (
        None
        if t.snapshot is None
        else SensorCoverage(t.snapshot.last_seq, t.snapshot.last_stamp_ns, peek)
    )
    return list(m.adopted(stream, cov))


def held(m: CustodyMachine[Frame], upto: int = 1) -> None:
    """Hold S (a new stream) with frames 1..upto tracked."""
    assert m.frame(S, f(1), view(), 0.0) == [Ask(S)]
    take(m, [], None)
    for q in range(2, upto + 1):
        assert tracked(m.frame(S, f(q), view(), 0.0)) == [(q, True)]


# ---------------------------------------------------------------------- G1
@pytest.mark.parametrize(
    ("role", "expect"),
    [(Role.STANDBY, Keep), (Role.NONE, NotOwned)],
)
def test_g1_frames_of_streams_not_owned_are_kept_or_ignored(role: Role, expect: type) -> None:
    m = machine()
    acts = m.frame(S, f(1), view(role), 0.0)
    assert [type(a) for a in acts] == [expect]
    assert m.phase(S) is Phase.UNHELD


def test_g1_held_stream_tracked_and_released_when_no_longer_owned() -> None:
    m = machine()
    held(m, 3)
    assert m.phase(S) is Phase.HELD
    acts = m.frame(S, f(4), view(Role.STANDBY), 0.0)
    assert acts[0] == Release(S, OTHER) and isinstance(acts[1], Keep)
    assert m.phase(S) is Phase.UNHELD


# ---------------------------------------------------------------------- G2
def test_g2_first_frame_asks_and_frames_wait_in_order() -> None:
    m = machine()
    assert m.frame(S, f(1), view(), 0.0) == [Ask(S)]
    assert m.frame(S, f(2), view(), 0.0) == []
    assert m.frame(S, f(3), view(), 0.0) == []
    assert m.phase(S) is Phase.ASKING
    assert tracked(take(m, [], None)) == [(1, True), (2, True), (3, True)]
    assert m.phase(S) in (Phase.HELD, Phase.CATCHING_UP)


def test_g2_alone_nothing_to_ask() -> None:
    m = machine()
    assert m.frame(S, f(1), view(members=(ME,)), 0.0) == [Resolve(S)]


def test_g2_a_live_frame_stamped_before_one_that_waited_is_tracked_not_skipped() -> None:
    # A fresh sensor's first frame waits for the takeover; the next one, stamped before it
    # (a replayed seq, a clock stepped back), came live too: the ordering rules answer it
    # (bench fuzz, seed 0: it was skipped, and never answered). Only what a cache or a
    # standby replayed can still be on its way, and only that is skipped.
    m = machine()
    assert m.frame(S, f(5), view(members=(ME,)), 0.0) == [Resolve(S)]
    assert tracked(take(m, [], None)) == [(5, True)]
    assert tracked(m.frame(S, (KEY, 1, 0), view(members=(ME,)), 0.0)) == [(1, True)]


# ---------------------------------------------------------------------- G3
def test_g3_handoff_beats_checkpoint_and_own_snapshot() -> None:
    m = machine()
    m.frame(S, f(1), view(Role.STANDBY), 0.0)
    m.checkpoint(S, snap(5, written_ns=30))
    m.restart([snap(6, written_ns=40)])
    m.frame(S, f(9), view(), 0.0)
    t = m.answered(S, [snap(8, written_ns=10)], nobody)
    assert t.source is Source.HANDOFF and t.snapshot is not None and t.snapshot.last_seq == 8


@pytest.mark.parametrize(
    ("checkpoint_ns", "local_ns", "source", "seq"),
    [(30, 20, Source.FAILOVER, 5), (20, 30, Source.RESTORE, 6)],
)
def test_g3_no_answer_takes_the_newest_of_checkpoint_and_own(
    checkpoint_ns: int, local_ns: int, source: Source, seq: int
) -> None:
    m = machine()
    m.checkpoint(S, snap(5, written_ns=checkpoint_ns))
    m.restart([snap(6, written_ns=local_ns)])
    m.frame(S, f(9), view(), 0.0)
    t = m.answered(S, [], nobody)
    assert t.source is source and t.snapshot is not None and t.snapshot.last_seq == seq


def test_g3_tracks_heard_but_no_state_is_lost() -> None:
    m = machine()
    m.frame(S, f(9), view(), 0.0)
    t = m.answered(S, [], heard(8, next_id=42))  # type: ignore[arg-type]
    assert t.source is Source.LOST and t.heard is not None and t.heard.next_id == 42


# ---------------------------------------------------------------------- G4
@pytest.mark.parametrize(
    ("replies", "expect"),
    [
        # hand-off: planners have up to 6 from the holder: 6 is not published again
        ("handoff", [(6, False), (7, True), (8, True)]),
        # failover: the last heard (6) is published again, at least once
        ("failover", [(6, True), (7, True), (8, True)]),
    ],
)
def test_g4_replay_skips_the_state_and_quiets_what_planners_have(
    replies: str, expect: list[tuple[int, bool]]
) -> None:
    m = machine()
    for q in range(3, 9):
        m.frame(S, f(q), view(Role.STANDBY), 0.0)
    state = snap(5, written_ns=10)
    if replies == "failover":
        m.checkpoint(S, state)
    first = m.frame(S, f(9), view(), 0.0)
    assert first == [Ask(S)]
    acts = take(m, [state] if replies == "handoff" else [], state, heard(6))
    assert tracked(acts) == [*expect, (9, True)]
    assert not any(isinstance(a, (AnnounceMissed, RaiseIds)) for a in acts)
    # live frames after the replay: published
    assert tracked(m.frame(S, f(10), view(), 0.0)) == [(10, True)]


# ---------------------------------------------------------------------- G4b
@pytest.mark.parametrize(
    ("replies", "state", "republished"),
    [
        ("failover", 6, True),
        ("failover", 5, False),
        ("final", 6, False),
        ("handoff", 6, False),
    ],
)
def test_g4b_a_failover_whose_checkpoint_holds_the_last_answer_publishes_it_again(
    replies: str, state: int, republished: bool
) -> None:
    m = machine()
    for q in range(3, 9):
        m.frame(S, f(q), view(Role.STANDBY), 0.0)
    snapshot = snap(state, written_ns=10)
    if replies != "handoff":
        m.checkpoint(S, snapshot, final=replies == "final")
    assert m.frame(S, f(9), view(), 0.0) == [Ask(S)]
    last = Heard(600, 9, payload=b"tracks of 6")

    acts = take(m, [snapshot] if replies == "handoff" else [], snapshot, lambda _: last)
    again = [a for a in acts if isinstance(a, Republish)]
    assert again == ([Republish(S, b"tracks of 6")] if republished else [])
    if republished:  # before anything the replay publishes
        assert acts.index(again[0]) < min(i for i, a in enumerate(acts) if isinstance(a, Track))
    # 6 published again by the replay instead, the other way round
    assert ((6, True) in tracked(acts)) is (replies == "failover" and not republished)


# ---------------------------------------------------------------------- G5
def test_g5_overlapping_kept_cached_and_waiting_frames_tracked_once_in_order() -> None:
    m = machine()
    for q in (6, 8, 7):
        m.frame(S, f(q), view(Role.STANDBY), 0.0)
    m.checkpoint(S, snap(3, written_ns=5))
    m.frame(S, f(9), view(), 0.0)
    m.frame(S, f(8), view(), 0.0)  # also waiting
    # 4, 5 missing: the cache's newest frames back to the state's 3, and 10 sent since
    assert take(m, [], snap(3)) == [FetchCache(S, 9 - 3 + FETCH_SLACK)]
    acts = m.cached(S, [f(q) for q in range(2, 10)], 16)
    assert tracked(acts) == [(q, True) for q in range(4, 10)]


# ---------------------------------------------------------------------- G6 / G7
def test_g6_g7_restart_replays_the_gap_from_the_cache_with_exact_ids() -> None:
    m = machine()
    m.restart([snap(10)])
    assert m.frame(S, f(20), view(members=(ME,)), 0.0) == [Resolve(S)]
    assert take(m, [], snap(10)) == [FetchCache(S, 20)]
    acts = m.cached(S, [f(q) for q in range(1, 21)])  # the cache's last 20 frames
    assert tracked(acts) == [(q, True) for q in range(11, 21)]
    assert not any(isinstance(a, (AnnounceMissed, RaiseIds)) for a in acts)


def test_g6_a_hole_nobody_kept_is_announced_and_raises_the_ids() -> None:
    m = machine()
    m.restart([snap(10)])
    m.frame(S, f(20), view(members=(ME,)), 0.0)
    assert take(m, [], snap(10), heard(9, next_id=77)) == [FetchCache(S, 20)]
    acts = m.cached(S, [f(q) for q in range(15, 20)], 20)  # 11..14 gone from the cache
    assert AnnounceMissed(S, 4) in acts and RaiseIds(S, 77) in acts
    assert tracked(acts) == [(q, True) for q in range(15, 21)]
    # the floor is raised before any frame after the hole is tracked
    assert acts.index(RaiseIds(S, 77)) < next(i for i, a in enumerate(acts) if isinstance(a, Track))


def test_g6_a_cache_that_answers_all_asked_with_holes_left_is_asked_for_all() -> None:
    # Asked for its newest 20, the cache had 20 frames newer than expected (a burst since):
    # the gap's frames are older, asked for once more, all of them.
    m = machine()
    m.restart([snap(10)])
    m.frame(S, f(20), view(members=(ME,)), 0.0)
    assert take(m, [], snap(10)) == [FetchCache(S, 20)]
    assert m.cached(S, [f(q) for q in range(21, 41)], 20) == [FetchCache(S)]
    acts = m.cached(S, [f(q) for q in range(1, 41)], None)
    assert tracked(acts)[:10] == [(q, True) for q in range(11, 21)]
    assert not any(isinstance(a, (AnnounceMissed, RaiseIds)) for a in acts)


def test_g6_a_restarted_publisher_is_not_exact() -> None:
    cov = SensorCoverage(10, 1000, peek)
    assert cov.exact([f(11), f(12)]) and cov.exact([])
    assert cov.exact([f(9), f(10), f(11)])  # copies of frames in the state: covered
    assert not cov.exact([f(11), f(13)])
    assert not cov.exact([("k", 1, 2000)])  # a new numbering: ids not provably the same


def test_g6_a_handoff_with_copies_of_frames_in_the_state_keeps_exact_ids() -> None:
    m = machine()
    m.frame(S, f(9), view(), 0.0)
    m.frame(S, f(10), view(), 0.0)
    m.frame(S, f(11), view(), 0.0)
    acts = take(m, [snap(10)], snap(10), heard(10))
    assert not any(isinstance(a, (AnnounceMissed, RaiseIds)) for a in acts)
    assert tracked(acts) == [(11, True)]


# ---------------------------------------------------------------------- G8
def test_g8_standby_bounded_and_trimmed_by_checkpoints() -> None:
    m = machine(standby_frames=3)
    for q in range(1, 8):
        m.frame(S, f(q), view(Role.STANDBY), 0.0)
    m.checkpoint(S, snap(5, written_ns=10))
    m.checkpoint(S, snap(2, written_ns=5))  # older, overtaken on the way: ignored
    t = m.answered(S, [], nobody)
    assert t.snapshot is not None and t.snapshot.last_seq == 5
    assert [fr[1] for fr in t.kept] == [6, 7]


def test_g8_waiting_frames_bounded_oldest_dropped_and_announced() -> None:
    m = machine(standby_frames=2)
    m.frame(S, f(1), view(), 0.0)
    m.frame(S, f(2), view(), 0.0)
    assert m.frame(S, f(3), view(), 0.0) == [Drop(S, f(1), ErrorReason.DROPPED_QUEUE_FULL)]


class _Budget:
    def __init__(self, limit: int) -> None:
        self.limit, self.used = limit, 0

    def take(self, n: int) -> bool:
        if self.used + n > self.limit:
            return False
        self.used += n
        return True

    def give(self, n: int) -> None:
        self.used -= n


def test_g8_waiting_frames_past_the_bound_kept_on_the_budget_then_given_back() -> None:
    budget = _Budget(limit=30)
    m = CustodyMachine(peek, Limits(standby_frames=2), budget, size=lambda fr: 10)
    acts = [a for q in range(1, 7) for a in m.frame(S, f(q), view(), 0.0)]
    # 2 free, 3 on the budget (30 bytes), the 6th drops the oldest, announced
    assert acts[1:] == [Drop(S, f(1), ErrorReason.DROPPED_QUEUE_FULL)]
    assert budget.used == 30
    assert tracked(take(m, [], None)) == [(q, True) for q in range(2, 7)]
    assert budget.used == 0


# ---------------------------------------------------------------------- G9
def test_g9_released_to_an_unseen_member_is_stood_by_for() -> None:
    m = machine()
    held(m)
    assert m.release_asked(S, "c", held=True) == [Release(S, "c")]
    m.released_as(S, snap(1), "c", 100.0)
    assert isinstance(m.frame(S, f(2), view(), 100.5)[0], Keep)  # "c" not in the view yet
    assert m.frame(S, f(3), view(), 100.0 + RELEASE_GUARD_S + 0.1) == [Ask(S)]


# ---------------------------------------------------------------------- G10
def test_g10_a_stopped_member_publishes_nothing_until_it_asked_again() -> None:
    m = machine(fence_after_s=2.0, fence_hold_s=1.0)
    held(m, 3)
    assert m.beat(10.0, view()) == []
    assert m.beat(22.0, view()) == [Stash(S)]  # stopped 12 s
    m.stashed(S, snap(3, written_ns=50))
    assert m.frame(S, f(4), view(), 22.0) == []  # waits: nothing tracked from stale state
    assert m.beat(22.5, view(), connected_at=None) == []  # not back in the group yet
    assert m.beat(22.8, view(), connected_at=22.6) == []  # back, tokens still coming
    assert m.beat(23.7, view(), connected_at=22.6) == [Ask(S)]
    # the member that took over answers: its state, not the stale one
    t = m.answered(S, [snap(40, written_ns=60)], nobody)
    assert t.source is Source.HANDOFF and t.snapshot is not None and t.snapshot.last_seq == 40


def test_g10_own_stash_used_when_nobody_took_over_its_last_message_sent_again() -> None:
    m = machine()
    held(m, 3)
    m.beat(0.0, view())
    assert m.beat(6.0, view()) == [Stash(S)]  # past the default fence_after_s (5 s)
    m.stashed(S, snap(3, written_ns=50), b"tracks of 3")
    m.frame(S, f(4), view(), 6.0)
    assert m.beat(7.5, view(), connected_at=0.0) == [Ask(S)]
    acts = take(m, [], snap(3))
    # The stop may have cut frame 3's message off on its way: sent again, then frame 4.
    assert acts[0] == Resend(S, b"tracks of 3")
    assert tracked(acts) == [(4, True)]


def test_g10_the_stash_is_not_sent_again_after_a_higher_epoch_was_heard() -> None:
    m = machine()
    held(m, 3)
    m.beat(0.0, view())
    m.beat(6.0, view())
    stash = SensorSnapshot(**{**snap(3, written_ns=50).model_dump(), "epoch": 1 << 16})
    m.stashed(S, stash, b"tracks of 3")
    m.frame(S, f(4), view(), 6.0)
    m.beat(7.5, view(), connected_at=0.0)
    t = m.answered(S, [], lambda _: Heard(300, 9, None, 2 << 16))
    assert t.source is Source.RESTORE and t.resend is None


def test_g10_a_taker_s_state_wins_and_the_stash_is_not_sent_again() -> None:
    m = machine()
    held(m, 3)
    m.beat(0.0, view())
    m.beat(6.0, view())
    m.stashed(S, snap(3, written_ns=50), b"tracks of 3")
    m.frame(S, f(4), view(), 6.0)
    m.beat(7.5, view(), connected_at=0.0)
    acts = take(m, [snap(3, written_ns=60)], snap(3))
    assert not any(isinstance(a, Resend) for a in acts)


def test_g10_fenced_even_when_the_others_tokens_went_before_the_first_beat() -> None:
    """A resumed client's link was closed while it was stopped: the others' tokens may be
    gone from its view before its worker beats. It was in a group: fenced all the same."""
    m = machine()
    held(m, 3)
    m.beat(0.0, view())
    assert m.beat(12.0, view(members=(ME,))) == [Stash(S)]


def test_g10_alone_nothing_is_fenced() -> None:
    m = machine()
    held(m)
    m.beat(0.0, view(members=(ME,)))
    assert m.beat(60.0, view(members=(ME,))) == []
    assert m.phase(S) in (Phase.HELD, Phase.CATCHING_UP)


# ---------------------------------------------------------------------- G11
def test_g11_a_fused_vehicle_replays_through_its_buffer() -> None:
    m = machine()
    v = "car/@vehicle"
    m.frame(v, f(1, "fleet/car/cam/detections"), view(), 0.0)
    t = m.answered(v, [], nobody)
    acts = m.adopted(v, None)
    assert t.source is Source.NEW
    assert [(type(a), a.replayed) for a in acts if isinstance(a, Track)] == [(Track, True)]
    assert [a.replayed for a in m.frame(v, f(2), view(), 0.0) if isinstance(a, Track)] == [False]


@pytest.mark.parametrize("kept", [False, True])
def test_g11_fusion_starts_past_what_each_sensors_own_key_was_answered_for(kept: bool) -> None:
    m = machine()
    m.fused_sensors = ("lidar", "cam")
    v, lidar, cam = "car/@vehicle", "fleet/car/lidar/detections", "fleet/car/cam/detections"
    frames = [f(3, lidar), f(3, cam), f(4, lidar), f(4, cam), f(5, lidar)]
    if kept:  # the old member owned the sensors' own streams; this one stood by for them
        for fr in frames:
            sensor = f"car/{fr[0].split('/')[2]}"
            assert isinstance(m.frame(sensor, fr, view(Role.STANDBY), 0.0)[0], Keep)
        assert m.frame(v, f(6, lidar), view(), 1.0) == [Ask(v)]
    else:  # not stood by for: the new subscription's history and live frames wait
        assert m.frame(v, frames[0], view(), 1.0) == [Ask(v)]
        for fr in [*frames[1:], f(6, lidar)]:
            assert m.frame(v, fr, view(), 1.0) == []
    on_own_key = {"car/lidar": Heard(400, 9), "car/cam": Heard(300, 9)}
    t = m.answered(v, [], on_own_key.get)
    acts = m.adopted(v, None)
    assert t.source is Source.NEW
    done = [(a.frame[0].split("/")[2], a.frame[1]) for a in acts if isinstance(a, Track)]
    assert done == [("cam", 4), ("lidar", 5), ("lidar", 6)]
    if not kept:
        skipped = [(a.frame[0].split("/")[2], a.frame[1]) for a in acts if isinstance(a, Skip)]
        assert skipped == [("lidar", 3), ("cam", 3), ("lidar", 4)]


class UpTo:
    """A fused vehicle's state holding every frame stamped up to ``stamp``."""

    def __init__(self, stamp: int) -> None:
        self.stamp = stamp

    def covers(self, frame: Frame) -> bool:
        return frame[2] <= self.stamp

    def holes(self, frames: object) -> int:
        return 0


def test_g11_a_vehicle_taken_over_skips_the_frames_its_state_holds() -> None:
    # A new owner's subscription hands it the vehicle's last frames: those the checkpoint
    # holds would meet the sensors' order rules, refused and announced, if tracked again.
    m = machine()
    v, lidar, cam = "car/@vehicle", "fleet/car/lidar/detections", "fleet/car/cam/detections"
    assert m.frame(v, f(2, lidar), view(), 0.0) == [Ask(v)]
    for fr in (f(2, cam), f(3, lidar), f(4, cam)):
        assert m.frame(v, fr, view(), 0.0) == []
    m.answered(v, [snap(3, stream=v)], nobody)
    acts = m.adopted(v, UpTo(300))
    assert [(type(a).__name__, a.frame[1]) for a in acts if isinstance(a, Track | Skip)] == [
        ("Skip", 2), ("Skip", 2), ("Skip", 3), ("Track", 4),
    ]  # fmt: skip


def test_g11_a_vehicles_frames_its_state_holds_are_skipped_until_each_sensor_is_past_it() -> None:
    # A new owner's subscription hands it each sensor's last frame from the cache; one may
    # come after the takeover finished, maybe a frame the cache's answer replayed already:
    # skipped, not refused by the sensor's order rules. A sensor's first frame past both
    # ends its catching up; once all are past, the order rules answer every frame.
    m, v, lidar, cam = filling_vehicle(f(5, LIDAR))  # lidar 4 missing: the cache is asked
    acts = m.cached(v, [f(4, lidar)])
    assert [(type(a), a.frame[1]) for a in acts if isinstance(a, Track)] == [(Track, 4), (Track, 5)]
    assert m.phase(v) is Phase.CATCHING_UP
    assert m.frame(v, f(4, lidar), view(), 0.0) == [Skip(v, f(4, lidar))]  # replayed already
    assert m.frame(v, f(5, lidar), view(), 0.0) == [Skip(v, f(5, lidar))]  # it waited: a copy
    assert m.frame(v, f(3, cam), view(), 0.0) == [Skip(v, f(3, cam))]  # the state holds it
    assert m.frame(v, f(6, lidar), view(), 0.0) == [Track(v, f(6, lidar))]  # lidar past both
    assert m.phase(v) is Phase.CATCHING_UP  # cam is not yet
    assert m.frame(v, f(5, cam), view(), 0.0) == [Track(v, f(5, cam))]
    assert m.phase(v) is Phase.HELD
    assert m.frame(v, f(3, cam), view(), 0.0) == [Track(v, f(3, cam))]


def test_g11_a_vehicles_replay_orders_equal_stamps_as_its_reorder_buffer() -> None:
    # Two sensors stamped alike, the camera's answer first: replayed in the buffer's order
    # (its sensors', then seq), or the lidar's would come late into a state without history.
    m, v, lidar, cam = filling_vehicle(f(6, LIDAR))
    acts = m.cached(v, [f(4, cam), f(4, lidar), f(5, cam)])
    done = [(a.frame[0].split("/")[2], a.frame[1]) for a in acts if isinstance(a, Track)]
    assert done == [("lidar", 4), ("cam", 4), ("cam", 5), ("lidar", 6)]


LIDAR, CAM = "fleet/car/lidar/detections", "fleet/car/cam/detections"


def filling_vehicle(first: Frame) -> tuple[CustodyMachine[Frame], str, str, str]:
    """A fused vehicle (lidar, cam) taken over from a state up to stamp 300 on ``first``,
    lidar 4 missing: its cache asked."""
    m = machine()
    m.fused_sensors = ("lidar", "cam")
    v = "car/@vehicle"
    m.frame(v, first, view(), 0.0)
    m.answered(v, [snap(3, stream=v)], nobody)
    assert m.adopted(v, Holes(300, 1)) == [FetchCache(v)]
    return m, v, LIDAR, CAM


class Holes(UpTo):
    """As ``UpTo``, with ``missing`` frames nobody kept."""

    def __init__(self, stamp: int, missing: int) -> None:
        super().__init__(stamp)
        self.missing = missing

    def holes(self, frames: object) -> int:
        return self.missing if not any(f[1] == 4 for f in frames) else 0  # type: ignore[attr-defined]


# ---------------------------------------------------------------------- G12
def test_g12_evicted_asks_again_and_late_cache_ignored() -> None:
    m = machine()
    held(m)
    m.gone(S)
    assert m.frame(S, f(5), view(), 0.0) == [Ask(S)]
    assert m.cached(S, [f(4)]) == []  # not filling: nothing to do


def test_g10_a_higher_epoch_heard_fences_the_holder() -> None:
    m = machine()
    held(m, 3)
    assert m.superseded(S, 10.0) == [Stash(S)]
    assert m.phase(S) is Phase.FENCED
    assert m.frame(S, f(4), view(), 10.0) == []
    assert m.beat(11.5, view(), connected_at=0.0) == [Ask(S)]
    assert m.superseded("car/other", 10.0) == []  # not held: nothing to fence


def test_g10_epochs_grow_by_one_takeover_and_differ_by_instance() -> None:
    first = next_epoch("a")
    assert first >> 16 == 1 and first & 0xFFFF == epoch_tag("a")
    again = next_epoch("b", first, None)
    assert again >> 16 == 2 and again > first
    # Two members taking over from the same state (a partition): never equal, both higher.
    one, two = next_epoch("a", again), next_epoch("c", again)
    assert one != two and min(one, two) > again
    t = m_takeover(snap_epoch=again, heard_epoch=first)
    assert t.epoch("a") >> 16 == 3


def m_takeover(snap_epoch: int, heard_epoch: int) -> Takeover[Frame]:
    state = SensorSnapshot(**{**snap(5).model_dump(), "epoch": snap_epoch})
    return Takeover(S, Source.FAILOVER, state, Heard(0, 0, None, heard_epoch), [])


# ---------------------------------------------------------------------- G13
def standby_of(*seqs: int, state: int = 2) -> CustodyMachine[Frame]:
    """A standby that kept ``seqs`` and has the owner's checkpoint at ``state``."""
    m = machine()
    for q in seqs:
        assert isinstance(m.frame(S, f(q), view(Role.STANDBY), 0.0)[0], Keep)
    m.checkpoint(S, snap(state, written_ns=10))
    return m


def test_g13_a_frame_the_dead_owner_never_answered_is_taken_over_at_the_group_change() -> None:
    # The owner answered 2 and died (or left) before 3; 3 reached the standby before it saw
    # the owner go. Its next frame may be seconds away: 3 must not wait for it.
    m = standby_of(2, 3)
    acts = m.promoted(lambda _: view(members=(ME, "c")), heard(2), 1.0)
    assert acts == [Ask(S)] and m.phase(S) is Phase.ASKING
    assert tracked(take(m, [], snap(2), heard(2))) == [(3, True)]
    assert tracked(m.frame(S, f(4), view(), 1.0)) == [(4, True)]


def test_g13_frames_that_arrive_while_asked_wait_behind_the_answer() -> None:
    m = standby_of(2, 3)
    assert m.promoted(lambda _: view(), heard(2), 1.0) == [Ask(S)]
    assert m.frame(S, f(4), view(), 1.0) == []  # no second question
    assert tracked(take(m, [snap(2)], snap(2), heard(2))) == [(3, True), (4, True)]


@pytest.mark.parametrize(
    ("case", "heard_fn", "the_view", "expect"),
    [
        ("every kept frame answered", heard(3), view(), []),
        ("still stood by for", heard(2), view(Role.STANDBY), []),
        ("owned by nobody here", heard(2), view(Role.NONE), []),
        ("nothing heard: the owner answered none", nobody, view(), [Ask(S)]),
        # The member that left answers its hand-off still: asked, not resolved alone.
        ("alone now", heard(2), view(members=(ME,)), [Ask(S)]),
    ],
)
def test_g13_who_is_asked_for_at_the_change(
    case: str, heard_fn: object, the_view: View, expect: list[object]
) -> None:
    m = standby_of(2, 3)
    assert m.promoted(lambda _: the_view, heard_fn, 1.0) == expect, case  # type: ignore[arg-type]
    if not expect:
        assert m.phase(S) is Phase.UNHELD


def test_g13_a_stream_asked_already_or_held_is_left_alone() -> None:
    m = standby_of(2, 3)
    assert m.frame(S, f(4), view(), 1.0) == [Ask(S)]  # its next frame came first
    assert m.promoted(lambda _: view(), heard(2), 1.0) == []
    h = machine()
    held(h, 3)
    assert h.promoted(lambda _: view(), heard(1), 1.0) == []


def test_g13_a_stream_just_released_to_a_member_not_seen_yet_is_not_taken_back() -> None:
    m = machine()
    held(m, 3)
    assert m.frame(S, f(4), view(Role.STANDBY), 0.0)[0] == Release(S, OTHER)
    m.released_as(S, snap(3), "c", 0.0)
    m.frame(S, f(5), view(), 0.5)  # kept: "c" is not in the view yet
    assert m.promoted(lambda _: view(), heard(3), 1.0) == []


def test_g13_a_sensor_stream_its_vehicle_fuses_now_is_left_to_the_vehicle() -> None:
    # Kept as the sensor's own stream before fusion was on in the group: the vehicle's
    # takeover takes those frames (G11); asking for the sensor's own would publish them twice.
    m = standby_of(2, 3)
    assert m.promoted(lambda _: view(), heard(2), 1.0, current=lambda s: s != S) == []
    assert m.phase(S) is Phase.UNHELD


# ---------------------------------------------------------------------- G14
def test_g14_a_fresh_sensors_start_replays_its_vehicles_whole_cache_first() -> None:
    # zenoh-ext 1.10 delivered frame 1 live and dropped 0 from the history (1 in 40 replays).
    m = machine()
    assert m.frame(S, f(1), view(members=(ME,)), 0.0) == [Resolve(S)]
    assert m.frame(S, f(2), view(members=(ME,)), 0.0) == []  # waits behind the cache
    m.answered(S, [], nobody)
    assert m.adopted(S, None, frozenset({"lidar"})) == [FetchCache(S)]
    assert m.phase(S) is Phase.FILLING
    acts = m.cached(S, [f(2), f(0), f(1), f(3)])  # any order; 2 waited, 1 came live
    assert tracked(acts) == [(0, True), (1, True), (2, True), (3, True)]
    assert m.frame(S, f(3), view(members=(ME,)), 0.0) == [Skip(S, f(3))]  # its live copy
    assert tracked(m.frame(S, f(4), view(members=(ME,)), 0.0)) == [(4, True)]


def test_g14_a_sensor_not_fresh_starts_at_its_first_frame() -> None:
    m = machine()
    assert m.frame(S, f(5), view(members=(ME,)), 0.0) == [Resolve(S)]
    m.answered(S, [], nobody)
    assert tracked(m.adopted(S, None)) == [(5, True)]


def test_g14_a_fresh_start_with_a_state_fills_only_its_gap() -> None:
    # A checkpoint exists: the state, not the cache's oldest frames, is where it starts.
    m = machine()
    assert m.frame(S, f(4), view(), 0.0) == [Ask(S)]
    t = m.answered(S, [snap(3)], nobody)
    cov = SensorCoverage(t.snapshot.last_seq, t.snapshot.last_stamp_ns, peek)  # type: ignore[union-attr]
    assert tracked(m.adopted(S, cov, frozenset({"lidar"}))) == [(4, True)]


def test_g14_a_fused_vehicles_fresh_sensor_replays_its_cache_not_the_others() -> None:
    m = machine()
    m.fused_sensors = ("lidar", "cam")
    v = "car/@vehicle"
    assert m.frame(v, f(2, LIDAR), view(), 0.0) == [Ask(v)]
    m.answered(v, [], nobody)
    assert m.adopted(v, None, frozenset({"lidar"})) == [FetchCache(v)]
    acts = m.cached(v, [f(0, CAM), f(1, CAM), f(0, LIDAR), f(1, LIDAR), f(2, LIDAR)])
    done = [(a.frame[0].split("/")[2], a.frame[1]) for a in acts if isinstance(a, Track)]
    assert done == [("lidar", 0), ("lidar", 1), ("lidar", 2)]


# ---------------------------------------------------------------------- G15
def r(seq: int, key: str = KEY, sn: int | None = None) -> Frame:
    """A frame of the restarted publisher's session: its seqs start again, its stamps go on
    after the old session's last (300); ``sn``: its Zenoh sequence number, as the vehicle's
    cache answers it (the same as its seq unless given; None: heard live)."""
    return (key, seq, 500 + seq * 100, seq if sn is None else sn)  # type: ignore[return-value]


def live(fr: Frame) -> Frame:
    return fr[:3]  # type: ignore[return-value]


def sn(fr: Frame) -> int | None:
    return fr[3] if len(fr) > 3 else None  # type: ignore[misc]


def restarted(first: Frame) -> CustodyMachine[Frame]:
    """S held with frames 1..3 (stamps up to 300); ``first`` is the restarted session's
    first frame heard: the cache is asked."""
    m = machine()
    held(m, 3)
    cov = RestartCoverage(SensorCoverage(3, 300, peek), KEY, sn, peek)
    assert m.refill(S, first, cov, 7) == [FetchCache(S)]
    assert m.phase(S) is Phase.FILLING
    return m


def test_g15_a_restarted_publishers_unheard_frames_are_tracked_first() -> None:
    m = restarted(live(r(5)))
    assert m.frame(S, live(r(6)), view(), 0.0) == []  # waits behind the cache
    acts = m.cached(S, [r(q) for q in (6, 2, 0, 5, 1, 4, 3)])  # any order, 5 and 6 too
    assert tracked(acts) == [(q, True) for q in range(7)]
    assert not any(isinstance(a, AnnounceMissed) for a in acts)
    assert tracked(m.frame(S, live(r(7)), view(), 0.0)) == [(7, True)]


@pytest.mark.parametrize(
    ("first", "cached", "missed"),
    [
        (5, [r(3), r(4), r(5)], 3),  # samples 0-2 gone
        (5, [r(2), r(4), r(5)], 3),  # and 3, between two the cache kept
        (8, [r(6, sn=2), r(7, sn=3), r(8, sn=4)], 2),  # resumed at 4: its samples 0-1 gone
        (5003, [r(q, sn=q - 5000) for q in range(5000, 5004)], 0),  # a counter of its own
        (5, [], 0),  # no cache (a plain put): nothing to tell it by
    ],
)
def test_g15_what_the_cache_no_longer_keeps_is_announced_on_the_restarted_sensor(
    first: int, cached: list[Frame], missed: int
) -> None:
    m = restarted(live(r(first)))
    acts = m.cached(S, cached)
    announced = [a for a in acts if isinstance(a, AnnounceMissed)]
    assert announced == ([AnnounceMissed(S, missed, "lidar")] if missed else [])
    assert tracked(acts) == [(q, True) for q in sorted({*(c[1] for c in cached), first})]
    assert not any(isinstance(a, RaiseIds) for a in acts)  # the state's own ids go on


def test_g15_each_session_is_asked_once_and_only_of_a_stream_held() -> None:
    m = restarted(live(r(5)))
    cov = RestartCoverage(SensorCoverage(3, 300, peek), KEY, sn, peek)
    assert m.refill(S, live(r(6)), cov, 7) is None  # filling already
    m.cached(S, [r(4), r(5)])  # 0-3 gone: the session's frames go on from 4
    assert m.refill(S, live(r(9)), cov, 8) is None  # catching up: a copy of 5 may still come
    assert tracked(m.frame(S, live(r(6)), view(), 0.0)) == [(6, True)]  # past it: held
    assert m.refill(S, live(r(7)), cov, 7) is None  # this session was asked for: as is
    assert m.refill(S, live(r(9)), cov, 8) == [FetchCache(S)]  # another restart: asked again
    fresh = machine()
    assert fresh.refill(S, live(r(5)), cov, 7) is None  # not held: the takeover's to answer
    assert fresh.frame(S, live(r(5)), view(), 0.0) == [Ask(S)]
    assert fresh.refill(S, live(r(6)), cov, 7) is None  # asking


def test_g15_a_fused_vehicles_restarted_sensor_is_filled_not_its_others() -> None:
    m = machine()
    m.fused_sensors = ("lidar", "cam")
    v = "car/@vehicle"
    assert m.frame(v, f(1, LIDAR), view(), 0.0) == [Ask(v)]
    m.answered(v, [], nobody)
    m.adopted(v, None)
    for fr in (f(1, CAM), f(2, LIDAR), f(2, CAM), f(3, CAM)):
        m.frame(v, fr, view(), 0.0)
    assert m.phase(v) is Phase.HELD
    cov = RestartCoverage(UpTo(300), LIDAR, sn, peek)
    assert m.refill(v, live(r(4, LIDAR)), cov, 7) == [FetchCache(v)]
    assert m.frame(v, live(r(4, CAM)), view(), 0.0) == []  # the camera's frames wait too
    acts = m.cached(v, [f(2, CAM), f(3, CAM), r(2, LIDAR), r(3, LIDAR), r(4, LIDAR)])
    done = [(a.frame[0].split("/")[2], a.frame[1]) for a in acts if isinstance(a, Track)]
    assert done == [("lidar", 2), ("lidar", 3), ("lidar", 4), ("cam", 4)]
    assert [a for a in acts if isinstance(a, AnnounceMissed)] == [
        AnnounceMissed(v, 2, "lidar")  # samples 0 and 1 gone
    ]


def test_g15_a_fused_vehicle_still_catching_up_on_a_silent_sensor_is_refilled_too() -> None:
    # Taken over from a state, it catches up until each sensor is past it: the camera never
    # is once it went silent, and the lidar's restart must not wait for it.
    m, v, lidar, _ = filling_vehicle(f(5, LIDAR))
    m.cached(v, [f(4, lidar)])
    assert m.frame(v, f(6, lidar), view(), 0.0) == [Track(v, f(6, lidar))]
    assert m.phase(v) is Phase.CATCHING_UP  # the camera: silent
    after = [(LIDAR, q, 700 + q * 100, q) for q in range(10)]  # stamped after the state's 600
    cov = RestartCoverage(UpTo(600), LIDAR, sn, peek)
    assert m.refill(v, live(after[9]), cov, 7) == [FetchCache(v)]  # type: ignore[arg-type]
    acts = m.cached(v, after)  # type: ignore[arg-type]
    assert [a.frame[1] for a in acts if isinstance(a, Track)] == list(range(10))
