"""``simpletrack view``: a live bird's-eye view of tracks in the browser (docs/VIEW.md).

    from simpletrack.view import serve_view
    view = serve_view(session, "fleet", "127.0.0.1", 8090)   # on an open Zenoh session
    print(view.url); ...; view.close()

Light like ``simpletrack.client``: the standard library's HTTP server, no web framework. The
same frames as Foxglove 3D scenes, live: ``serve_foxglove`` (foxglove_live.py; needs the
``foxglove`` extra, imported only when it starts).
"""

from simpletrack.view.foxglove_live import (
    DEFAULT_FOXGLOVE_PORT,
    FoxgloveLive,
    FoxgloveMissing,
    serve_foxglove,
)
from simpletrack.view.server import DEFAULT_PORT, PortInUse, ViewServer, serve_view
from simpletrack.view.state import Fov, ViewState

__all__ = [
    "DEFAULT_FOXGLOVE_PORT",
    "DEFAULT_PORT",
    "Fov",
    "FoxgloveLive",
    "FoxgloveMissing",
    "PortInUse",
    "ViewServer",
    "ViewState",
    "serve_foxglove",
    "serve_view",
]
