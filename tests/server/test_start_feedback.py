"""What a starting service tells its operator while it is not ready yet: a cold kernel cache's
compile (tens of seconds at the first start after an install) is logged before and after,
and /readyz's 503 says why."""

from __future__ import annotations

import logging
import urllib.error
import urllib.request
from collections.abc import Iterator

import pytest

from simpletrack.core import jit
from simpletrack.server import app
from simpletrack.server.app import Service
from simpletrack.server.settings import load_settings
from tests.service_helpers import LogEvents, log_events


@pytest.fixture
def events() -> Iterator[LogEvents]:
    with log_events("simpletrack.service") as handler:
        yield handler


def readyz(port: int) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=5) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def _service() -> Service:
    return Service(load_settings(None, {"metrics_port": 0, "instance": "feedback"}))


def test_a_cold_kernel_cache_is_logged_before_and_after_and_readyz_says_why(
    monkeypatch: pytest.MonkeyPatch, events: LogEvents
) -> None:
    service = _service()
    http = service._bind_http()  # port 0: any free port
    http.start()
    logged_before: list[str] = []
    during: list[tuple[int, str]] = []

    def compile_all() -> None:
        logged_before.extend(name for name, _, _ in events.events)
        during.append(readyz(http.port))

    monkeypatch.setattr(jit, "cache_state", lambda: jit.CacheState(14, 7, "/cache/here"))
    monkeypatch.setattr(jit, "preload", compile_all)
    try:
        assert readyz(http.port) == (503, "not ready: starting\n")
        service._load_kernels()
        assert readyz(http.port) == (503, "not ready: starting\n")
    finally:
        http.close()

    assert logged_before == ["compiling_kernels"]  # logged before the compile starts
    [(status, body)] = during
    assert status == 503 and body.startswith("not ready: compiling kernels"), body
    (name, level, fields), (done, done_level, done_fields) = events.events
    assert (name, level) == ("compiling_kernels", logging.INFO)
    assert fields["kernels"] == 7 and fields["of"] == 14 and fields["cache"] == "/cache/here"
    assert fields["estimate_s"] == round(app.COMPILE_ALL_S / 2)
    assert (done, done_level) == ("kernels_compiled", logging.INFO)
    assert done_fields["kernels"] == 7 and isinstance(done_fields["seconds"], float)


def test_a_warm_kernel_cache_logs_no_compile(
    monkeypatch: pytest.MonkeyPatch, events: LogEvents
) -> None:
    monkeypatch.setattr(jit, "cache_state", lambda: jit.CacheState(14, 0, "/cache/here"))
    monkeypatch.setattr(jit, "preload", lambda: None)
    _service()._load_kernels()
    assert [(name, level) for name, level, _ in events.events] == [
        ("kernels_loaded", logging.DEBUG)
    ]


def test_readyz_says_stopping_once_asked_to_stop() -> None:
    service = _service()
    assert service.not_ready_reason() == "starting"
    service.request_stop()
    assert service.not_ready_reason() == "stopping"
