"""A view on a real Zenoh session on 127.0.0.1 and a second session that puts frames to it."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import zenoh

from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.view import Fov, ViewServer, serve_view
from tests.view.frames import Sender


@dataclass
class Rig:
    view: ViewServer
    publisher: zenoh.Session

    def sender(self, vehicle: str, sensor: str, detections: bool = False) -> Sender:
        s = Sender(self.publisher, vehicle, sensor)
        s.wait_matched(detections)
        return s


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    """``@pytest.mark.parametrize("rig", [{"sensors": [...]}], indirect=True)`` passes
    serve_view keyword arguments; by default detections on, a 90 degree lidar field of view."""
    kwargs = getattr(request, "param", None) or {
        "detections": True,
        "fov": {"lidar": Fov(90.0, 30.0)},
    }
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view_session = open_session(mode="peer", listen=[endpoint])
    publisher = open_session(mode="peer", connect=[endpoint])
    view = serve_view(view_session, "fleet", "127.0.0.1", 0, **kwargs)
    try:
        yield Rig(view, publisher)
    finally:
        view.close()
        publisher.close()  # type: ignore[no-untyped-call]
        view_session.close()  # type: ignore[no-untyped-call]
