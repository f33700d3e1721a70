"""Zenoh session options: explicit endpoints by default, or a Zenoh config file (TLS, ACL)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

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
    with pytest.raises(ValueError, match=r"nope\.json5"):
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


def test_only_options_given_explicitly_override_the_config_file(tmp_path: Path) -> None:
    f = _file(tmp_path, '{mode: "client", connect: {endpoints: ["tcp/10.9.9.9:7447"]}}')
    assert ZenohOptions(config_file=f).to_config().get_json("mode") == '"client"'
    explicit = ZenohOptions(config_file=f, mode=ZenohMode.PEER)
    assert explicit.to_config().get_json("mode") == '"peer"'
    assert explicit == ZenohOptions(config_file=str(f))  # same values; given is not compared


def test_settings_keep_what_the_config_file_says_unless_told(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    f = _file(tmp_path, '{mode: "client", connect: {endpoints: ["tcp/10.9.9.9:7447"]}}')
    monkeypatch.setenv("SIMPLETRACK_ZENOH__CONFIG_FILE", str(f))
    assert load_settings().zenoh.options().to_config().get_json("mode") == '"client"'
    monkeypatch.setenv("SIMPLETRACK_ZENOH__MODE", "peer")
    assert load_settings().zenoh.options().to_config().get_json("mode") == '"peer"'


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mode": "client"}, "client mode needs at least one --connect endpoint (a router)"),
        (
            {"mode": "client", "connect": ["tcp/a:1"], "listen": ["tcp/b:2"]},
            "client mode does not listen; drop --listen or use --mode peer",
        ),
        ({"listen": ["7447"]}, "endpoint '7447' must look like PROTO/ADDRESS"),
        ({"connect": ["ab"]}, "connect.0: String should have at least 3 characters"),
        ({"mode": "router"}, "mode: Input should be 'peer' or 'client'"),
        ({"connect_timeout_ms": -2}, "greater than or equal to -1"),
    ],
)
def test_bad_options_raise_value_errors_saying_what_is_wrong(
    kwargs: dict[str, object], message: str
) -> None:
    with pytest.raises(ValueError, match=None) as info:
        ZenohOptions(**kwargs)  # type: ignore[arg-type]
    assert message in str(info.value)


def test_options_are_immutable() -> None:
    o = ZenohOptions(connect=("tcp/127.0.0.1:7447",))
    assert o.connect == ["tcp/127.0.0.1:7447"] and o.given == {"connect"}
    with pytest.raises(AttributeError):
        o.mode = ZenohMode.CLIENT  # type: ignore[misc]


def test_a_lost_connection_is_retried_at_most_every_reconnect_max_ms(tmp_path: Path) -> None:
    retry = json.loads(ZenohOptions(reconnect_max_ms=500).to_config().get_json("connect/retry"))
    assert retry["period_max_ms"] == 500 and retry["period_init_ms"] <= 500
    # Over a config file only an explicit value is laid: the file may set its own retry.
    f = _file(tmp_path, '{mode: "peer", scouting: {multicast: {enabled: false}}}')
    assert ZenohOptions(config_file=f).to_config().get_json("connect/retry") == "null"
    with pytest.raises(ValueError, match="reconnect_max_ms"):
        ZenohOptions(reconnect_max_ms=10)


def test_a_config_file_can_make_a_session_a_client(tmp_path: Path) -> None:
    f = _file(tmp_path, '{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7447"]}}')
    assert ZenohOptions(config_file=f).is_client()
    assert not ZenohOptions(config_file=f, mode=ZenohMode.PEER).is_client()


def test_a_blocked_put_keeps_its_link_a_minute_unless_the_config_file_says_otherwise(
    tmp_path: Path,
) -> None:
    # Zenoh's 5 s default closed the link mid-burst and lost the queued frames (tests/faults).
    key = "transport/link/tx/queue/congestion_control/block/wait_before_close"
    assert json.loads(ZenohOptions().to_config().get_json(key)) == 60_000_000
    f = _file(
        tmp_path,
        "{transport: {link: {tx: {queue: {congestion_control: {block: {wait_before_close: 7}}}}}}}",
    )
    assert json.loads(ZenohOptions(config_file=f).to_config().get_json(key)) == 7
