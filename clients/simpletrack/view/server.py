"""``serve_view``: the bird's-eye view's HTTP server on an existing Zenoh session.

    view = serve_view(session, "fleet", "127.0.0.1", 8090)   # port 0: any free port
    print(view.url); ...; view.close()

Subscribes to ``<prefix>/*/*/tracks`` (each sensor's tracks) and ``<prefix>/*/@vehicle/tracks``
(each fused vehicle's). Endpoints: ``/`` the page (one static file), ``/state.json`` every
stream's latest frame, ``/events?sensor=V/S`` (or ``V/@vehicle``) Server-Sent Events: the
chosen stream's latest frame, pushed when a new one came but at most ``MAX_PUSH_HZ`` times a
second. Nothing queues: a slow page just skips to the newest frame.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

import zenoh

from simpletrack.client.subscriber import TrackSubscriber, VehicleTrackSubscriber
from simpletrack.view.state import Fov, ViewState
from simpletrack.wire.keys import VEHICLE_STREAM, Keys

log = logging.getLogger(__name__)
MAX_PUSH_HZ = 10.0
KEEPALIVE_S = 15.0  # a comment line now and then: proxies and browsers keep the stream open
DEFAULT_PORT = 8090


class PortInUse(OSError):
    """The view's HTTP port is taken; the message names it."""


def _page() -> bytes:
    return resources.files("simpletrack.view").joinpath("page.html").read_bytes()


def _sensor_filters(sensors: Iterable[str] | None) -> list[tuple[str, str]]:
    """``vehicle/sensor`` names (either may be ``*``; the sensor may be ``@vehicle``, a
    vehicle's fused stream) as pairs; ``[("*", "*")]`` for all."""
    out = []
    for name in sensors or ["*/*"]:
        vehicle, sep, sensor = name.partition("/")
        if not sep or not vehicle or not sensor or "/" in sensor:
            raise ValueError(f"sensor {name!r} must look like VEHICLE/SENSOR (either may be *)")
        out.append((vehicle, sensor))
    return out


@dataclass(frozen=True, slots=True)
class Plan:
    """What the view subscribes to for its sensor filters, each once: sensors' tracks
    (vehicle, sensor), fused vehicles' tracks (vehicle) and, with detections, detection
    key patterns (vehicle, sensor; a fused vehicle's: those of all its sensors). A ``*``
    sensor never matches the verbatim ``@vehicle``: it brings the vehicle's fused tracks
    as well. The page and the Foxglove channel both subscribe by it."""

    tracks: list[tuple[str, str]]
    vehicles: list[str]
    detections: list[tuple[str, str]]


def plan(filters: list[tuple[str, str]], detections: bool) -> Plan:
    tracks: dict[tuple[str, str], None] = {}
    vehicles: dict[str, None] = {}
    dets: dict[tuple[str, str], None] = {}
    for vehicle, sensor in filters:
        fused = sensor == VEHICLE_STREAM
        if not fused:
            tracks[vehicle, sensor] = None
        if fused or sensor == "*":
            vehicles[vehicle] = None
        if detections:
            dets[vehicle, "*" if fused else sensor] = None
    return Plan(list(tracks), list(vehicles), list(dets))


class ViewServer:
    """The view's subscribers and HTTP server; ``close()`` stops both (the session stays)."""

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str = "fleet",
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        *,
        sensors: Iterable[str] | None = None,
        detections: bool = False,
        fov: Mapping[str, Fov] | None = None,
    ) -> None:
        filters = _sensor_filters(sensors)
        self.state = ViewState(fov, detections)
        # Bound first: a taken port fails before anything subscribes.
        try:
            self._httpd = _Httpd((host, port), _Handler, self.state)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise PortInUse(f"http port {port} on {host} is already in use") from None
            raise
        self.port = int(self._httpd.server_address[1])
        # A wildcard address is reachable here at the loopback one; IPv6 literals need [].
        shown = "127.0.0.1" if host in ("", "0.0.0.0") else host
        shown = f"[{shown}]" if ":" in shown else shown
        self.url = f"http://{shown}:{self.port}/"
        self._keys = Keys(prefix)
        self._subs: list[TrackSubscriber | VehicleTrackSubscriber] = []
        self._det_subs: list[zenoh.Subscriber[None]] = []
        subscribed = plan(filters, detections)
        try:
            for vehicle, sensor in subscribed.tracks:
                self._subs.append(
                    TrackSubscriber(
                        session,
                        vehicle=vehicle,
                        sensor=sensor,
                        prefix=prefix,
                        callback=self.state.add_tracks,
                    )
                )
            for vehicle in subscribed.vehicles:
                self._subs.append(
                    VehicleTrackSubscriber(
                        session,
                        vehicle=vehicle,
                        prefix=prefix,
                        callback=self.state.add_vehicle_tracks,
                    )
                )
            for vehicle, sensor in subscribed.detections:
                key = self._keys.detections(vehicle, sensor)
                self._det_subs.append(session.declare_subscriber(key, self._on_detections))
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True
        )
        self._thread.name = f"view-http-{self.port}"
        self._thread.start()
        self._closed = False

    def _on_detections(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        names = self._keys.sensor_of(str(sample.key_expr))
        if names is not None:
            self.state.add_detections("/".join(names), sample.payload.to_bytes(), received)

    def close(self) -> None:
        if getattr(self, "_closed", False):
            return
        self._closed = True
        self.state.close()  # wakes every event stream
        for sub in self._subs:
            sub.close()
        for det in self._det_subs:
            with contextlib.suppress(Exception):  # already gone with its session
                det.undeclare()  # type: ignore[no-untyped-call]
        if getattr(self, "_thread", None) is not None:
            self._httpd.shutdown()
        self._httpd.server_close()

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve_view(
    session: zenoh.Session,
    prefix: str = "fleet",
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    **kwargs: Any,
) -> ViewServer:
    """Start the view on ``session`` (kept open by ``close()``); ``PortInUse`` if taken.
    Keyword arguments: ``sensors`` (VEHICLE/SENSOR filters), ``detections``, ``fov``."""
    return ViewServer(session, prefix, host, port, **kwargs)


class _Httpd(ThreadingHTTPServer):
    daemon_threads = True  # an open event stream must not hold the process at exit

    def __init__(self, address: tuple[str, int], handler: type[_Handler], state: ViewState) -> None:
        self.state = state
        self.page = _page()
        super().__init__(address, handler)


class _Handler(BaseHTTPRequestHandler):
    server: _Httpd
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s " + format, self.address_string(), *args)

    def do_GET(self) -> None:
        url = urlsplit(self.path)
        query = parse_qs(url.query)
        if url.path in ("/", "/index.html"):
            self._send(HTTPStatus.OK, "text/html; charset=utf-8", self.server.page)
        elif url.path == "/state.json":
            body = json.dumps(self.server.state.state_json()).encode()
            self._send(HTTPStatus.OK, "application/json", body)
        elif url.path == "/events":
            self._events(query.get("sensor", [None])[0])
        else:
            self._send(HTTPStatus.NOT_FOUND, "text/plain", b"not found\n")

    def _send(self, status: HTTPStatus, kind: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _events(self, chosen: str | None) -> None:
        state = self.server.state
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")  # the stream ends with the connection
        self.end_headers()
        self.close_connection = True
        seen = -1
        try:
            while not state.closed:
                version = state.wait_newer(seen, KEEPALIVE_S)
                if state.closed:
                    break
                if version == seen:
                    self.wfile.write(b": keepalive\n\n")
                else:
                    seen = version
                    data = json.dumps(state.event_json(chosen))
                    self.wfile.write(f"data: {data}\n\n".encode())
                self.wfile.flush()
                time.sleep(1.0 / MAX_PUSH_HZ)  # the bound on pushes: newer frames wait here
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page went away
