"""Zenoh session options: explicit endpoints by default, or a Zenoh config file (TLS, ACL)."""

from __future__ import annotations

import errno
import json
import socket
from pathlib import Path

import pytest
import zenoh

from simpletrack.server.settings import load_settings
from simpletrack.session import (
    ZenohMode,
    ZenohOptions,
    listen_error,
    open_session,
    without_rust_locations,
)


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


def test_a_listen_port_in_use_is_one_line_a_user_can_act_on() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        endpoint = f"tcp/127.0.0.1:{busy.getsockname()[1]}"
        with pytest.raises(zenoh.ZError) as info:
            open_session(ZenohOptions(listen=[endpoint])).close()  # type: ignore[no-untyped-call]
    assert listen_error(info.value) == (
        f"cannot listen on {endpoint}: the address is in use (another simpletrack service or "
        "a Zenoh router?); pass --listen with a free port"
    )
    assert ".rs:" not in without_rust_locations(info.value)


@pytest.mark.parametrize(
    ("message", "line"),
    [
        (  # Zenoh 1.x, word for word
            "Can not create a new TCP listener bound to tcp/10.255.255.1:7447: [10.255.255.1:7447: "
            f"Cannot assign requested address (os error {errno.EADDRNOTAVAIL}) at /root/.cargo/git/checkouts/zenoh-9c5"
            "/cc83980/io/zenoh-link-commons/src/tcp.rs:61.] at /root/.cargo/git/checkouts/zenoh-9c5"
            "/cc83980/io/zenoh-links/zenoh-link-tcp/src/unicast.rs:338.",
            "cannot listen on tcp/10.255.255.1:7447: no network interface of this machine has "
            "that address; pass --listen with one of its addresses (e.g. tcp/127.0.0.1:7447)",
        ),
        (
            "Can not create a new UDP listener bound to udp/[::1]:80: [Can not create a new UDP "
            f"listener on [::1]:80: Permission denied (os error {errno.EACCES}) at /x/unicast.rs:418.] at "
            "/x/unicast.rs:536.",
            "cannot listen on udp/[::1]:80: permission denied (a port below 1024 needs "
            "privileges); pass --listen with a higher port",
        ),
    ],
)
def test_other_listen_errors_say_what_to_change(message: str, line: str) -> None:
    assert listen_error(message) == line


def test_other_errors_keep_zenohs_words_without_its_source_paths() -> None:
    message = (
        "Unable to connect to any of [Single(tcp/127.0.0.1:1)]!  at /root/.cargo/git/checkouts/"
        "zenoh-9c599d5ef3e0480e/cc83980/zenoh/src/net/runtime/orchestrator.rs:447."
    )
    assert listen_error(message) is None
    assert (
        without_rust_locations(message) == "Unable to connect to any of [Single(tcp/127.0.0.1:1)]!"
    )
