"""``simpletrack view``: a live bird's-eye view of tracks in the browser (docs/VIEW.md).

    from simpletrack.view import serve_view
    view = serve_view(session, "fleet", "127.0.0.1", 8090)   # on an open Zenoh session
    print(view.url); ...; view.close()

Light like ``simpletrack.client``: the standard library's HTTP server, no web framework.
"""

from simpletrack.view.server import DEFAULT_PORT, PortInUse, ViewServer, serve_view
from simpletrack.view.state import Fov, ViewState

__all__ = ["DEFAULT_PORT", "Fov", "PortInUse", "ViewServer", "ViewState", "serve_view"]
