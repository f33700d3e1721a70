"""Zenoh session options: explicit endpoints by default, or a Zenoh config file (TLS, ACL)."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from simpletrack.server.settings import load_settings
from simpletrack.session import ZenohMode, ZenohOptions, open_session


def _file(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "zenoh.json5"
    p.write_text(body)
    return p


def test_defaults_listen_nowhere_and_never_scout() -> None:
    c = ZenohOptions().to_config()
    assert c.get_json("listen/endpoints") == "[]"
    assert c.get_json("scouting/multicast/enabled") == "false"


def test_a_config_file_is_the_base_and_given_options_override_it(tmp_path: Path) -> None:
    f = _file(
        tmp_path,
        '{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:0"]},'
        " scouting: {multicast: {enabled: false}}}",
    )
    c = ZenohOptions(config_file=f).to_config()
    assert c.get_json("listen/endpoints") == '["tcp/127.0.0.1:0"]'
    c = ZenohOptions(config_file=f, mode=ZenohMode.CLIENT, connect=["tcp/10.1.2.3:7447"])
    cfg = c.to_config()
    assert cfg.get_json("mode") == '"client"'
    assert cfg.get_json("connect/endpoints") == '["tcp/10.1.2.3:7447"]'
    with open_session(ZenohOptions(config_file=f)) as session:
        assert str(session.zid())


def test_clients_can_wait_for_their_router() -> None:
    o = ZenohOptions(mode=ZenohMode.CLIENT, connect=["tcp/127.0.0.1:7447"], connect_timeout_ms=-1)
    assert o.to_config().get_json("connect/timeout_ms") == "-1"


def test_a_missing_config_file_is_named_in_the_error(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match=r"nope\.json5"):
        ZenohOptions(config_file=tmp_path / "nope.json5")


def test_settings_take_the_config_file_from_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    f = _file(tmp_path, '{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:0"]}}')
    monkeypatch.setenv("SIMPLETRACK_ZENOH__CONFIG_FILE", str(f))
    monkeypatch.setenv("SIMPLETRACK_ZENOH__CONNECT_TIMEOUT_MS", "-1")
    s = load_settings()
    assert s.zenoh.config_file == f and s.zenoh.connect_timeout_ms == -1
    assert s.zenoh.listen == []  # the file says where to listen
