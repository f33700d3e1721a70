"""Settings layering, validation messages, Zenoh options, the serve command's user errors,
and the generated docs tables."""

from __future__ import annotations

import json
import re
import socket
from pathlib import Path

import pytest
from pydantic import BaseModel

from simpletrack.cli.main import build_parser, main
from simpletrack.cli.serve import settings_from_args
from simpletrack.core.config import (
    PRESETS,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    preset,
)
from simpletrack.server.settings import (
    OTHER_ENV_VARS,
    Backpressure,
    ZenohSettings,
    check_environment,
    load_settings,
    refresh_docs,
)
from simpletrack.server.tracker_settings import TrackerOptions
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


def test_class_overrides_file_is_applied_when_the_settings_load(tmp_path: Path) -> None:
    good = tmp_path / "o.toml"
    good.write_text("[Car]\nscore_high = 0.6\nmax_age = 4\n")
    cfg = load_settings(None, {"class_overrides": good}).tracker_config()
    assert cfg.classes["Car"].score_high == 0.6 and cfg.classes["Car"].max_age == 4
    assert cfg.classes["Pedestrian"].score_high == 0.5


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[Tram]\nmax_age = 4\n", "class 'Tram' is not in preset 'kitti'"),
        (
            "[Car]\nmax_age = -1\n",
            "Car: max_age: Input should be greater than or equal to 1 (got -1)",
        ),
        ("[Car]\nscore_low = 0.9\n", "Car: score_low (0.9) must not exceed score_high (0.7)"),
        ("Car = 3\n", "Car must be a table of fields (got 3)"),
        ("[Car\n", "line 1"),  # not TOML
    ],
)
def test_a_bad_class_overrides_file_fails_load_settings_naming_file_class_and_value(
    tmp_path: Path, text: str, needle: str
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(ValueError) as info:
        load_settings(None, {"class_overrides": bad})
    assert str(info.value).startswith(f"{bad}") and needle in str(info.value)
    with pytest.raises(ValueError, match="cannot read"):
        load_settings(None, {"class_overrides": tmp_path / "missing.toml"})


def test_motion_models_and_lost_tracks_load_per_sensor_and_are_refused_for_a_fused_vehicle(
    tmp_path: Path,
) -> None:
    models = tmp_path / "models.toml"
    models.write_text('[Car]\nmotion_model = "ctra"\nrevive_frames = 20\nrevive_gate = 12.0\n')
    cfg = load_settings(None, {"class_overrides": models}).tracker_config()
    assert (cfg.classes["Car"].motion_model, cfg.classes["Car"].revive_frames) == ("ctra", 20)
    assert cfg.state_dim == 12
    fused = {"fusion": {"sensors": {"lidar": {}, "camera": {}}}}
    with pytest.raises(
        ValueError, match=r"Car: motion_model ctra, revive_frames 20, process_noise None: a fused"
    ):
        load_settings(None, {"class_overrides": models, **fused})
    per_sensor = {
        "fusion": {"sensors": {"lidar": {}, "camera": {"classes": {"Car": {"revive_frames": 5}}}}}
    }
    with pytest.raises(ValueError, match=r"fusion.sensors.camera.classes.Car: motion_model cv"):
        load_settings(None, per_sensor)
    assert load_settings(None, fused).tracker_config().state_dim == 10


def _fields(model: type[BaseModel]) -> dict[str, object]:
    """Field names, nested models as dicts of their own."""
    out: dict[str, object] = {}
    for name, info in model.model_fields.items():
        kind = info.annotation
        nested = isinstance(kind, type) and issubclass(kind, BaseModel)
        out[name] = _fields(kind) if nested else None  # type: ignore[arg-type]
    return out


def test_every_top_level_tracker_option_is_a_service_setting() -> None:
    want = _fields(TrackerConfig)
    del want["classes"]  # the preset's, changed by class_overrides
    assert _fields(TrackerOptions) == want


def test_tracker_options_from_file_env_and_flags_over_the_preset(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    nuscenes = preset("nuscenes")
    # Options left out keep the preset's values, not TrackerConfig's defaults.
    assert load_settings(None, {"preset": "nuscenes"}).tracker_config() == nuscenes
    cfg = tmp_path / "s.toml"
    cfg.write_text(
        'preset = "nuscenes"\n[tracker]\noutput = "paper"\ncoast_score_decay = 0.3\n'
        "[tracker.kalman]\nq = 2.0\n[tracker.non_key]\nscore_high = 0.4\n"
    )
    monkeypatch.setenv("SIMPLETRACK_TRACKER__MOTION", "constant_velocity")
    monkeypatch.setenv("SIMPLETRACK_TRACKER__COAST_SCORE_DECAY", "0.2")
    args = build_parser().parse_args(
        ["serve", "--config", str(cfg), "--tie-order", "reference", "--coast-score-decay", "0.1"]
    )
    got = settings_from_args(args).tracker_config()
    assert got == nuscenes.with_overrides(
        output=OutputPolicy.PAPER,
        motion=MotionModel.CONSTANT_VELOCITY,
        tie_order=TieOrder.REFERENCE,
        coast_score_decay=0.1,  # flag over environment over file
        kalman=nuscenes.kalman.model_copy(update={"q": 2.0}),
        non_key=nuscenes.non_key.model_copy(update={"score_high": 0.4}),
    )


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"tracker": {"coast_score_decay": 2}}, "tracker.coast_score_decay: Input should be"),
        ({"tracker": {"motion": "bicycle"}}, "tracker.motion: Input should be"),
        ({"tracker": {"kalman": {"q": -1}}}, "tracker.kalman.q: Input should be greater than 0"),
        ({"tracker": {"classes": {}}}, "tracker.classes: Extra inputs are not permitted"),
        ({"ignore_classes": ["Car"]}, "ignore_classes: 'Car' is a tracked class"),
    ],
)
def test_settings_that_cannot_make_a_tracker_fail_to_load(
    overrides: dict[str, object], needle: str
) -> None:
    with pytest.raises(ValueError) as info:
        load_settings(None, overrides)
    assert needle in str(info.value)


def test_preset_names_everywhere_come_from_the_core_registry(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(ValueError) as info:
        load_settings(None, {"preset": "carla"})
    assert f"choose one of {', '.join(PRESETS)}" in str(info.value)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve", "--preset", "carla"])
    assert ", ".join(f"'{name}'" for name in PRESETS) in capsys.readouterr().err
    docs = (ROOT / "docs/SERVICE.md").read_text()
    assert " \\| ".join(PRESETS) in docs
    for name in PRESETS:
        assert f"| `{name}` | " + ", ".join(f"`{c}`" for c in preset(name).class_names) in docs


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
    assert f"metrics port {port} on 127.0.0.1 is in use" in err and "Traceback" not in err


@pytest.mark.parametrize("doc", ["docs/SERVICE.md", "README.md"])
def test_docs_tables_are_generated_from_the_code(doc: str) -> None:
    text = (ROOT / doc).read_text()
    assert refresh_docs(text) == text, f"run: python -m simpletrack.server.settings --write {doc}"
    for name in (
        "backpressure",
        "snapshot_interval_s",
        "SIMPLETRACK_ZENOH__MODE",
        "tracker.motion",
    ):
        assert name in text
    for name in ("simpletrack_frames_rejected_total", "simpletrack_end_to_end_seconds"):
        assert name in text


# --- SIMPLETRACK_* variables that are no setting ---------------------------------------------


@pytest.mark.parametrize(
    ("name", "closest"),
    [
        ("SIMPLETRACK_WORKRS", "SIMPLETRACK_WORKERS"),
        ("SIMPLETRACK_ZENOH_MODE", "SIMPLETRACK_ZENOH__MODE"),  # one underscore: not nested
        ("SIMPLETRACK_ZENOH__LISTN", "SIMPLETRACK_ZENOH__LISTEN"),
        ("SIMPLETRACK_TRACKER__KALMAN__QQ", "SIMPLETRACK_TRACKER__KALMAN__Q"),
        (
            "SIMPLETRACK_FUSION__SENSORS__LIDAR__MIN_SCOR",
            "SIMPLETRACK_FUSION__SENSORS__LIDAR__MIN_SCORE",
        ),
        ("SIMPLETRACK_WORKERS__MAX", "SIMPLETRACK_WORKERS"),
        ("simpletrack_metrics_prot", "SIMPLETRACK_METRICS_PORT"),  # read case-insensitively
        ("SIMPLETRACK_JTI", "SIMPLETRACK_JIT"),
        ("SIMPLETRACK_DATASET", "SIMPLETRACK_DATA"),
    ],
)
def test_a_variable_that_is_no_setting_is_refused_with_the_closest_name(
    name: str, closest: str
) -> None:
    with pytest.raises(ValueError) as info:
        check_environment({"HOME": "/root", "SIMPLETRACK_WORKERS": "3", name: "1"})
    assert str(info.value) == (
        f"environment variable {name} is no simpletrack setting: did you mean {closest}? "
        "(unset it to start; every setting's variable: docs/SERVICE.md)"
    )


def test_a_variable_like_no_setting_at_all_is_refused_without_a_guess() -> None:
    with pytest.raises(ValueError, match=r"SIMPLETRACK_XYZZY is no simpletrack setting: \(unset"):
        check_environment({"SIMPLETRACK_XYZZY": "1"})


@pytest.mark.parametrize(
    "name",
    [
        *sorted(OTHER_ENV_VARS),
        "SIMPLETRACK_WORKERS",
        "simpletrack_workers",
        "SIMPLETRACK_TRACKER",  # a JSON object
        "SIMPLETRACK_TRACKER__KALMAN__Q",
        "SIMPLETRACK_ZENOH__CONNECT_TIMEOUT_MS",
        "SIMPLETRACK_FUSION__SENSORS__LIDAR__MIN_SCORE",  # a sensor's name, then its field
        "SIMPLETRACK_FUSION__WINDOW_S",
        "SIMPLETRACK",  # not the prefix: no concern of ours
        "NOT_SIMPLETRACK_WORKRS",
    ],
)
def test_settings_and_the_variables_other_parts_read_are_accepted(name: str) -> None:
    check_environment({name: "1"})


# Files that hold misspelt names on purpose (the tests of the refusal, its example).
_TYPOS_ON_PURPOSE = {"tests/server/test_settings.py", "docs/SERVICE.md", "README.md"}


def test_every_simpletrack_variable_the_project_sets_is_accepted() -> None:
    """Deploy files, scripts, docs and the tests' service processes: a variable they set
    that serve refused would stop those services (and a setting renamed without them)."""
    files = [ROOT / "Dockerfile", *(ROOT / "deploy").rglob("*"), *(ROOT / "scripts").glob("*")]
    files += [*(ROOT / "docs").glob("*.md"), *(ROOT / "tests").rglob("*.py")]
    names: dict[str, str] = {}
    for path in files:
        rel = str(path.relative_to(ROOT))
        if not path.is_file() or rel in _TYPOS_ON_PURPOSE or path.suffix in {".png", ".svg"}:
            continue
        # -DSIMPLETRACK_...: the C++ client's CMake options; SIMPLETRACK_TRACKER__<FIELD>: a form
        for m in re.finditer(r"(-D)?(SIMPLETRACK_[A-Z0-9_]+)", path.read_text(errors="ignore")):
            if not m[1] and not m[2].endswith("_"):
                names.setdefault(m[2], rel)
    assert len(names) > 20, names  # the deploy files' settings at least
    for name, where in sorted(names.items()):
        try:
            check_environment({name: "1"})
        except ValueError as e:
            raise AssertionError(f"{where}: {e}") from None


def test_serve_refuses_a_misspelt_variable_before_it_starts(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("SIMPLETRACK_METRICS_PROT", "9999")
    assert main(["serve"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "simpletrack serve: error: environment variable SIMPLETRACK_METRICS_PROT is no "
        "simpletrack setting: did you mean SIMPLETRACK_METRICS_PORT? (unset it to start; "
        "every setting's variable: docs/SERVICE.md)"
    )


# --- a YAML settings file's mistakes, with their line and column ------------------------------


@pytest.mark.parametrize(
    ("text", "place", "problem"),
    [
        (
            "workers: 2\nzenoh:\n  mode: peer\n  listen: [tcp/127.0.0.1:7447\n",
            "5:1",
            "expected ',' or ']', but got '<stream end>' (while parsing a flow sequence at line 4)",
        ),
        ("workers: 2\nzenoh:\n  mode: peer\n listen: x\n", "4:2", "expected <block end>"),
        ("prefix: a: b\n", "1:10", "mapping values are not allowed here"),
    ],
)
def test_a_yaml_syntax_error_names_the_file_line_and_column(
    tmp_path: Path, text: str, place: str, problem: str
) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text(text)
    with pytest.raises(ValueError) as info:
        load_settings(cfg)
    assert str(info.value).startswith(f"{cfg}:{place}: {problem}"), info.value


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (  # an unknown key: the key's place
            "workers: 2\nzenoh:\n  mode: peer\n  listn: [tcp/127.0.0.1:7447]\n",
            "4:3: zenoh.listn: Extra inputs are not permitted (got ['tcp/127.0.0.1:7447'])",
        ),
        (  # a wrong value
            "prefix: p\nqueue_size: 0\n",
            "2:1: queue_size: Input should be greater than or equal to 1 (got 0)",
        ),
        (  # deep in the tracker options
            "tracker:\n  kalman:\n    q: -1\n",
            "3:5: tracker.kalman.q: Input should be greater than 0 (got -1.0)",
        ),
        (  # a check of the whole model names its setting first
            "preset: kitti\nignore_classes:\n  - Car\n",
            "2:1: ignore_classes: 'Car' is a tracked class of this preset",
        ),
        (  # a list item
            "zenoh:\n  connect:\n    - tcp/10.0.0.1:7447\n    - [nested]\n",
            "4:7: zenoh.connect.1: Input should be a valid string (got ['nested'])",
        ),
    ],
)
def test_a_wrong_value_in_a_yaml_file_names_the_file_line_column_and_key(
    tmp_path: Path, text: str, expected: str
) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text(text)
    with pytest.raises(ValueError) as info:
        load_settings(cfg)
    assert str(info.value) == f"{cfg}:{expected}"


def test_every_wrong_value_of_a_yaml_file_has_its_own_place(tmp_path: Path) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text("workers: 0\nzenoh:\n  mode: peer\n  listn: []\n")
    with pytest.raises(ValueError) as info:
        load_settings(cfg)
    problems = sorted(str(info.value).split("; "))
    assert [p.split(": ")[:2] for p in problems] == [
        [f"{cfg}:1:1", "workers"],
        [f"{cfg}:4:3", "zenoh.listn"],
    ]


def test_a_wrong_value_given_over_the_file_is_not_placed_in_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = tmp_path / "s.yaml"
    cfg.write_text("workers: 2\nqueue_size: 4\n")
    monkeypatch.setenv("SIMPLETRACK_WORKERS", "0")
    with pytest.raises(ValueError) as info:
        load_settings(cfg)
    assert str(info.value) == "workers: Input should be greater than or equal to 1 (got '0')"
    monkeypatch.delenv("SIMPLETRACK_WORKERS")
    with pytest.raises(ValueError) as info:
        load_settings(cfg, {"queue_size": 0})
    assert str(info.value) == "queue_size: Input should be greater than or equal to 1 (got 0)"
