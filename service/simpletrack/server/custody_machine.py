"""A stream's custody in the group as one pure state machine (docs/SCALE.md).

A stream (server/streams.py: a sensor's own, or a fused vehicle's) is, on one member, in one
``Phase``; events come in (a frame, the group's answers, the vehicle's cache, a hand-off
asked, a checkpoint, the group changed, a beat of the worker's clock, a restart's
snapshots) and actions come out (track, track without publishing, keep, ask, fetch the
cache, release, announce missed, stash). The worker and the app carry the actions out
(Zenoh, the registry, the trackers); this module imports no Zenoh and reads no clock:
``now`` is always passed in. Its table tests are ``tests/server/test_custody_machine.py``.

Frames are opaque to it (``F``): ``peek(frame) -> (key, seq, stamp_ns)`` reads what it needs.
Only the worker's thread calls it.
"""

from __future__ import annotations

import hashlib
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Generic, Protocol, TypeVar

from simpletrack.wire.keys import VEHICLE_STREAM
from simpletrack.wire.models import SensorSnapshot
from simpletrack.wire.reasons import ErrorReason

F = TypeVar("F")
Peek = Callable[[F], tuple[str, int | None, int | None]]  # frame -> (key, seq, stamp_ns)

# A stream released to a member this one cannot see yet (its token is on the way) is not
# taken back for this long: the views agree well within it.
RELEASE_GUARD_S = 2.0
RELEASED_KEPT_S = 60.0
MAX_STANDBY_STREAMS = 100_000
_RESTARTED_PUBLISHER = 100_000  # a seq jump this large is a new numbering, not a gap
_SESSIONS_KEPT = 8  # restarted publisher sessions remembered per stream (each asked once)
# Frames a sensor may publish between the newest one a takeover has and the cache's answer
# (they come live as well); a cache that answers as many frames as asked, holes still left,
# is asked for all it keeps.
FETCH_SLACK = 10
EPOCH_TAG_BITS = 16


def epoch_tag(instance: str) -> int:
    """The low bits of every epoch an instance gives: two members that took a stream over
    from the same state (each side of a partition) are ordered by name, never equal."""
    digest = hashlib.blake2b(instance.encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") & ((1 << EPOCH_TAG_BITS) - 1)


def next_epoch(instance: str, *before: int | None) -> int:
    """A stream's custody epoch when ``instance`` takes it: one takeover more than any epoch
    it had before (``before``: its state's, the last heard on its key), in the high bits."""
    count = max((e >> EPOCH_TAG_BITS for e in before if e is not None), default=0)
    return ((count + 1) << EPOCH_TAG_BITS) | epoch_tag(instance)


class Role(Enum):
    OWNER = "owner"
    STANDBY = "standby"
    NONE = "none"


class Phase(Enum):
    UNHELD = "unheld"  # not held here (never, released, or evicted)
    ASKING = "asking"  # owned, the group asked for its state: frames wait
    FILLING = "filling"  # state chosen, the vehicle's cache asked for the gap: frames wait
    CATCHING_UP = "catching_up"  # held; frames up to the state skipped, up to planners' quiet
    HELD = "held"
    FENCED = "fenced"  # was held when this process stopped past the lease: frames wait


class Source(Enum):
    """Where a taken-over stream's state came from."""

    HANDOFF = "handoff"  # the holder's exact state
    FAILOVER = "failover"  # the standby's checkpoint
    RESTORE = "restore"  # this member's state directory (or its own fenced state)
    LOST = "lost"  # another member published it and nobody has its state
    NEW = "new"
    # Held here all along: a restarted publisher's first frames reached no member (a vehicle
    # rebooted while its router was away), so its cache is asked for them.
    RESTARTED = "restarted"


# ---------------------------------------------------------------------- actions
@dataclass(frozen=True, slots=True)
class Track(Generic[F]):
    """Track the frame; ``publish`` False: planners have its tracks already."""

    stream: str
    frame: F
    publish: bool = True
    replayed: bool = False


@dataclass(frozen=True, slots=True)
class Skip(Generic[F]):
    stream: str
    frame: F  # the state holds it already


@dataclass(frozen=True, slots=True)
class Keep(Generic[F]):
    stream: str
    frame: F  # kept as the stream's standby


@dataclass(frozen=True, slots=True)
class NotOwned(Generic[F]):
    stream: str
    frame: F


@dataclass(frozen=True, slots=True)
class Drop(Generic[F]):
    stream: str
    frame: F
    reason: ErrorReason


@dataclass(frozen=True, slots=True)
class Ask:
    stream: str  # ask the group for its state (``answered`` follows)


@dataclass(frozen=True, slots=True)
class Resolve:
    stream: str  # nobody to ask: ``answered`` with no replies now


@dataclass(frozen=True, slots=True)
class FetchCache:
    """Ask the vehicle's cache for the gap (``cached`` follows): its ``newest`` frames (a cache
    answers the newest n, or all it keeps: None)."""

    stream: str
    newest: int | None = None


@dataclass(frozen=True, slots=True)
class Release:
    stream: str
    to: str  # snapshot it, forget it here (``released`` records the snapshot)


@dataclass(frozen=True, slots=True)
class Stash:
    stream: str  # fenced: snapshot it as this member's local state, forget it, publish nothing


@dataclass(frozen=True, slots=True)
class Resend:
    """Publish a stream's last message again, as it was (its epoch the old one)."""

    stream: str
    payload: bytes


@dataclass(frozen=True, slots=True)
class Republish:
    """Publish the newest message heard on a stream's key again, as this member's (its
    instance and epoch): a failover's state holds that message's frame, and the dead holder
    may have written it to some links only (planners' readers drop a repeat)."""

    stream: str
    payload: bytes


@dataclass(frozen=True, slots=True)
class AnnounceMissed:
    stream: str
    frames: int
    restarted: str | None = None  # a restarted publisher's sensor (``refill``): its frames


@dataclass(frozen=True, slots=True)
class RaiseIds:
    """Tracks may have been born in frames nobody has: new ids start at or above ``floor``
    and at least an id block above the state's."""

    stream: str
    floor: int


Action = (
    Track[F] | Skip[F] | Keep[F] | NotOwned[F] | Drop[F] | Ask | Resolve | FetchCache | Release
    | Stash | Resend | Republish | AnnounceMissed | RaiseIds
)  # fmt: skip


# ---------------------------------------------------------------------- inputs
@dataclass(frozen=True, slots=True)
class View:
    """The group as the member sees it when an event comes."""

    me: str
    members: frozenset[str]
    role: Role
    owner: str


@dataclass(frozen=True, slots=True)
class Heard:
    """The latest tracks message heard on a stream's key, from any member."""

    stamp_ns: int
    next_id: int  # above every id heard on the key
    seq: int | None = None  # a fused vehicle's message seq (its own counter)
    epoch: int | None = None
    payload: bytes | None = None  # the newest message heard, as it came


class Coverage(Protocol[F]):  # type: ignore[misc]
    """What a taken-over state already holds (a fused vehicle's is per sensor)."""

    def covers(self, frame: F) -> bool: ...

    def holes(self, frames: Iterable[F]) -> int: ...


@dataclass(slots=True)
class SensorCoverage(Generic[F]):
    """A sensor's state: frames up to its last stamp are in it."""

    last_seq: int | None
    last_stamp_ns: int | None
    peek: Peek[F]

    def covers(self, frame: F) -> bool:
        stamp = self.peek(frame)[2]
        return self.last_stamp_ns is not None and stamp is not None and stamp <= self.last_stamp_ns

    def holes(self, frames: Iterable[F]) -> int:
        """Seqs between the state's last and the newest frame that none of them has."""
        if self.last_seq is None:
            return 0
        seqs = {s for s in (self.peek(f)[1] for f in frames) if s is not None}
        top = max(seqs, default=self.last_seq)
        if top - self.last_seq > _RESTARTED_PUBLISHER:
            return 0
        return sum(1 for q in range(self.last_seq + 1, top + 1) if q not in seqs)

    def exact(self, frames: Iterable[F]) -> bool:
        """The frames after the state (by stamp) continue its seqs without a hole and
        without a new numbering (a restarted publisher): every frame tracked after the state
        is among them, so the replay gives the ids an uninterrupted run gave."""
        if self.last_seq is None:
            return False
        seqs = {q for f in frames if not self.covers(f) and (q := self.peek(f)[1]) is not None}
        if not seqs:
            return True  # nothing after the state: nothing to differ
        if min(seqs) <= self.last_seq or max(seqs) - self.last_seq > _RESTARTED_PUBLISHER:
            return False
        return seqs == set(range(self.last_seq + 1, max(seqs) + 1))


@dataclass(slots=True)
class RestartCoverage(Generic[F]):
    """A held stream's state when a restarted publisher's first frame heard here was not its
    first (``refill``): the state covers what it covers; the holes are the restarted
    sensor's (frames on ``key``) samples its publisher sent before the newest the vehicle's
    cache answered and that the cache no longer keeps. ``sn``: a cached frame's Zenoh
    sequence number (its publisher's first sample is 0, whatever seqs the frames carry: a
    new numbering, a resumed one, a counter of its own); None for a frame heard live."""

    inner: Coverage[F]
    key: str
    sn: Callable[[F], int | None]
    peek: Peek[F]

    def covers(self, frame: F) -> bool:
        return self.inner.covers(frame)

    def holes(self, frames: Iterable[F]) -> int:
        sns = {
            n
            for f in frames
            if self.peek(f)[0] == self.key and not self.inner.covers(f)
            and (n := self.sn(f)) is not None
        }  # fmt: skip
        return 0 if not sns else max(sns) + 1 - len(sns)


@dataclass(slots=True)
class Takeover(Generic[F]):
    """How a stream comes to this member."""

    stream: str
    source: Source
    snapshot: SensorSnapshot | None
    heard: Heard | None
    kept: list[F]  # the standby's frames (and a vehicle's sensors' own streams')
    coverage: Coverage[F] | None = None
    replay: list[F] = field(default_factory=list)
    missed: int = 0
    from_cache: int = 0
    exact_ids: bool = True  # the replay covers every seq since the state
    resend: bytes | None = None  # its own stash's last message, sent again first
    republish: bytes | None = None  # the newest message heard, which the state holds
    # A fused vehicle's sensors: the stamp each was answered up to on its own key (by a
    # member of before fusion); their frames up to it are skipped, wherever they come from.
    answered_upto: dict[str, int] = field(default_factory=dict)
    # Its sensors first published while this member ran (none of their frames tracked
    # anywhere): a fresh start replays every frame their vehicle's cache keeps.
    fresh: frozenset[str] = frozenset()

    @property
    def covered_stamp_ns(self) -> int | None:
        return None if self.snapshot is None else self.snapshot.last_stamp_ns

    def epoch(self, instance: str) -> int:
        """The stream's custody epoch from this takeover on (docs/SCALE.md, "Fencing")."""
        mine = None if self.snapshot is None else self.snapshot.epoch
        return next_epoch(instance, mine, None if self.heard is None else self.heard.epoch)

    @property
    def published_stamp_ns(self) -> int | None:
        """Planners have tracks up to it. The holder of a hand-off published all it heard; a
        member killed mid-put may have written its last tracks to some links only (Zenoh
        writes one link after another), so after a failover the last frame heard is
        published again and ``TrackSubscriber`` drops the repeat where it arrived before."""
        if self.heard is None:
            return None
        return self.heard.stamp_ns if self.source is Source.HANDOFF else self.heard.stamp_ns - 1

    @property
    def published_seq(self) -> int | None:
        """A fused vehicle's message seq planners have up to (as ``published_stamp_ns``)."""
        if self.heard is None or self.heard.seq is None:
            return None
        return self.heard.seq if self.source is Source.HANDOFF else self.heard.seq - 1


@dataclass(slots=True)
class _Stream(Generic[F]):
    phase: Phase = Phase.UNHELD
    waiting: deque[F] = field(default_factory=deque)  # frames behind a takeover
    takeover: Takeover[F] | None = None
    limits: tuple[int | None, int | None] = (None, None)  # (covered, published) stamps
    fenced_at: float | None = None
    borrowed: int = 0  # bytes of waiting frames kept on the budget
    # A fused vehicle catching up: its state, and the sensors none of whose frames came past
    # it yet, each with the stamps of its frames the takeover had (a new subscription's
    # history may bring one of them again after the takeover finished).
    held_by: Coverage[F] | None = None
    catching: dict[str, set[int]] = field(default_factory=dict)
    refilled: set[int] = field(default_factory=set)  # publisher sessions asked for (refill)


@dataclass(slots=True)
class _Standby(Generic[F]):
    checkpoint: SensorSnapshot | None = None
    final: bool = False  # the checkpoint is the one its holder sent as it stopped cleanly
    frames: deque[tuple[int | None, F]] = field(default_factory=deque)  # (stamp, frame)


@dataclass(frozen=True, slots=True)
class Released:
    snapshot: SensorSnapshot
    to: str
    at: float


@dataclass(frozen=True, slots=True)
class Limits:
    """The machine's bounds (the service's settings)."""

    standby_frames: int = 100  # frames kept per stream stood by for, and waiting per takeover
    fence_after_s: float = 5.0  # a beat later than this after the last: the process was stopped
    fence_hold_s: float = 1.0  # after a fence, how long frames wait before the group is asked


class Budget(Protocol):
    """Bytes a member may hold beyond its bounds (server/intake.py ``BurstBudget``)."""

    def take(self, n: int) -> bool: ...

    def give(self, n: int) -> None: ...


class CustodyMachine(Generic[F]):
    def __init__(
        self,
        peek: Peek[F],
        limits: Limits | None = None,
        budget: Budget | None = None,
        size: Callable[[F], int] = lambda frame: 0,
    ) -> None:
        """``budget`` and ``size``: frames waiting on a takeover past ``standby_frames`` are
        kept while the member's byte budget has room (a burst after a fence or an outage),
        and dropped, announced, only past it."""
        self.peek = peek
        self.limits = limits or Limits()
        self.budget, self.size = budget, size
        self._streams: dict[str, _Stream[F]] = {}
        self._standby: dict[str, _Standby[F]] = {}
        self.released: dict[str, Released] = {}
        # Snapshots of this member's own (state directory at a restart, or stashed at a
        # fence): a takeover's candidates when no holder answers.
        self.local: dict[str, SensorSnapshot] = {}
        self.fused_sensors: tuple[str, ...] = ()  # the sensors a vehicle's stream fuses
        self._beat: float | None = None
        self._members = 1  # members in the view at the last beat
        # Streams fenced since the beat that last found none still fenced: the worker beats
        # at every item it takes, and a walk over every held stream each time cost a frame
        # more the more streams a member holds.
        self._fenced: set[str] = set()
        self._resend: dict[str, bytes] = {}  # a stashed state's last message
        self.fences = 0

    # ------------------------------------------------------------------ queries
    def phase(self, stream: str) -> Phase:
        s = self._streams.get(stream)
        return Phase.UNHELD if s is None else s.phase

    def held(self) -> list[str]:
        return [k for k, s in self._streams.items() if s.phase in _HELD]

    def waiting(self, stream: str) -> list[F]:
        s = self._streams.get(stream)
        return [] if s is None else list(s.waiting)

    def busy(self) -> list[str]:
        """Streams whose takeover is under way (asked, or filling from the cache)."""
        return [k for k, s in self._streams.items() if s.phase in (Phase.ASKING, Phase.FILLING)]

    def role(self, stream: str, view: View, now: float) -> Role:
        """The view's role, but a stream just released to a member this one cannot see yet
        is stood by for (its frames kept in case the asker never shows up)."""
        if view.role is Role.OWNER:
            rel = self.released.get(stream)
            if rel is not None and rel.to not in view.members and now - rel.at < RELEASE_GUARD_S:
                return Role.STANDBY
        return view.role

    # ------------------------------------------------------------------ events
    def frame(self, stream: str, frame: F, view: View, now: float) -> list[Action[F]]:
        """A detection frame of the stream."""
        s = self._streams.get(stream)
        phase = Phase.UNHELD if s is None else s.phase
        role = self.role(stream, view, now)
        if role is not Role.OWNER:
            acts: list[Action[F]] = []
            if phase in _HELD:
                acts += self._release(stream, view.owner)
            if role is Role.STANDBY:
                self._keep(stream, frame)
                return [*acts, Keep(stream, frame)]
            return [*acts, NotOwned(stream, frame)]
        if s is None:
            s = self._streams[stream] = _Stream()
        if phase in (Phase.ASKING, Phase.FILLING, Phase.FENCED):
            return self._wait(stream, s, frame)
        if phase is Phase.UNHELD:
            s.phase = Phase.ASKING
            s.waiting = deque([frame])
            alone = len(view.members) <= 1 and not self.released
            return [Resolve(stream) if alone else Ask(stream)]
        if phase is Phase.CATCHING_UP:
            return [self._after_takeover(stream, s, frame)]
        return [Track(stream, frame)]

    def promoted(
        self,
        view_of: Callable[[str], View],
        heard: Callable[[str], Heard | None],
        now: float,
        current: Callable[[str], bool] = lambda stream: True,
    ) -> list[Action[F]]:
        """The group changed. A stream stood by for that this member owns now, with a kept
        frame newer than the last tracks heard on its key (the owner died, or left, before
        answering it), is asked for now: that frame waits for no other to start the
        takeover (its next frame may be a whole period away, 2 s at 0.5 Hz). The others ask
        at their next frame, as ever (nothing of theirs waits). ``current``: whether the
        stream's frames go to it now; a sensor's own stream kept from before its vehicle
        fused is not (the vehicle's takeover takes its frames)."""
        acts: list[Action[F]] = []
        for stream, held in self._standby.items():
            if not held.frames or self.phase(stream) is not Phase.UNHELD:
                continue
            if not current(stream):
                continue
            view = view_of(stream)
            if self.role(stream, view, now) is not Role.OWNER:
                continue
            last, newest = heard(stream), held.frames[-1][0]
            if last is not None and newest is not None and newest <= last.stamp_ns:
                continue
            s = self._streams.setdefault(stream, _Stream())
            s.phase = Phase.ASKING
            # Asked even when alone now: the member that left answers hand-offs after its
            # token is gone, with its exact state, while its final checkpoint may still wait
            # in the stream's lane behind this event (an older one would replay, and publish
            # again, frames planners have).
            acts.append(Ask(stream))
        return acts

    def answered(
        self,
        stream: str,
        replies: Sequence[SensorSnapshot],
        heard: Callable[[str], Heard | None],
    ) -> Takeover[F]:
        """The group answered (``replies``: the holder's state, if any). The state taken is
        the holder's, else the newest of the standby checkpoint and this member's own;
        ``heard(stream)``: the last tracks heard on a key. The caller adopts the snapshot,
        then calls ``adopted``."""
        s = self._streams.setdefault(stream, _Stream())
        self.released.pop(stream, None)
        standby = self._standby.get(stream)
        final = standby is not None and standby.final
        checkpoint, kept = self._take_standby(stream)
        vehicle, name = stream.split("/")
        answered_upto: dict[str, int] = {}
        if name == VEHICLE_STREAM:
            # Kept as the sensors' own streams before fusion was on in the group (a rolling
            # upgrade's last old member just left): those no member answered on the
            # sensor's own key are the vehicle's now. So for the frames that waited (the
            # vehicles' caches hand a new subscription their last ones).
            for sensor in self.fused_sensors:
                answered = heard(f"{vehicle}/{sensor}")
                upto = None if answered is None else answered.stamp_ns
                if upto is not None:
                    answered_upto[sensor] = upto
                kept += [
                    f for f in self._take_standby(f"{vehicle}/{sensor}")[1] if self._after(f, upto)
                ]
        snap, source = None, Source.NEW
        if replies:
            snap, source = max(replies, key=lambda r: r.written_ns), Source.HANDOFF
        else:
            local = self.local.pop(stream, None)
            candidates = [(c, Source.FAILOVER) for c in (checkpoint,) if c is not None]
            candidates += [(c, Source.RESTORE) for c in (local,) if c is not None]
            if candidates:
                snap, source = max(candidates, key=lambda c: c[0].written_ns)
        resend = self._resend.pop(stream, None)
        last = heard(stream)
        if source is Source.NEW and last is not None:
            # Another member published this stream's tracks and nobody has its state (it
            # died before its first checkpoint, or with its standby): tracks start afresh,
            # their ids above every one heard.
            source = Source.LOST
        t = Takeover(stream, source, snap, last, kept, answered_upto=answered_upto)
        if (
            source is Source.FAILOVER
            and not final
            and snap is not None
            and last is not None
            and last.payload is not None
            and snap.last_stamp_ns is not None
            and snap.last_stamp_ns >= last.stamp_ns
        ):
            # The checkpoint holds the newest frame heard answered: no replay publishes it
            # again, and the dead holder may have put it on this member's link (ahead of
            # the checkpoint) but not on the planners' (a SIGKILL between two links'
            # flushes: once in CI, a frame no planner got). Not after a final checkpoint:
            # its holder stopped cleanly, every message out, and a stop answers each frame
            # once.
            t.republish = last.payload
        if source is Source.RESTORE and resend is not None and snap is not None:
            # Its own stash taken back: sent again unless another member published the
            # stream with a higher epoch meanwhile (readers drop the old message then; that
            # member republished from the last one it heard).
            newer = last is not None and last.epoch is not None and last.epoch > (snap.epoch or 0)
            if not newer:
                t.resend = resend
        s.takeover = t
        return t

    def adopted(
        self, stream: str, coverage: Coverage[F] | None, fresh: frozenset[str] = frozenset()
    ) -> list[Action[F]]:
        """The state is in the registry (``coverage``: what it holds; None: a fresh start).
        The frames it lacks are those kept and waiting; a hole among them is asked of the
        vehicle's cache (restore, failover and hand-off alike) before the replay. A fresh
        start of sensors first published while this member runs (``fresh``, their names)
        asks the cache for all it keeps of them: a new subscription's history may lack the
        first (zenoh-ext 1.10 delivers a live frame ahead of the history still pending and
        then drops that history as old: seen once in 40 replays, silently)."""
        s = self._streams[stream]
        t = s.takeover
        assert t is not None, "adopted before answered"
        t.coverage = coverage
        if coverage is None:
            t.replay = list(t.kept)
            if fresh:
                t.fresh = fresh
                s.phase = Phase.FILLING
                return [FetchCache(stream)]
            return self._complete(stream, s, t)
        t.replay = [f for f in t.kept if not coverage.covers(f)]
        t.missed = coverage.holes([*t.replay, *s.waiting])
        if t.missed:
            s.phase = Phase.FILLING
            return [FetchCache(stream, self._newest(coverage, [*t.replay, *s.waiting]))]
        return self._complete(stream, s, t)

    def refill(
        self, stream: str, frame: F, coverage: Coverage[F], session: int
    ) -> list[Action[F]] | None:
        """A held stream's live ``frame`` is the first heard of a publisher ``session`` that
        published before it (its seq says so): the publisher restarted while no member heard
        it. The frame waits, with those after it, while the vehicle's cache is asked for all
        it keeps; then the frames the state lacks are tracked in stamp order and a hole
        left is announced (``cached``, as a takeover's). None: track the frame as it is
        (the stream is in a takeover here, or this session was asked for already)."""
        s = self._streams.get(stream)
        # A fused vehicle catches up until each of its sensors is past its state (a silent
        # camera: for good); a sensor's stream only until its next frame.
        simply_held = s is not None and (
            s.phase is Phase.HELD or (s.phase is Phase.CATCHING_UP and s.held_by is not None)
        )
        if s is None or not simply_held or session in s.refilled:
            return None
        if len(s.refilled) >= _SESSIONS_KEPT:
            s.refilled.clear()
        s.refilled.add(session)
        s.phase = Phase.FILLING
        s.takeover = Takeover(stream, Source.RESTARTED, None, None, [], coverage=coverage)
        s.waiting = deque([frame])
        return [FetchCache(stream)]

    def cached(self, stream: str, frames: Sequence[F], asked: int | None = None) -> list[Action[F]]:
        """The vehicle's cache answered (the frames it still keeps, any order; ``asked``: the
        ``newest`` of the question)."""
        s = self._streams.get(stream)
        if s is None or s.phase is not Phase.FILLING or s.takeover is None:
            return []  # finished already (at shutdown, without the cache)
        t = s.takeover
        cov = t.coverage
        have = {self._id(f) for f in [*t.replay, *s.waiting]}
        extra = [
            f
            for f in frames
            if (cov is None or not cov.covers(f))
            and self._id(f) not in have
            and (not t.fresh or self._sensor(f) in t.fresh)  # others' old frames: not again
        ]
        t.from_cache += len(extra)
        t.replay += extra
        if cov is not None:
            t.missed = cov.holes([*t.replay, *s.waiting])
        if t.missed and asked is not None and len(frames) >= asked:
            return [FetchCache(stream)]  # the cache may keep older ones: all of them
        return self._complete(stream, s, t)

    def _newest(self, cov: Coverage[F], frames: Sequence[F]) -> int | None:
        """How many of a cache's newest frames reach back to a sensor's state: from its last
        seq to the newest frame here, and ``FETCH_SLACK`` published since. A fused vehicle's
        sensors differ: all the cache keeps."""
        if not isinstance(cov, SensorCoverage) or cov.last_seq is None:
            return None
        seqs = [q for q in (self.peek(f)[1] for f in frames) if q is not None]
        top = max(seqs, default=cov.last_seq)
        if top - cov.last_seq > _RESTARTED_PUBLISHER:
            return None
        return max(0, top - cov.last_seq) + FETCH_SLACK

    def settle(self) -> list[Action[F]]:
        """At the end: takeovers still waiting finish with what they have."""
        acts: list[Action[F]] = []
        for stream, s in list(self._streams.items()):
            if s.phase is Phase.FILLING and s.takeover is not None:
                acts += self._complete(stream, s, s.takeover)
            elif s.phase in (Phase.ASKING, Phase.FENCED):
                acts.append(Resolve(stream))
        return acts

    def release_asked(self, stream: str, to: str, held: bool) -> list[Action[F]]:
        """A member that owns the stream in its view asks for it."""
        if not held:
            return []
        return self._release(stream, to)

    def released_as(self, stream: str, snap: SensorSnapshot, to: str, now: float) -> None:
        """The worker released the stream with this state (asked again: the same answer)."""
        self.released[stream] = Released(snap, to, now)

    def checkpoint(self, stream: str, snap: SensorSnapshot, final: bool = False) -> None:
        """The owner's state, for a stream this member stands by for (``final``: the one it
        sent as it stopped, after publishing every frame's tracks)."""
        if self.phase(stream) in _HELD:
            return
        held = self._standby_of(stream)
        if held is None:
            return
        old = held.checkpoint
        if old is not None and old.written_ns > snap.written_ns:
            return  # an older one overtaken on the way
        held.checkpoint, held.final = snap, final
        last = snap.last_stamp_ns
        if last is not None:
            while held.frames and (held.frames[0][0] or 0) <= last:
                held.frames.popleft()

    def gone(self, stream: str) -> None:
        """Evicted from the registry (silent): the next frame starts it again."""
        s = self._streams.get(stream)
        if s is not None and s.phase in _HELD:
            del self._streams[stream]

    def restart(self, snapshots: Iterable[SensorSnapshot]) -> None:
        """This member's state directory at start: each is a takeover's candidate, used when
        no member holds the stream (alone: always), the gap since it replayed first."""
        for snap in snapshots:
            key = f"{snap.vehicle}/{snap.sensor}"
            old = self.local.get(key)
            if old is None or old.written_ns < snap.written_ns:
                self.local[key] = snap

    def beat(self, now: float, view: View, connected_at: float | None = None) -> list[Action[F]]:
        """The worker's clock, at every turn of its loop. A beat later than ``fence_after_s``
        after the one before means this process was stopped (SIGSTOP, a frozen VM): the
        group may have taken its streams over, so it publishes nothing from them until it
        asked again (``Stash`` each held stream; its frames wait). Alone, nobody could have
        taken them: nothing is fenced. ``connected_at``: since when the member reaches the
        group again (a client: its router back; None: not now); frames of a fenced stream
        wait until then plus ``fence_hold_s`` (the group's tokens and answers are in)."""
        last, self._beat = self._beat, now
        # The group as it was before the gap: a resumed process may hear the others' tokens
        # go (its link closed while it was stopped) before its first beat.
        grouped = max(self._members, len(view.members)) > 1
        self._members = len(view.members)
        acts: list[Action[F]] = []
        if last is not None and now - last > self.limits.fence_after_s and grouped:
            self.fences += 1
            for stream, s in self._streams.items():
                if s.phase in _HELD:
                    acts.append(Stash(stream))
                    s.phase, s.fenced_at, s.limits = Phase.FENCED, now, (None, None)
                    s.held_by, s.catching = None, {}
                    self._fenced.add(stream)
            return acts
        if not self._fenced:
            return acts  # every item's beat, nothing fenced: no walk, no new set
        self._fenced = {k for k in self._fenced if self._is_fenced(k)}
        if not self._fenced:
            return acts
        for stream, s in self._streams.items():
            if s.phase is not Phase.FENCED or s.fenced_at is None or connected_at is None:
                continue
            if now - max(s.fenced_at, connected_at) < self.limits.fence_hold_s:
                continue
            if s.waiting:
                # Asked even when the view shows nobody else yet: this member was in a group
                # when it stopped, and a member that took the stream over must answer.
                s.phase = Phase.ASKING
                acts.append(Ask(stream))
            else:
                s.phase = Phase.UNHELD  # its next frame asks
        return acts

    def _is_fenced(self, stream: str) -> bool:
        s = self._streams.get(stream)
        return s is not None and s.phase is Phase.FENCED

    def superseded(self, stream: str, now: float) -> list[Action[F]]:
        """Another member published the stream with a higher epoch (it took the stream over
        while this one could not see it: a partition that healed, a pause): this member's
        state is stale. Fenced as after a stop: stashed, its frames wait, then it asks."""
        s = self._streams.get(stream)
        if s is None or s.phase not in _HELD:
            return []
        s.phase, s.fenced_at, s.limits = Phase.FENCED, now, (None, None)
        s.held_by, s.catching = None, {}
        self._fenced.add(stream)
        return [Stash(stream)]

    def requeue(self, stream: str, frames: Sequence[F]) -> None:
        """Frames a fenced stream had taken in but not applied (a fused vehicle's window):
        they wait again, before those that came since."""
        s = self._streams.get(stream)
        if s is not None:
            s.waiting.extendleft(reversed(frames))

    def stashed(self, stream: str, snap: SensorSnapshot, last: bytes | None = None) -> None:
        """The state a fence took from the registry: this member's own candidate, with the
        last message it published from it (``last``), which the stop may have cut off on
        its way: taken back, the state sends it again first (at least once)."""
        self.local[stream] = snap
        if last is not None:
            self._resend[stream] = last

    def housekeeping(self, now: float, role: Callable[[str], Role]) -> None:
        for key in [k for k, r in self.released.items() if now - r.at > RELEASED_KEPT_S]:
            del self.released[key]
        for key in [k for k in self._standby if role(k) is Role.NONE]:
            del self._standby[key]
        for key in [
            k for k, s in self._streams.items() if s.phase is Phase.UNHELD and not s.waiting
        ]:
            del self._streams[key]

    def standby_count(self) -> int:
        return len(self._standby)

    def standby_streams(self) -> list[str]:
        return list(self._standby)

    # ------------------------------------------------------------------ inside
    def _wait(self, stream: str, s: _Stream[F], frame: F) -> list[Action[F]]:
        s.waiting.append(frame)
        if len(s.waiting) <= self.limits.standby_frames:
            return []
        n = self.size(frame)
        if self.budget is not None and self.budget.take(n):
            s.borrowed += n
            return []
        return [Drop(stream, s.waiting.popleft(), ErrorReason.DROPPED_QUEUE_FULL)]

    def _settled(self, s: _Stream[F]) -> list[F]:
        """The frames that waited, handed back with the bytes they borrowed."""
        waiting = list(s.waiting)
        s.waiting.clear()
        if s.borrowed and self.budget is not None:
            self.budget.give(s.borrowed)
        s.borrowed = 0
        return waiting

    def _release(self, stream: str, to: str) -> list[Action[F]]:
        s = self._streams.pop(stream, None)
        if s is None or s.phase not in _HELD:
            return []
        return [Release(stream, to)]

    def _complete(self, stream: str, s: _Stream[F], t: Takeover[F]) -> list[Action[F]]:
        """Replay what the state lacks, then the frames that waited, one of each in stamp
        order; frames planners have tracks of are tracked without publishing."""
        acts: list[Action[F]] = []
        waiting = self._settled(s)
        s.takeover = None
        cov = t.coverage
        if isinstance(cov, SensorCoverage):
            t.exact_ids = cov.exact([*t.replay, *waiting])
        else:
            t.exact_ids = t.missed == 0
        if t.resend is not None:
            acts.append(Resend(stream, t.resend))
        if t.republish is not None:
            acts.append(Republish(stream, t.republish))
        if t.missed:
            restarted = _sensor_of(cov.key) if isinstance(cov, RestartCoverage) else None
            acts.append(AnnounceMissed(stream, t.missed, restarted))
        if t.snapshot is not None and (t.missed or not t.exact_ids):
            floor = 0 if t.heard is None else t.heard.next_id
            acts.append(RaiseIds(stream, floor))
        # In stamp order, ties as a fused vehicle's reorder buffer orders them (its sensors'
        # order, then seq): the taker's new buffer lets a replayed frame go at once when the
        # state's other sensors were silent, and one of another sensor stamped the same
        # coming after it would be late (a restored state has no history to re-process it
        # into). Each header is read once.
        order = {name: i for i, name in enumerate(self.fused_sensors)}
        heads = [(*self.peek(f), f) for f in [*t.replay, *waiting]]
        peeked = sorted(
            ((key, _sensor_of(key), seq, stamp, f) for key, seq, stamp, f in heads),
            key=lambda p: (p[3] or 0, order.get(p[1], len(order)), p[2] or 0),
        )
        frames: list[F] = []
        taken: list[tuple[str, int | None]] = []  # (sensor, stamp) of each of ``frames``
        seen: set[tuple[str, int]] = set()
        for key, sensor, _, stamp, f in peeked:
            if stamp is not None:
                if (key, stamp) in seen:
                    continue
                seen.add((key, stamp))
            frames.append(f)
            taken.append((sensor, stamp))
        s.phase = Phase.HELD
        if stream.endswith(f"/{VEHICLE_STREAM}"):
            # A fused vehicle's frames go through its reorder buffer, which sends no message
            # planners have (by its message seq). Those its state holds (a new owner's
            # subscription hands it the vehicle's last frames) are skipped here, as a
            # sensor's are: the sensor's order rules would refuse them, announced.
            acts += [
                Skip(stream, f)
                if (cov is not None and cov.covers(f)) or self._answered(t, f)
                else Track(stream, f, replayed=True)
                for f in frames
            ]
            if cov is not None and self.fused_sensors:
                s.phase, s.held_by = Phase.CATCHING_UP, cov
                s.catching = {sensor: set() for sensor in self.fused_sensors}
                for sensor, stamp in taken:
                    if sensor in s.catching and stamp is not None:
                        s.catching[sensor].add(stamp)
            return acts
        s.limits = (t.covered_stamp_ns, t.published_stamp_ns)
        s.phase = Phase.CATCHING_UP
        for f in frames:
            acts.append(
                self._after_takeover(stream, s, f)
                if s.phase is Phase.CATCHING_UP
                else Track(stream, f)
            )
        # A frame both replayed (a vehicle's cache, a standby's) and still on its way live is
        # in the state now: skip it then. Not so a frame that waited: it came live and never
        # comes again, and a later one stamped before it is for the ordering rules to answer
        # (skipped, a fresh sensor's frame stamped before its refused first frame went
        # unanswered: bench fuzz, seed 0).
        top = max((st for st in map(self._stamp, t.replay) if st is not None), default=None)
        if top is not None and s.phase is Phase.CATCHING_UP:
            covered, published = s.limits
            s.limits = (top if covered is None else max(covered, top), published)
        elif top is not None:
            s.phase, s.limits = Phase.CATCHING_UP, (top, t.published_stamp_ns)
        return acts

    def _after_takeover(self, stream: str, s: _Stream[F], frame: F) -> Action[F]:
        if s.held_by is not None:
            return self._vehicle_after_takeover(stream, s, frame, s.held_by)
        covered, published = s.limits
        stamp = self.peek(frame)[2]
        if stamp is None:
            return Track(stream, frame)
        if covered is not None and stamp <= covered:
            return Skip(stream, frame)
        if published is not None and stamp <= published:
            return Track(stream, frame, publish=False)
        s.phase, s.limits = Phase.HELD, (None, None)  # past both: like any frame from here
        return Track(stream, frame)

    def _vehicle_after_takeover(
        self, stream: str, s: _Stream[F], frame: F, cov: Coverage[F]
    ) -> Action[F]:
        """A fused vehicle's frame after its takeover: one its state holds, or one the
        takeover had (replayed or waiting: the cache's answer and a new subscription's
        history can both bring it), is a copy, skipped until its sensor's first other frame
        (from then on the sensor's order rules answer, as for any frame); all of them past,
        the stream is held as any."""
        sensor = self._sensor(frame)
        if sensor not in s.catching:
            return Track(stream, frame)
        if cov.covers(frame) or self._stamp(frame) in s.catching[sensor]:
            return Skip(stream, frame)
        del s.catching[sensor]
        if not s.catching:
            s.phase, s.held_by = Phase.HELD, None
        return Track(stream, frame)

    def _sensor(self, frame: F) -> str:
        return _sensor_of(self.peek(frame)[0])

    def _standby_of(self, stream: str) -> _Standby[F] | None:
        held = self._standby.get(stream)
        if held is None:
            if len(self._standby) >= MAX_STANDBY_STREAMS:
                return None
            held = self._standby[stream] = _Standby()
        return held

    def _keep(self, stream: str, frame: F) -> None:
        held = self._standby_of(stream)
        if held is None:
            return
        held.frames.append((self.peek(frame)[2], frame))
        if len(held.frames) > self.limits.standby_frames:
            held.frames.popleft()  # a takeover finds the gap and asks the vehicle's cache

    def _take_standby(self, stream: str) -> tuple[SensorSnapshot | None, list[F]]:
        held = self._standby.pop(stream, None)
        if held is None:
            return None, []
        return held.checkpoint, [f for _, f in held.frames]

    def _after(self, frame: F, stamp_ns: int | None) -> bool:
        if stamp_ns is None:
            return True
        stamp = self.peek(frame)[2]
        return stamp is None or stamp > stamp_ns

    def _answered(self, t: Takeover[F], frame: F) -> bool:
        """A fused sensor's frame its own key was answered for (``answered_upto``)."""
        if not t.answered_upto:
            return False
        stamp = self.peek(frame)[2]
        upto = t.answered_upto.get(self._sensor(frame))
        return upto is not None and stamp is not None and stamp <= upto

    def _stamp(self, frame: F) -> int | None:
        return self.peek(frame)[2]

    def _id(self, frame: F) -> tuple[str, int | None]:
        key, _, stamp = self.peek(frame)
        return key, stamp


_HELD = (Phase.HELD, Phase.CATCHING_UP)


def _sensor_of(key: str) -> str:
    """The sensor's name in a detections key (``<prefix>/<vehicle>/<sensor>/detections``)."""
    return key.rsplit("/", 2)[-2] if key.count("/") >= 2 else ""


__all__ = [
    "Action", "AnnounceMissed", "Ask", "Budget", "Coverage", "CustodyMachine", "Drop", "FetchCache",
    "Heard", "Keep", "Limits", "NotOwned", "Phase", "RaiseIds", "Release", "Released", "Republish",
    "Resend", "Resolve", "RestartCoverage", "Role", "SensorCoverage", "Skip", "Source", "Stash", "Takeover", "Track", "View",
    "epoch_tag", "next_epoch",
]  # fmt: skip
