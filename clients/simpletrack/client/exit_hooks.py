"""Closing client sessions before the interpreter waits for threads at exit.

Zenoh runs each Python callback subscriber on a non-daemon thread of its own. At exit the
interpreter joins non-daemon threads *before* running ``atexit`` handlers, so a process that
forgets ``close()`` would hang forever. ``threading._register_atexit`` hooks run before that
join (it is how ``concurrent.futures`` stops its workers); we use it, falling back to
``atexit`` on interpreters without it.
"""

from __future__ import annotations

import atexit
import contextlib
import threading
import weakref
from typing import Protocol


class Closable(Protocol):
    def close(self) -> None: ...


_open: weakref.WeakSet[Closable] = weakref.WeakSet()
_lock = threading.Lock()
_registered = False


def _close_all() -> None:
    for obj in list(_open):
        # Best effort at exit: never turn shutdown into a traceback.
        with contextlib.suppress(Exception):
            obj.close()


def close_before_thread_join(obj: Closable) -> None:
    """Call ``obj.close()`` early in interpreter shutdown if it is still alive then. Objects are
    held weakly: registering many short-lived publishers keeps no memory."""
    global _registered
    with _lock:
        _open.add(obj)
        if _registered:
            return
        _registered = True
    register = getattr(threading, "_register_atexit", None)
    try:
        if register is None:
            raise RuntimeError("no threading._register_atexit")
        register(_close_all)
    except RuntimeError:  # an interpreter without the hook, or already shutting down
        atexit.register(_close_all)
