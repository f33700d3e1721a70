"""``simpletrack view --foxglove``: the tracks as Foxglove 3D scenes, live, over the Foxglove
WebSocket protocol (foxglove-sdk's server; docs/VIEW.md, "Foxglove").

    from simpletrack.mcap.foxglove import foxglove_schema
    from simpletrack.mcap.scene import SceneConverter
    live = serve_foxglove(session, "fleet", "127.0.0.1", 8765,      # port 0: any free port
                          scenes=SceneConverter(), schema=foxglove_schema, detections=True)
    print(live.url); ...; live.close()

Subscribes to the same keys as the page (``<prefix>/*/*/tracks``, ``<prefix>/*/@vehicle/tracks``,
with ``detections`` ``<prefix>/*/*/detections``) and puts each frame on the channels a
recording has for it (``record --format mcap``): ``<key>/scene``, a ``foxglove.SceneUpdate`` of
its boxes, and ``<key>/tf``, a ``foxglove.FrameTransform`` of a detection frame's pose or
extrinsic. One channel per topic, advertised when its first frame comes; JSON messages with
the recorder's JSON Schemas. A layout made on a recording works live, and the other way round.

The scenes are the recorder's: ``scenes`` (``simpletrack.mcap.scene.SceneConverter``) and
``schema`` (``simpletrack.mcap.foxglove.foxglove_schema``) are passed in, as a tool the view
does not import (docs/ARCHITECTURE.md). foxglove-sdk is the optional ``foxglove`` extra,
imported only here and only when a server starts: ``simpletrack.view`` stays light.

Zenoh's callbacks only copy the payload into a bounded queue (the oldest sample goes when it
is full); one worker thread decodes, builds the scenes and hands them to the SDK, whose
server keeps a bounded backlog per client (a slow client loses old messages, not the view).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, Protocol

import msgpack
import zenoh

from simpletrack.view.server import PortInUse, _sensor_filters, plan
from simpletrack.wire.header import MAX_BYTES
from simpletrack.wire.keys import Keys

if TYPE_CHECKING:
    import foxglove

log = logging.getLogger(__name__)
DEFAULT_FOXGLOVE_PORT = 8765  # Foxglove's own default for a WebSocket data source
FOXGLOVE_EXTRA = "simpletrack-service[foxglove]"
SCENE_SUFFIX = "/scene"  # as record --format mcap names its channels
TF_SUFFIX = "/tf"
SCENE_SCHEMA = "foxglove.SceneUpdate"
TF_SCHEMA = "foxglove.FrameTransform"
QUEUE = 1024  # samples waiting for the worker: a few seconds of a busy fleet
MAX_CHANNELS = 10_000  # a flood of sensor names must not grow memory without end
_COMPACT: dict[str, Any] = {"ensure_ascii": False, "separators": (",", ":")}


class FoxgloveMissing(ImportError):
    """foxglove-sdk is not installed; the message says which extra brings it."""


class SceneBuilder(Protocol):
    """What turns a frame's plainly decoded msgpack map into (SceneUpdate, FrameTransform),
    each a JSON-ready dict or None: ``simpletrack.mcap.scene.SceneConverter``."""

    def convert(
        self, leaf: str, vehicle: str, sensor: str, frame: dict[str, Any]
    ) -> tuple[dict[str, Any] | None, dict[str, Any] | None]: ...


def import_foxglove() -> Any:
    """The ``foxglove`` module, or ``FoxgloveMissing`` naming the extra to install."""
    try:
        import foxglove
    except ImportError:
        raise FoxgloveMissing(
            f"foxglove-sdk is not installed: pip install '{FOXGLOVE_EXTRA}'"
        ) from None
    return foxglove


def foxglove_available() -> bool:
    try:
        import_foxglove()
    except FoxgloveMissing:
        return False
    return True


def _unpack(payload: bytes) -> dict[str, Any] | None:
    if len(payload) > MAX_BYTES:
        return None
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception:  # garbage of any kind: no scene
        return None
    return obj if isinstance(obj, dict) else None


def _dumps(value: dict[str, Any] | None) -> bytes | None:
    if value is None:
        return None
    try:  # a NaN box (only in a damaged frame) has no place in a scene
        return json.dumps(value, allow_nan=False, **_COMPACT).encode()
    except ValueError:
        return None


class FoxgloveLive:
    """The subscribers, the worker and the Foxglove WebSocket server; ``close()`` stops them
    (the session stays open). ``PortInUse`` when the port is taken, ``FoxgloveMissing``
    without foxglove-sdk, ``ValueError`` for a bad ``sensors`` filter."""

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str = "fleet",
        host: str = "127.0.0.1",
        port: int = DEFAULT_FOXGLOVE_PORT,
        *,
        scenes: SceneBuilder,
        schema: Callable[[str], bytes],
        sensors: Iterable[str] | None = None,
        detections: bool = False,
        name: str = "simpletrack view",
    ) -> None:
        self._closed = False
        self._subs: list[zenoh.Subscriber[None]] = []
        self._thread: threading.Thread | None = None
        filters = _sensor_filters(sensors)
        fg = import_foxglove()
        self._fg = fg
        self._scenes = scenes
        self._schemas = {s: schema(s) for s in (SCENE_SCHEMA, TF_SCHEMA)}
        self._keys = Keys(prefix)
        self._context: foxglove.Context = fg.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self._queue: deque[tuple[str, bytes]] = deque(maxlen=QUEUE)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.scenes_sent = 0  # SceneUpdate messages handed to the server
        self.dropped = 0  # samples the full queue let go (approximate)
        try:
            self._server = fg.start_server(name=name, host=host, port=port, context=self._context)
        except RuntimeError as exc:  # the SDK's FoxgloveError
            if "in use" in str(exc):
                raise PortInUse(f"foxglove port {port} on {host} is already in use") from None
            raise OSError(str(exc)) from None
        self.port = int(self._server.port)
        shown = "127.0.0.1" if host in ("", "0.0.0.0") else host
        shown = f"[{shown}]" if ":" in shown else shown
        self.url = f"ws://{shown}:{self.port}"
        try:
            for key in _key_exprs(prefix, filters, detections):
                self._subs.append(session.declare_subscriber(key, self._on_sample))
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(
            target=self._work, name=f"view-foxglove-{self.port}", daemon=True
        )
        self._thread.start()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Zenoh's thread: copy and go. A full deque drops its oldest sample.
        if len(self._queue) == QUEUE:
            self.dropped += 1
        self._queue.append((str(sample.key_expr), sample.payload.to_bytes()))
        self._wake.set()

    def _work(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            while self._queue and not self._stop.is_set():
                key, payload = self._queue.popleft()
                try:
                    self._publish(key, payload)
                except Exception:  # one bad frame must not end the stream
                    log.exception("foxglove: frame on %s not sent", key)

    def _publish(self, key: str, payload: bytes) -> None:
        names = self._keys.sensor_of(key)
        frame = _unpack(payload)
        if names is None or frame is None:
            return
        vehicle, sensor = names
        leaf = key.rsplit("/", 1)[1]
        scene, transform = self._scenes.convert(leaf, vehicle, sensor, frame)
        for topic, schema, value in (
            (key + SCENE_SUFFIX, SCENE_SCHEMA, scene),
            (key + TF_SUFFIX, TF_SCHEMA, transform),
        ):
            data = _dumps(value)
            if data is None:
                continue
            channel = self._channel(topic, schema)
            if channel is not None:
                channel.log(data)
                if schema == SCENE_SCHEMA:
                    self.scenes_sent += 1

    def _channel(self, topic: str, schema: str) -> foxglove.Channel | None:
        channel = self._channels.get(topic)
        if channel is None:
            if len(self._channels) >= MAX_CHANNELS:
                return None
            channel = self._fg.Channel(
                topic,
                schema=self._fg.Schema(
                    name=schema, encoding="jsonschema", data=self._schemas[schema]
                ),
                message_encoding="json",
                context=self._context,
            )
            self._channels[topic] = channel
        return channel

    def topics(self) -> list[str]:
        """The channels advertised so far."""
        return sorted(self._channels)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for sub in self._subs:
            with contextlib.suppress(Exception):  # already gone with its session
                sub.undeclare()  # type: ignore[no-untyped-call]
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(5)
        server = getattr(self, "_server", None)
        if server is not None:
            server.stop()
        for channel in self._channels.values():
            with contextlib.suppress(Exception):
                channel.close()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _key_exprs(prefix: str, filters: list[tuple[str, str]], detections: bool) -> list[str]:
    """The key expressions of the page's subscriptions (``plan``), each once."""
    keys, subscribed = Keys(prefix), plan(filters, detections)
    return (
        [keys.tracks(v, s) for v, s in subscribed.tracks]
        + [keys.vehicle_tracks(v) for v in subscribed.vehicles]
        + [keys.detections(v, s) for v, s in subscribed.detections]
    )


def serve_foxglove(
    session: zenoh.Session,
    prefix: str = "fleet",
    host: str = "127.0.0.1",
    port: int = DEFAULT_FOXGLOVE_PORT,
    **kwargs: Any,
) -> FoxgloveLive:
    """Start the Foxglove channel on ``session`` (kept open by ``close()``). Keyword
    arguments: ``scenes`` and ``schema`` (required, see the module), ``sensors``,
    ``detections``, ``name``."""
    return FoxgloveLive(session, prefix, host, port, **kwargs)
