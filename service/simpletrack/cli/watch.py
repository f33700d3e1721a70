"""``simpletrack watch``: a live table of the track frames a planner would receive."""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from types import FrameType
from typing import TYPE_CHECKING, Any

import numpy as np
import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.client.subscriber import TrackMessage, TrackSubscriber
from simpletrack.wire import WireTrackState

if TYPE_CHECKING:  # rich draws the live table where it is installed (the service extra)
    from rich.console import Group

EPILOG = f"""\
One row per stream (vehicle/sensor): last seq, frames received, rate, latency from the sensor
stamp to arrival here (p50/p99 of the last 200 frames; meaningful when sensors stamp with
wall-clock time; a negative one, or one over a minute, is marked "!" with the likely cause:
the stamps are on another clock, or replayed), tracks by state. With --detail VEHICLE/SENSOR (or when one stream matches),
also that stream's tracks, nearest first. Not on a terminal: one line per stream every
--interval seconds. Ends on Ctrl-C (exit 0) or after --duration.

{ZENOH_NOTE}

examples:
  simpletrack watch                                  # the whole fleet
  simpletrack watch --keys 'fleet/veh01/*/tracks'    # one vehicle
  simpletrack watch --detail veh01/lidar --rows 25   # and that sensor's tracks
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "watch",
        help="live terminal table of the tracks a planner receives",
        description="Subscribe to track frames by key expression and show them live.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument("--keys", help="key expression (default: <prefix>/*/*/tracks, the whole fleet)")
    p.add_argument("--detail", metavar="VEHICLE/SENSOR", help="also list this stream's tracks")
    p.add_argument("--rows", type=int, default=15, help="tracks listed in the detail (15)")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--interval", type=float, default=2.0, help="seconds between plain lines (2)")
    add_client_args(p)
    p.set_defaults(func=run)


@dataclass
class StreamView:
    last: TrackMessage
    frames: int = 0
    latency: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=64))

    def add(self, msg: TrackMessage, now: float) -> None:
        self.last = msg
        self.frames += 1
        self.latency.append(msg.latency_s)
        self.arrivals.append(now)

    def rate(self, now: float) -> float:
        recent = [t for t in self.arrivals if now - t <= 3.0]
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9) if len(recent) > 1 else 0.0

    def states(self) -> tuple[int, int, int]:
        s = self.last.tracks.state
        return (
            int((s == WireTrackState.CONFIRMED).sum()),
            int((s == WireTrackState.TENTATIVE).sum()),
            int((s == WireTrackState.COASTING).sum()),
        )


# Beyond this a latency is no network's or queue's: the stamps are on another clock (a
# recording's, a sensor's not in sync).
FAR_BEHIND_MS = 60_000.0
AHEAD_HINT = "stamp ahead of receive time: clock offset or replay"
BEHIND_HINT = "stamp far behind receive time: clock offset or an old recording's stamps"


def latency_hint(ms: float) -> str | None:
    """Why a latency cannot be one (a frame cannot arrive before it was stamped), if so."""
    if ms < 0:
        return AHEAD_HINT
    if ms > FAR_BEHIND_MS:
        return BEHIND_HINT
    return None


def _quantile_ms(values: deque[float], q: float) -> float | None:
    if not values:
        return None
    return float(np.quantile(np.fromiter(values, float), q)) * 1e3


def latency_number(ms: float | None) -> str:
    """A latency with its unit, precise where precision means something."""
    if ms is None or not math.isfinite(ms):
        return "-"
    if abs(ms) < 100:
        return f"{ms:.1f} ms"
    if abs(ms) < 100_000:
        return f"{ms:.0f} ms"
    return f"{ms / 1e3:.0f} s"


def format_latency(ms: float | None) -> str:
    """``12.3 ms``, or ``-7505 ms (stamp ahead of receive time: ...)`` when it cannot be one."""
    text = latency_number(ms)
    hint = None if ms is None or not math.isfinite(ms) else latency_hint(ms)
    return f"{text} ({hint})" if hint else text


STREAM_COLUMNS = (
    "stream", "seq", "frames", "Hz", "p50", "p99", "confirmed", "tentative", "coasting", "frame",
    "age s",
)  # fmt: skip
TRACK_COLUMNS = ("id", "class", "x", "y", "yaw", "speed m/s", "score", "state", "hits", "age")
LEFT = {"stream", "frame", "class", "state"}


@dataclass(frozen=True, slots=True)
class Screen:
    """What one refresh shows, before it is drawn (by rich, or as plain text without it)."""

    title: str
    streams: list[list[str]]
    hints: list[str]
    detail_title: str | None = None
    tracks: list[list[str]] = field(default_factory=list)


def screen(
    views: dict[str, StreamView], keys: str, detail: str | None, rows: int, now: float
) -> Screen:
    hints: set[str] = set()

    def cell(ms: float | None) -> str:
        hint = None if ms is None or not math.isfinite(ms) else latency_hint(ms)
        if hint is None:
            return latency_number(ms)
        hints.add(hint)
        return f"{latency_number(ms)} !"

    streams = []
    for name, v in sorted(views.items()):
        confirmed, tentative, coasting = v.states()
        streams.append(
            [
                name,
                str(v.last.seq),
                str(v.frames),
                f"{v.rate(now):.1f}",
                cell(_quantile_ms(v.latency, 0.5)),
                cell(_quantile_ms(v.latency, 0.99)),
                str(confirmed),
                str(tentative),
                str(coasting),
                v.last.frame.frame_id,
                f"{(time.time_ns() - v.last.received_ns) * 1e-9:.1f}",
            ]
        )
    title = f"watching {keys}: {len(views)} stream(s)"
    chosen = detail or (next(iter(views)) if len(views) == 1 else None)
    if chosen not in views:
        return Screen(title, streams, sorted(hints))
    msg = views[chosen].last
    t = msg.tracks
    order = np.argsort(np.hypot(t.center[:, 0], t.center[:, 1]))[:rows]
    names = msg.class_names()
    tracks = [
        [
            str(int(t.id[i])),
            names[i],
            f"{t.center[i, 0]:.1f}",
            f"{t.center[i, 1]:.1f}",
            f"{t.yaw[i]:.2f}",
            f"{math.hypot(float(t.velocity[i, 0]), float(t.velocity[i, 1])):.1f}",
            f"{t.score[i]:.2f}",
            WireTrackState(int(t.state[i])).name.lower(),
            str(int(t.hits[i])),
            str(int(t.age[i])),
        ]
        for i in order.tolist()
    ]
    detail_title = f"{chosen} seq {msg.seq}: {len(t)} tracks, nearest first"
    return Screen(title, streams, sorted(hints), detail_title, tracks)


def render(shown: Screen) -> Group:
    """The screen as rich renderables."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    def table(columns: tuple[str, ...], rows: list[list[str]], title: str | None) -> Table:
        t = Table(title=title, header_style="bold")
        for name in columns:
            t.add_column(name, justify="left" if name in LEFT else "right")
        for row in rows:
            t.add_row(*row)
        return t

    parts: list[object] = [
        Text(shown.title, style="bold"),
        table(STREAM_COLUMNS, shown.streams, None),
    ]
    parts.extend(Text(f"! {hint}", style="yellow") for hint in shown.hints)
    if shown.detail_title is not None:
        parts.append(table(TRACK_COLUMNS, shown.tracks, shown.detail_title))
    return Group(*parts)  # type: ignore[arg-type]


def render_plain(shown: Screen) -> str:
    """The screen as fixed-width text (a terminal without rich)."""

    def table(columns: tuple[str, ...], rows: list[list[str]]) -> list[str]:
        widths = [max(len(r[k]) for r in [list(columns), *rows]) for k in range(len(columns))]

        def line(row: list[str] | tuple[str, ...]) -> str:
            cells = (
                c.ljust(w) if name in LEFT else c.rjust(w)
                for c, w, name in zip(row, widths, columns, strict=True)
            )
            return "  ".join(cells).rstrip()

        return [line(columns), *(line(r) for r in rows)]

    out = [shown.title, *table(STREAM_COLUMNS, shown.streams)]
    out.extend(f"! {hint}" for hint in shown.hints)
    if shown.detail_title is not None:
        out += ["", shown.detail_title, *table(TRACK_COLUMNS, shown.tracks)]
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    prefix = check_prefix(args.prefix)
    keys = args.keys or f"{prefix}/*/*/tracks"
    try:
        zenoh.KeyExpr(keys)
    except (zenoh.ZError, ValueError) as exc:
        raise UserError(f"--keys {keys!r} is not a valid key expression: {exc}") from None
    for flag in ("duration", "interval"):
        value = getattr(args, flag)
        if value is not None and value <= 0:
            raise UserError(f"--{flag} {value} must be positive")
    if args.rows < 1:
        raise UserError(f"--rows {args.rows} must be at least 1")
    options = client_options(args)
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    live, plain = _live_display()
    views: dict[str, StreamView] = {}
    started = time.monotonic()
    session = open_client_session(options)
    next_draw = started
    try:
        sub = TrackSubscriber(session, key_expr=keys, buffer=10_000)
        if live is not None:
            live.start()
        elif not plain:
            print(f"watching {keys}; Ctrl-C to stop", flush=True)
        while not stop.is_set():
            now = time.monotonic()
            if args.duration is not None and now - started >= args.duration:
                break
            msg = sub.recv(timeout=0.1)
            while msg is not None:
                name = f"{msg.vehicle}/{msg.sensor}"
                if name not in views:
                    views[name] = StreamView(msg)
                views[name].add(msg, time.monotonic())
                msg = sub.try_recv()
            now = time.monotonic()
            if now < next_draw:
                continue
            if live is not None or plain:
                shown = screen(views, keys, args.detail, args.rows, now)
                if live is not None:
                    live.update(render(shown), refresh=True)
                else:  # home, clear to the end, draw
                    print("\x1b[H\x1b[J" + render_plain(shown), flush=True)
                next_draw = now + 0.25
            else:
                for name, v in sorted(views.items()):
                    c, t, k = v.states()
                    print(
                        f"{name} seq {v.last.seq} frames {v.frames} {v.rate(now):.1f} Hz "
                        f"p50 {format_latency(_quantile_ms(v.latency, 0.5))} tracks {c} confirmed, {t} tentative, "
                        f"{k} coasting",
                        flush=True,
                    )
                next_draw = now + args.interval
        sub.close()
    finally:
        if live is not None:
            live.stop()
        session.close()  # type: ignore[no-untyped-call]
        for s, handler in previous.items():
            signal.signal(s, handler)
    total = sum(v.frames for v in views.values())
    print(
        f"watch: {total} frames from {len(views)} stream(s) in {time.monotonic() - started:.1f} s"
    )
    sys.stdout.flush()
    return 0


def _live_display() -> tuple[Any, bool]:
    """(rich's Live, False) on a terminal with rich; (None, True) on a terminal without it
    (plain redraws); (None, False) when not on a terminal (a line per stream)."""
    if not sys.stdout.isatty():
        return None, False
    try:
        from rich.console import Console
        from rich.live import Live
    except ModuleNotFoundError:
        return None, True
    return Live(console=Console(), auto_refresh=False), False
