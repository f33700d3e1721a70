"""Settings layering, validation messages, Zenoh options, the serve command's user errors,
and the generated docs tables."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest

from simpletrack.cli.main import main
from simpletrack.server.settings import Backpressure, ZenohSettings, load_settings, refresh_docs
from simpletrack.session import ZenohMode, ZenohOptions

ROOT = Path(__file__).resolve().parents[2]


def test_layers_defaults_then_file_then_env_then_flags(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = tmp_path / "s.toml"
    cfg.write_text(
        'workers = 3\nqueue_size = 5\nprefix = "file"\n[zenoh]\nconnect = ["tcp/10.0.0.1:7447"]\n'
    )
    monkeypatch.setenv("SIMPLETRACK_QUEUE_SIZE", "7")
    monkeypatch.setenv("SIMPLETRACK_PREFIX", "env")
    s = load_settings(cfg, {"prefix": "flag"})
    assert (s.workers, s.queue_size, s.prefix) == (3, 7, "flag")
    assert s.backpressure is Backpressure.DROP_OLDEST  # default
    # A peer listens on loopback unless told otherwise, whatever else the file says.
    assert s.zenoh.listen == ["tcp/127.0.0.1:7447"]
    assert s.zenoh.connect == ["tcp/10.0.0.1:7447"]


def test_yaml_file_and_nested_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text("zenoh:\n  mode: client\n  connect: [tcp/10.0.0.1:7447]\n")
    monkeypatch.setenv("SIMPLETRACK_ZENOH__CONNECT", '["tcp/10.0.0.2:7447"]')
    s = load_settings(cfg)
    assert s.zenoh.mode is ZenohMode.CLIENT
    assert s.zenoh.listen == [] and s.zenoh.connect == ["tcp/10.0.0.2:7447"]


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"workers": 0}, "workers: Input should be greater than or equal to 1 (got 0)"),
        ({"backpressure": "maybe"}, "(got 'maybe')"),
        ({"prefix": "a/*"}, "prefix"),
        ({"preset": "carla"}, "(got 'carla')"),
        ({"surprise": 1}, "surprise"),
        ({"zenoh": {"mode": "client"}}, "client mode needs at least one --connect"),
        ({"zenoh": {"listen": ["7447"]}}, "'7447' must look like PROTO/ADDRESS"),
    ],
)
def test_bad_settings_name_the_setting_and_value(overrides: dict[str, object], needle: str) -> None:
    with pytest.raises(ValueError, match=None) as info:
        load_settings(None, overrides)
    assert needle in str(info.value)


def test_zenoh_config_has_scouting_off_and_explicit_endpoints() -> None:
    config = ZenohOptions(listen=["tcp/127.0.0.1:7000"], connect=["tcp/127.0.0.1:7001"]).to_config()
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7000"]
    assert json.loads(config.get_json("mode")) == "peer"


def test_zenoh_settings_mirror_the_session_options() -> None:
    defaults = ZenohOptions()
    assert set(ZenohSettings.model_fields) == {f for f in defaults.__slots__ if f != "given"}
    built = ZenohSettings().options()
    assert built == defaults and built.given == frozenset()
    s = load_settings(None, {"zenoh": {"connect": ["tcp/10.0.0.3:7447"]}})
    assert s.zenoh.options().given == {"connect", "listen"}  # listen: the loopback default


def test_class_overrides_file(tmp_path: Path) -> None:
    good = tmp_path / "o.toml"
    good.write_text("[Car]\nscore_high = 0.6\nmax_age = 4\n")
    cfg = load_settings(None, {"class_overrides": good}).tracker_config()
    assert cfg.classes["Car"].score_high == 0.6 and cfg.classes["Car"].max_age == 4
    assert cfg.classes["Pedestrian"].score_high == 0.5
    bad = tmp_path / "b.toml"
    bad.write_text("[Tram]\nmax_age = 4\n")
    with pytest.raises(ValueError, match="class 'Tram' is not in preset 'kitti'"):
        load_settings(None, {"class_overrides": bad}).tracker_config()
    bad.write_text("[Car]\nmax_age = -1\n")
    with pytest.raises(ValueError, match="max_age"):
        load_settings(None, {"class_overrides": bad}).tracker_config()


def test_serve_user_errors_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["serve", "--workers", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("simpletrack serve: error: workers") and "\n" not in err

    assert main(["serve", "--config", str(tmp_path / "missing.toml")]) == 2
    assert "no such file" in capsys.readouterr().err

    assert main(["serve", "--mode", "client"]) == 2
    assert "--connect" in capsys.readouterr().err

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["serve", "--metrics-port", str(port), "--listen", "tcp/127.0.0.1:0"]) == 2
    err = capsys.readouterr().err
    assert "address already in use" in err.lower() and "Traceback" not in err


@pytest.mark.parametrize("doc", ["docs/SERVICE.md", "README.md"])
def test_docs_tables_are_generated_from_the_code(doc: str) -> None:
    text = (ROOT / doc).read_text()
    assert refresh_docs(text) == text, f"run: python -m simpletrack.server.settings --write {doc}"
    for name in ("backpressure", "snapshot_interval_s", "SIMPLETRACK_ZENOH__MODE"):
        assert name in text
    for name in ("simpletrack_frames_rejected_total", "simpletrack_end_to_end_seconds"):
        assert name in text
