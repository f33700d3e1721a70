"""``simpletrack view``: a live bird's-eye view of the tracks in the browser (docs/VIEW.md)."""

from __future__ import annotations

import argparse
import signal
import threading
from types import FrameType

import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.view import (
    DEFAULT_FOXGLOVE_PORT,
    DEFAULT_PORT,
    Fov,
    FoxgloveLive,
    FoxgloveMissing,
    PortInUse,
    ViewServer,
)
from simpletrack.view.foxglove_live import import_foxglove

EPILOG = f"""\
Subscribes to <prefix>/*/*/tracks and <prefix>/*/@vehicle/tracks like a planner (and to
detections with --detections) and serves a page drawing the chosen stream's tracks from
above: boxes by state, ids, heading, velocity, the ego pose (when frames carry one) and the
field of view given with --fov. A fused vehicle (<vehicle>/@vehicle, the page's first choice
when there is one) shows every fused sensor in a colour of its own: its field of view from
where it is mounted, its detections, its condition, and on each track which sensors last
updated it. Also GET /state.json (the latest frame of every stream) and /events
(Server-Sent Events, at most 10 pushes a second). Ends on Ctrl-C.

With --foxglove (the foxglove extra: pip install 'simpletrack-service[foxglove]') it also
serves the same frames to Foxglove over its WebSocket protocol, on --http-host: open a
connection to ws://HOST:PORT in Foxglove. Each stream gets the channels a recording has:
<key>/scene (foxglove.SceneUpdate, one entity per box) and <key>/tf (foxglove.FrameTransform
of a detection frame's pose or extrinsic), e.g. fleet/veh01/lidar/tracks/scene.

{ZENOH_NOTE}

examples:
  simpletrack view                                   # open the URL it prints
  simpletrack view --sensors veh01/lidar,veh02/'*' --detections
  simpletrack view --sensors veh01/@vehicle --detections --fov lidar=360:50 --fov camera=90:75
  simpletrack view --fov lidar=360:50 --fov front=100:70
  simpletrack view --detections --foxglove           # and ws://127.0.0.1:8765 for Foxglove
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "view",
        help="live bird's-eye view of the tracks in the browser",
        description="Serve a live bird's-eye view of the tracks (and detections) over HTTP.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument(
        "--sensors",
        metavar="V/S[,V/S...]",
        help="only these vehicle/sensor streams (either part may be *; vehicle/@vehicle: the "
        "vehicle's fused tracks and its sensors' detections); default all",
    )
    p.add_argument("--detections", action="store_true", help="also subscribe to detections")
    p.add_argument(
        "--fov",
        action="append",
        default=[],
        metavar="SENSOR=DEG:RANGE",
        help="draw this field of view (degrees, metres) for a sensor name or vehicle/sensor",
    )
    p.add_argument("--http-host", default="127.0.0.1", help="address to serve on (127.0.0.1)")
    p.add_argument(
        "--http-port", type=int, default=DEFAULT_PORT, help=f"port to serve on ({DEFAULT_PORT})"
    )
    p.add_argument(
        "--foxglove",
        nargs="?",
        type=int,
        const=DEFAULT_FOXGLOVE_PORT,
        metavar="PORT",
        help="also serve the frames as Foxglove 3D scenes over a WebSocket on --http-host "
        f"(port {DEFAULT_FOXGLOVE_PORT} when none is given; needs the foxglove extra)",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    add_client_args(p)
    p.set_defaults(func=run)


def parse_fov(values: list[str]) -> dict[str, Fov]:
    out = {}
    for value in values:
        name, eq, rest = value.partition("=")
        deg, colon, rng = rest.partition(":")
        try:
            fov = Fov(float(deg), float(rng))
        except ValueError:
            fov = None
        if not (eq and colon and name) or fov is None or not 0 < fov.deg <= 360 or fov.range_m <= 0:
            raise UserError(
                f"--fov {value!r} must look like SENSOR=DEG:RANGE, 0 < DEG <= 360, RANGE > 0"
            )
        out[name] = fov
    return out


def run(args: argparse.Namespace) -> int:
    prefix = check_prefix(args.prefix)
    sensors = [s for s in (args.sensors or "").split(",") if s] or None
    fov = parse_fov(args.fov)
    if not 0 <= args.http_port <= 65535:
        raise UserError(f"--http-port {args.http_port} must be between 0 and 65535")
    if args.foxglove is not None and not 0 <= args.foxglove <= 65535:
        raise UserError(f"--foxglove {args.foxglove} must be between 0 and 65535")
    if args.duration is not None and args.duration <= 0:
        raise UserError(f"--duration {args.duration} must be positive")
    if args.foxglove is not None:
        try:
            import_foxglove()  # before anything opens: a missing extra is one line
        except FoxgloveMissing as exc:
            raise UserError(f"--foxglove: {exc}") from None
    options = client_options(args)
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    session = open_client_session(options)
    try:
        try:
            view = ViewServer(
                session,
                prefix,
                args.http_host,
                args.http_port,
                sensors=sensors,
                detections=args.detections,
                fov=fov,
            )
        except PortInUse:
            raise UserError(
                f"--http-port {args.http_port} is already in use on {args.http_host}"
            ) from None
        except OSError as exc:
            raise UserError(
                f"cannot serve on --http-host {args.http_host} --http-port {args.http_port}: "
                f"{exc.strerror or exc}"
            ) from None
        except ValueError as exc:
            raise UserError(f"--sensors: {exc}") from None
        live = None
        try:
            if args.foxglove is not None:
                live = _start_foxglove(session, prefix, args, sensors)
            print(f"view: {view.url} (Ctrl-C to stop)", flush=True)
            if live is not None:
                print(f"foxglove: {live.url} (open connection > Foxglove WebSocket)", flush=True)
            stop.wait(args.duration)
        finally:
            if live is not None:
                live.close()
            view.close()
    finally:
        session.close()  # type: ignore[no-untyped-call]
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 0


def _start_foxglove(
    session: zenoh.Session, prefix: str, args: argparse.Namespace, sensors: list[str] | None
) -> FoxgloveLive:
    """The Foxglove channel with the recorder's scene builder and schemas."""
    from simpletrack.mcap.foxglove import foxglove_schema
    from simpletrack.mcap.scene import SceneConverter

    try:
        return FoxgloveLive(
            session,
            prefix,
            args.http_host,
            args.foxglove,
            scenes=SceneConverter(),
            schema=foxglove_schema,
            sensors=sensors,
            detections=args.detections,
        )
    except PortInUse:
        raise UserError(
            f"--foxglove {args.foxglove} is already in use on {args.http_host}"
        ) from None
    except OSError as exc:
        raise UserError(
            f"cannot serve --foxglove {args.foxglove} on --http-host {args.http_host}: {exc}"
        ) from None
