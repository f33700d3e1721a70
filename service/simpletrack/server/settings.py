"""Service settings: defaults, then a TOML/YAML file (``--config``), then ``SIMPLETRACK_*``
environment variables (nested with ``__``, e.g. ``SIMPLETRACK_ZENOH__MODE=client``), then flags.
A ``SIMPLETRACK_*`` variable that is no setting (nor one of ``OTHER_ENV_VARS``) is refused by
``check_environment``: pydantic-settings would ignore it, leaving its setting at the default.
A YAML file's mistakes are named with their line and column.

``python -m simpletrack.server.settings`` prints the reference table; ``--write docs/SERVICE.md`` refreshes
the table in the docs (a test fails when it drifts).
"""

from __future__ import annotations

import argparse
import difflib
import hashlib
import json
import os
import re
import socket
import sys
import tomllib
import types
from collections.abc import Iterator, Mapping
from contextvars import ContextVar
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo
from pydantic_settings import (
    BaseSettings,
    EnvSettingsSource,
    InitSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from simpletrack.core.config import PRESETS, TrackerConfig, preset
from simpletrack.core.fusion_config import FusionConfig, SensorTrust
from simpletrack.core.tracker import STATE_FORMAT, STATE_FORMATS
from simpletrack.core.vehicle import check_fusable
from simpletrack.server.messages import Where, format_error
from simpletrack.server.tracker_settings import (
    OneOf,
    PresetName,
    TrackerOptions,
    resolve_tracker_config,
)
from simpletrack.session import (
    DEFAULT_LISTEN,
    DEFAULT_RECONNECT_MAX_MS,
    ENDPOINT_LENGTH,
    RECONNECT_FIRST_MS,
    Congestion,
    ZenohMode,
    ZenohOptions,
    check_config_file,
    check_endpoints,
    check_roles,
)
from simpletrack.wire.models import NAME_PATTERN
from simpletrack.wire.reasons import TRACK_EPOCH_SCHEMA_VERSION

ENV_PREFIX = "SIMPLETRACK_"
# SIMPLETRACK_* variables that are no setting, read by other parts of the project: the
# kernels' compiler (core/jit.py), the datasets' folder, the native clients' test builds
# (tests/native). check_environment refuses any other that is no setting.
OTHER_ENV_VARS = frozenset(
    {"SIMPLETRACK_JIT", "SIMPLETRACK_DATA", "SIMPLETRACK_CARGO_TARGET", "SIMPLETRACK_CPP_BUILD"}
)
DOC_COMMAND = "python -m simpletrack.server.settings --write <this file>"


class Backpressure(StrEnum):
    DROP_OLDEST = "drop_oldest"  # never block Zenoh: a full worker queue drops its oldest frame
    BLOCK = "block"  # lossless: a full queue stops intake; Zenoh pushes back to BLOCK publishers


class Subscribe(StrEnum):
    WIDE = "wide"  # one subscriber on every sensor's detections
    OWNED = "owned"  # one per sensor owned or stood by for, from the vehicles' tokens


class StandbyCopy(StrEnum):
    CHECKPOINTS = "checkpoints"  # the owner's checkpoints and the tracks; frames from the cache
    FRAMES = "frames"  # and every frame since the checkpoint, kept


class LogFormat(StrEnum):
    JSON = "json"
    KV = "kv"


class LogLevel(StrEnum):
    DEBUG = "debug"
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


def _default_instance() -> str:
    host = re.sub(r"[^A-Za-z0-9_.\-]", "-", socket.gethostname())[:40].strip(".") or "host"
    return f"simpletrack-{host}"


Endpoint = Annotated[str, Field(min_length=ENDPOINT_LENGTH[0], max_length=ENDPOINT_LENGTH[1])]


class EnvValueError(Exception):
    """An environment variable no list or object can be read from. Not a ValueError:
    pydantic-settings would wrap that in a message naming neither variable nor value."""


def _is_list(annotation: Any) -> bool:
    if get_origin(annotation) is list or annotation is list:
        return True
    return any(_is_list(a) for a in get_args(annotation) if a is not type(None))


class ListFriendlyEnvSource(EnvSettingsSource):
    """``SIMPLETRACK_*`` variables, where a list may also be given comma-separated
    (``SIMPLETRACK_ZENOH__CONNECT=tcp/a:7447,tcp/b:7447``): the form a shell and a
    Kubernetes manifest write; a value starting with ``[`` is read as JSON."""

    def decode_complex_value(self, field_name: str, field: FieldInfo | None, value: Any) -> Any:
        if not isinstance(value, str):
            return super().decode_complex_value(field_name, field, value)  # type: ignore[arg-type]
        listed = field is not None and _is_list(field.annotation)
        text = value.strip()
        if listed and not text.startswith("["):
            return [item.strip() for item in text.split(",") if item.strip()]
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            form = (
                'a comma-separated list (a,b) or a JSON list (["a","b"])'
                if listed
                else f"a JSON object, or one variable per field ({self._name(field_name, value)}__<FIELD>)"
            )
            raise EnvValueError(
                f"{self._name(field_name, value)}={value!r}: expected {form}"
            ) from None

    def _name(self, field_name: str, value: str) -> str:
        """The variable that held ``value``: pydantic-settings passes only the last key."""
        want = field_name.lower()
        for name, v in self.env_vars.items():
            low = name.lower()
            if v == value and low.startswith(ENV_PREFIX.lower()) and low.endswith(want):
                return name.upper()
        return f"{ENV_PREFIX}{field_name.upper()}"


class ZenohSettings(BaseModel):
    """``ZenohOptions`` as settings: strings from the environment and files coerced, a bad
    value named by its field. Same fields, defaults and rules (a test holds them equal);
    ``options()`` is what opens the session."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: ZenohMode = Field(
        default=ZenohMode.PEER, description="peer (embedded) or client of routers"
    )
    listen: list[Endpoint] = Field(
        default_factory=list,
        description="endpoints to listen on (peer mode only); never all interfaces by default",
    )
    connect: list[Endpoint] = Field(
        default_factory=list, description="endpoints (peers or routers) to connect to"
    )
    multicast_scouting: bool = Field(default=False, description="discover peers by UDP multicast")
    config_file: Path | None = Field(
        default=None,
        description="Zenoh JSON5 config file to start from (TLS, access control); options above override it where given",
    )
    connect_timeout_ms: int | None = Field(
        default=None,
        ge=-1,
        description="how long to try the connect endpoints at start (-1: wait for the router forever)",
    )
    reconnect_max_ms: int = Field(
        default=DEFAULT_RECONNECT_MAX_MS,
        ge=RECONNECT_FIRST_MS,
        description="longest wait between two tries to (re)connect an endpoint (Zenoh's own grows to 4 s)",
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoint_syntax(cls, v: list[str]) -> list[str]:
        check_endpoints(v)
        return v

    @field_validator("config_file")
    @classmethod
    def _file_exists(cls, v: Path | None) -> Path | None:
        check_config_file(v)
        return v

    @model_validator(mode="after")
    def _client_needs_router(self) -> ZenohSettings:
        check_roles(self.mode, self.listen, self.connect, self.multicast_scouting, self.config_file)
        return self

    def options(self) -> ZenohOptions:
        """The session options, with the same options given (they decide what a Zenoh
        config file keeps)."""
        return ZenohOptions(**{name: getattr(self, name) for name in self.model_fields_set})


Seconds = Annotated[float, Field(gt=0.0)]


class FusionSettings(FusionConfig):
    """Vehicle fusion (docs/SERVICE.md, "Vehicle fusion"): the sensors named here feed one
    tracker per vehicle; the timing rules are the core's (core/fusion_config.py)."""

    sensors: dict[str, SensorTrust] = Field(
        default_factory=dict,
        max_length=64,
        description="sensor name -> its trust (spawn, spawn_classes, existence, "
        "hit_probability, detection_probability, min_score, r, fov_deg, min_range_m, "
        "max_range_m, verify); the first is the vehicle's reference; empty: no fusion",
    )
    vehicles: list[Annotated[str, Field(pattern=NAME_PATTERN)]] = Field(
        default_factory=list, description="vehicles that fuse (empty: every vehicle)"
    )
    per_sensor_output: bool = Field(
        default=False,
        description="also track each fused sensor on its own and publish on its tracks key "
        "(one more tracker step per frame)",
    )
    vehicle_frame_id: Annotated[str, Field(min_length=1, max_length=128)] = Field(
        default="base_link",
        description="frame_id of a vehicle's tracks when its frames carry extrinsics",
    )

    @field_validator("sensors")
    @classmethod
    def _sensor_names(cls, v: dict[str, SensorTrust]) -> dict[str, SensorTrust]:
        for name in v:
            if not re.fullmatch(NAME_PATTERN, name):
                raise ValueError(f"sensor name {name!r} must match {NAME_PATTERN}")
        return v

    def config(self) -> FusionConfig | None:
        """The core's fusion configuration (None: no fusion)."""
        if not self.sensors:
            return None
        own = {"vehicles", "per_sensor_output", "vehicle_frame_id"}
        return FusionConfig.model_validate(self.model_dump(exclude=own))


_PREFIX = r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}(/[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}){0,7}$"


class ServiceSettings(BaseSettings):
    """Everything ``simpletrack serve`` can be told."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX,
        env_nested_delimiter="__",
        extra="forbid",
        validate_default=True,
    )

    prefix: Annotated[str, Field(pattern=_PREFIX)] = Field(
        default="fleet", description="first key chunk(s): <prefix>/<vehicle>/<sensor>/detections"
    )
    instance: Annotated[str, Field(pattern=NAME_PATTERN)] = Field(
        default_factory=_default_instance,
        description="this instance's id in its liveliness/status keys (default from hostname)",
    )
    zenoh: ZenohSettings = Field(
        default_factory=lambda: ZenohSettings(),
        description="Zenoh session (flags --mode/--listen/--connect)",
    )
    wait_for_router: bool = Field(
        default=True,
        description="client mode: start not ready and wait for a router instead of exiting (false: exit as Zenoh does)",
    )
    history_frames: Annotated[int, Field(ge=1, le=100_000)] = Field(
        default=1,
        description="frames a vehicle's cache hands a service that first hears of it (start, restart): more replays frames a restored sensor may have tracked",
    )
    preset: PresetName = Field(
        default="kitti", description="tracker preset; its classes are the accepted class names"
    )
    class_overrides: Path | None = Field(
        default=None, description="TOML/YAML file {class: {field: value}} over the preset's classes"
    )
    tracker: TrackerOptions = Field(
        default_factory=TrackerOptions, description="tracker options over the preset's"
    )
    ignore_classes: list[str] = Field(
        default_factory=list,
        description="class names dropped from frames (counted) instead of rejected as unknown",
    )
    workers: Annotated[int, Field(ge=1, le=64)] = Field(
        default=2, description="tracker threads; each sensor is pinned to one"
    )
    queue_size: Annotated[int, Field(ge=1, le=100_000)] = Field(
        default=64,
        description="frames waiting per worker before backpressure applies (other members' "
        "checkpoints wait apart, the newest of each sensor)",
    )
    backpressure: Backpressure = Field(
        default=Backpressure.DROP_OLDEST, description="what a full queue does: drop_oldest or block"
    )
    # Recovered and replayed frames (docs/SERVICE.md, "Recovered frames are kept").
    catchup_after_s: Seconds = Field(
        default=0.5,
        description="a frame arriving this much later after its stamp than its sensor's usual "
        "delay is a catch-up frame (recovered from a vehicle's cache, replayed): it and the "
        "frames of its burst behind it are kept beyond queue_size on burst_bytes, never shed",
    )
    burst_bytes: Annotated[int, Field(ge=1 << 20)] = Field(
        default=256 << 20,
        description="bytes of catch-up frames a member holds beyond queue_size (all workers "
        "together, payload + 512 B each); past it a catch-up frame is dropped as missed "
        "(block: waits); 256 MiB holds the 10 s caches of 100 sensors at ~25 KB a frame",
    )
    congestion_control: Congestion = Field(
        default=Congestion.BLOCK,
        description="Zenoh congestion control of the tracks/errors publishers",
    )
    max_frame_bytes: Annotated[int, Field(ge=1024)] = Field(
        default=8 << 20, description="larger payloads are rejected (too_large)"
    )
    max_boxes: Annotated[int, Field(ge=1)] = Field(
        default=10_000,
        description="frames with more boxes are rejected (too_large); measured "
        "(python -m simpletrack.bench.heavy, nuscenes preset, 200 m street scene): "
        "10,000 boxes step in ~0.4-0.55 s with a ~100-180 MB peak, 20,000 take ~1.9 s, "
        "so no frame admitted holds its worker (and the sensors sharing it) near 1 s",
    )
    max_sensors: Annotated[int, Field(ge=1)] = Field(
        default=1000, description="new sensors beyond this are rejected (too_many_sensors)"
    )
    sensor_idle_s: Seconds = Field(
        default=600.0, description="a sensor silent this long is evicted (its ids stay reserved)"
    )
    reset_gap_s: Seconds = Field(
        default=5.0, description="a stamp gap over this resets the sensor's tracker"
    )
    reset_backward_s: Seconds = Field(
        default=5.0,
        description="a stamp this far behind the last one resets the tracker (less: out_of_order)",
    )
    state_dir: Path | None = Field(
        default=None, description="snapshot directory; restored on start (none: no persistence)"
    )
    snapshot_interval_s: Seconds = Field(
        default=5.0,
        description="periodic snapshot interval: a crash's gap since the last snapshot is replayed from the vehicles' caches at restart, so keep it plus the restart time within the cache (100 frames: 10 s at 10 Hz)",
    )
    group: bool = Field(
        default=True,
        description="share the prefix's sensors with the other instances on it: each sensor tracked by one (false: track every sensor heard)",
    )
    subscribe: Subscribe = Field(
        default=Subscribe.OWNED,
        description="owned: each member hears the frames and tracks of the sensors it owns only (what a standby hears: see standby), found from the vehicles' advanced-publisher tokens and, for plain puts, by the group's scout (one member hearing every frame); wide: every member hears every frame and every tracks message (its cost grows with the members)",
    )
    checkpoint_interval_s: Seconds = Field(
        default=1.0,
        description="how often an owner sends each changed sensor's state to its standby member (checkpoint_frames > 1: each sensor due one)",
    )
    checkpoint_frames: Annotated[int, Field(ge=1, le=100_000)] = Field(
        default=1,
        description="more than 1: a sensor's state goes to its standby only once it took this many frames since its last checkpoint, or took fewer and that checkpoint is checkpoint_max_age_s old; fewer checkpoints for sensors under 10 Hz, slower failovers of them (docs/SCALE.md)",
    )
    checkpoint_max_age_s: Seconds = Field(
        default=10.0,
        description="with checkpoint_frames > 1: a changed sensor's checkpoint is never older than this",
    )
    state_format: Annotated[int, Field(ge=min(STATE_FORMATS), le=max(STATE_FORMATS))] = Field(
        default=STATE_FORMAT,
        description="the byte form of the tracker states this member sends (checkpoints, hand-offs) and writes to state_dir: 2 leaves out what is zero in every track (a third of the bytes), 1 is the form of versions before it, which cannot read 2; set 1 while a rolling upgrade from such a version is under way",
    )
    standby: StandbyCopy = Field(
        default=StandbyCopy.CHECKPOINTS,
        description="what a standby member hears of a sensor (subscribe = owned): checkpoints: the owner's checkpoints and its word of the tracks it published (stamp, next id, epoch, in batches), not the frames nor the tracks; a takeover replays the frames since the checkpoint from the vehicle's cache (a plain put's sensor, which has none, is still heard whole, as is a sensor its vehicle will fuse while a rolling upgrade keeps fusion off); frames: every frame too, kept since the checkpoint (standby_frames), the cache asked only past them",
    )
    standby_frames: Annotated[int, Field(ge=1, le=100_000)] = Field(
        default=100,
        description="frames per sensor a standby member keeps since the last checkpoint (replayed at a takeover), and frames that wait per takeover",
    )
    fence_after_s: Seconds = Field(
        default=5.0,
        description="a worker that finds itself stopped this long (SIGSTOP, a frozen VM) while in a group publishes nothing from its streams until it asked the group again; keep it below the Zenoh lease (10 s), after which the group takes them over",
    )
    fence_hold_s: Seconds = Field(
        default=1.0,
        description="after a fence, how long frames wait once the member reaches the group again before it is asked (the group's tokens and tracks come in meanwhile)",
    )
    handoff_timeout_s: Seconds = Field(
        default=1.0,
        description="how long a takeover waits for the holder's answer, and a leaving instance for its sensors to be taken",
    )
    shutdown_timeout_s: Seconds = Field(
        default=20.0, description="on SIGTERM, how long queued frames may take to drain"
    )
    gil_switch_interval_ms: Annotated[float, Field(gt=0.0, le=100.0)] = Field(
        default=1.0,
        description="Python's thread switch interval: lower lets Zenoh's threads in sooner while a worker tracks (tail latency)",
    )
    metrics_host: str = Field(
        default="127.0.0.1", description="bind address of /metrics, /healthz, /readyz"
    )
    metrics_port: Annotated[int, Field(ge=0, le=65535)] = Field(
        default=9464, description="HTTP port for /metrics, /healthz, /readyz (0: disabled)"
    )
    metrics_vehicle_label: bool = Field(
        default=False,
        description="label frame counters by vehicle (bounded by metrics_max_vehicles)",
    )
    metrics_max_vehicles: Annotated[int, Field(ge=1, le=10_000)] = Field(
        default=100, description="vehicles beyond this share the label value _other"
    )
    world_frame_id: Annotated[str, Field(min_length=1)] = Field(
        default="world", description="frame_id of tracks when detections carry a pose"
    )
    fusion: FusionSettings = Field(
        default_factory=FusionSettings,
        description="vehicle fusion: which sensors feed one tracker per vehicle",
    )
    tracks_schema_version: Annotated[int, Field(ge=1, le=TRACK_EPOCH_SCHEMA_VERSION)] = Field(
        default=TRACK_EPOCH_SCHEMA_VERSION,
        description="TrackFrame version published: 3 carries the custody epoch; 2 or 1 until "
        "every reader decodes 3 (schemas/README.md, Versioning)",
    )
    log_format: LogFormat = Field(
        default=LogFormat.JSON, description="json or kv (key=value) lines"
    )
    log_level: LogLevel = Field(default=LogLevel.INFO, description="debug logs every frame")

    @model_validator(mode="before")
    @classmethod
    def _default_listen(cls, data: Any) -> Any:
        # A peer listens on loopback unless told otherwise; a client never listens.
        if not isinstance(data, dict):
            return data
        z = data.get("zenoh", {})
        if (
            isinstance(z, Mapping)
            and "listen" not in z
            and "config_file" not in z  # a Zenoh config file says where to listen
            and z.get("mode", "peer") == "peer"
        ):
            data = {**data, "zenoh": {**z, "listen": list(DEFAULT_LISTEN)}}
        return data

    @field_validator("ignore_classes")
    @classmethod
    def _no_blank(cls, v: list[str]) -> list[str]:
        for name in v:
            if not name.strip():
                raise ValueError("class names must not be blank")
        return v

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        file_values = _FILE_VALUES.get()
        env = ListFriendlyEnvSource(settings_cls)
        return (init_settings, env, InitSettingsSource(settings_cls, file_values))

    # Resolved once, when the settings load: settings that load always make a tracker.
    _tracker_config: TrackerConfig = PrivateAttr()

    @model_validator(mode="after")
    def _resolve_tracker(self) -> ServiceSettings:
        source = self.class_overrides
        changes = read_mapping(source) if source is not None else {}
        config = resolve_tracker_config(self.preset, self.tracker, changes, str(source))
        for name in self.ignore_classes:
            if name in config.classes:
                raise ValueError(f"ignore_classes: {name!r} is a tracked class of this preset")
        for sensor, trust in self.fusion.sensors.items():
            named = set(trust.spawn_classes or ())
            if isinstance(trust.min_score, dict):
                named |= set(trust.min_score)
            unknown = sorted(named - set(config.classes))
            if unknown:
                raise ValueError(
                    f"fusion.sensors.{sensor}: unknown class {unknown[0]!r}; known: "
                    f"{', '.join(config.classes)}"
                )
        fusion = self.fusion.config()
        if fusion is not None:
            check_fusable(config, fusion)
        self._tracker_config = config
        return self

    def tracker_config(self) -> TrackerConfig:
        """The preset with the tracker options and per-class overrides applied."""
        return self._tracker_config


_FILE_VALUES: ContextVar[dict[str, Any]] = ContextVar("_FILE_VALUES", default={})  # noqa: B039


def read_mapping(path: Path) -> dict[str, Any]:
    """A TOML (``.toml``) or YAML (``.yaml``/``.yml``) file holding a mapping."""
    try:
        text = path.read_text()
    except OSError as e:
        raise ValueError(f"cannot read {path}: {e.strerror}") from None
    try:
        if path.suffix == ".toml":
            data: Any = tomllib.loads(text)
        elif path.suffix in {".yaml", ".yml"}:
            data = yaml.safe_load(text) or {}
        else:
            raise ValueError(f"{path}: use a .toml, .yaml or .yml file")
    except yaml.MarkedYAMLError as e:
        raise ValueError(_yaml_syntax_error(path, e)) from None
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as e:
        raise ValueError(f"{path}: {e}".splitlines()[0]) from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    return data


def load_settings(
    config_file: Path | None = None, overrides: Mapping[str, Any] | None = None
) -> ServiceSettings:
    """Layer defaults < file < environment < ``overrides`` (flags). ValueError on bad input;
    a value from a YAML file is named with its line and column."""
    file_values = read_mapping(config_file) if config_file is not None else {}
    token = _FILE_VALUES.set(file_values)
    try:
        return ServiceSettings(**dict(overrides or {}))
    except ValidationError as e:
        where = _yaml_places(config_file, overrides) if config_file is not None else None
        raise ValueError(format_error(e, where=where)) from None
    except EnvValueError as e:
        raise ValueError(str(e)) from None
    finally:
        _FILE_VALUES.reset(token)


def _yaml_syntax_error(path: Path, e: yaml.MarkedYAMLError) -> str:
    """``file:line:column: problem (context at line N)``, from PyYAML's marks (0-based)."""
    mark = e.problem_mark or e.context_mark
    where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
    problem = e.problem or e.context or "not valid YAML"
    context = ""
    if e.context and e.problem and e.context_mark is not None:
        context = f" ({e.context} at line {e.context_mark.line + 1})"
    return f"{where}: {problem}{context}"


def _yaml_places(path: Path, overrides: Mapping[str, Any] | None) -> Where | None:
    """For a YAML settings file: where the value at a pydantic location was written
    (``file:line:column`` of its key), unless a flag or a variable gave it instead."""
    if path.suffix not in {".yaml", ".yml"}:
        return None
    try:
        root = yaml.compose(path.read_text(), Loader=yaml.SafeLoader)
    except (OSError, yaml.YAMLError):
        return None
    if root is None:
        return None
    given = set(_paths(dict(overrides or {})))
    given |= {env for env in map(_env_path, os.environ) if env is not None}

    def where(loc: tuple[str | int, ...], text: str) -> str | None:
        if not loc:  # a check of the whole model: its message starts with the setting
            named = re.match(r"([A-Za-z_][\w-]*(?:\.[\w-]+)*): ", text)
            loc = tuple(named[1].split(".")) if named else ()
        keys = tuple(str(p) for p in loc)
        if not keys or any(g[: len(keys)] == keys or keys[: len(g)] == g for g in given):
            return None
        mark = _yaml_mark(root, keys)
        return f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else None

    return where


def _yaml_mark(node: yaml.Node, keys: tuple[str, ...]) -> yaml.Mark | None:
    """The mark of the deepest key (or list item) along ``keys`` present in the document."""
    mark = None
    for key in keys:
        if isinstance(node, yaml.MappingNode):
            found = next((kv for kv in node.value if str(kv[0].value) == key), None)
            if found is None:
                break
            mark, node = found[0].start_mark, found[1]
        elif isinstance(node, yaml.SequenceNode) and key.isdigit() and int(key) < len(node.value):
            node = node.value[int(key)]
            mark = node.start_mark
        else:
            break
    return mark


def _paths(values: Mapping[str, Any], at: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    for key, value in values.items():
        if isinstance(value, Mapping) and value:
            yield from _paths(value, (*at, str(key)))
        else:
            yield (*at, str(key))


# --- SIMPLETRACK_* variables --------------------------------------------------------------


def _env_path(name: str) -> tuple[str, ...] | None:
    """The settings path a variable sets (``SIMPLETRACK_ZENOH__MODE``: zenoh, mode), or None
    for a variable of another kind. Names are case-insensitive, as pydantic-settings reads them."""
    upper = name.upper()
    if not upper.startswith(ENV_PREFIX) or upper in OTHER_ENV_VARS:
        return None
    return tuple(upper[len(ENV_PREFIX) :].lower().split("__"))


def _unknown_at(annotation: Any, parts: tuple[str, ...]) -> tuple[int, type[BaseModel]] | None:
    """None when ``parts`` name a setting (or a place inside one) of ``annotation``; else
    the index of the first part that does not, and the model it is no field of."""
    origin = get_origin(annotation)
    if origin is Annotated:
        return _unknown_at(get_args(annotation)[0], parts)
    if origin is Union or origin is types.UnionType:
        misses = []
        for arg in get_args(annotation):
            miss = _unknown_at(arg, parts)
            if miss is None:
                return None
            misses.append(miss)
        return max(misses, key=lambda m: m[0])
    if not parts or annotation is Any:
        return None
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        field = annotation.model_fields.get(parts[0])
        if field is None:
            return 0, annotation
        miss = _unknown_at(field.annotation, parts[1:])
        return None if miss is None else (miss[0] + 1, miss[1])
    if origin is dict:  # a key of the user's (a sensor's name), then its value
        miss = _unknown_at(get_args(annotation)[1], parts[1:])
        return None if miss is None else (miss[0] + 1, miss[1])
    return 0, _Leaf  # a plain value has no fields


class _Leaf(BaseModel):
    """What a plain setting has inside: nothing."""


def _names(model: type[BaseModel]) -> Iterator[str]:
    """The variable names (after the prefix, lower case) of every setting of ``model``."""
    for name, info in model.model_fields.items():
        yield name
        kind = info.annotation
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            yield from (f"{name}__{sub}" for sub in _names(kind))


def check_environment(environ: Mapping[str, str]) -> None:
    """Refuse a ``SIMPLETRACK_*`` variable that is neither a setting nor one of
    ``OTHER_ENV_VARS`` (ValueError naming it, and the closest known name): a misspelt one
    would otherwise be ignored, its setting left at the default without a word."""
    for name in sorted(environ):
        parts = _env_path(name)
        if parts is None:
            continue
        miss = _unknown_at(ServiceSettings, parts)
        if miss is None:
            continue
        at, model = miss
        known = list(_names(model))
        if at == 0:
            known += [n[len(ENV_PREFIX) :].lower() for n in OTHER_ENV_VARS]
        head = ENV_PREFIX + "".join(f"{p.upper()}__" for p in parts[:at])
        close = difflib.get_close_matches("__".join(parts[at:]), known, n=1, cutoff=0.6)
        if model is _Leaf:  # a plain setting given a field: SIMPLETRACK_WORKERS__MAX
            hint = f"did you mean {head.rstrip('_')}? "
        else:
            hint = f"did you mean {head}{close[0].upper()}? " if close else ""
        raise ValueError(
            f"environment variable {name} is no simpletrack setting: {hint}(unset it to "
            "start; every setting's variable: docs/SERVICE.md)"
        )


def config_digest(config: TrackerConfig) -> str:
    return hashlib.sha256(config.model_dump_json().encode()).hexdigest()


# --- the reference table in docs/SERVICE.md ------------------------------------------------


def _type_name(annotation: Any) -> str:
    origin = get_origin(annotation)
    if origin is Annotated:
        return _type_name(get_args(annotation)[0])
    if origin is Literal:
        return " \\| ".join(str(a) for a in get_args(annotation))
    if isinstance(annotation, type) and issubclass(annotation, StrEnum):
        return " \\| ".join(m.value for m in annotation)
    if origin is list:
        return f"list[{_type_name(get_args(annotation)[0])}]"
    args = [a for a in get_args(annotation) if a is not type(None)]
    if args and len(args) < len(get_args(annotation)):
        return f"{_type_name(args[0])} (optional)"
    return getattr(annotation, "__name__", str(annotation))


def _default(info: FieldInfo) -> str:
    if info.default_factory is not None:
        if info.default_factory is _default_instance:
            return "`simpletrack-<hostname>`"
        value: Any = info.default_factory()  # type: ignore[call-arg]
    else:
        value = info.default
    if isinstance(value, BaseModel):
        return "see below"
    if isinstance(value, StrEnum):
        value = value.value
    return f"`{value!r}`" if value is not None else "none"


_DOC_DEFAULTS = {
    "zenoh.listen": f"`{list(DEFAULT_LISTEN)!r}` in peer mode without a config file, else `[]`"
}


def _rows(model: type[BaseModel], path: str, env: str) -> Iterator[str]:
    for name, info in model.model_fields.items():
        annotation = info.annotation
        key, var = f"{path}{name}", f"{env}{name.upper()}"
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            yield from _rows(annotation, f"{key}.", f"{var}__")
            continue
        default = _DOC_DEFAULTS.get(key) or _default(info)
        if key.startswith("tracker.") and default == "none":
            default = "the preset's"
        choices = next((m.values for m in info.metadata if isinstance(m, OneOf)), None)
        kind = " \\| ".join(choices) if choices else _type_name(annotation)
        yield (f"| `{key}` | `{var}` | {kind} | {default} | {info.description or ''} |")


def reference_markdown() -> str:
    lines = [
        "| setting (file key) | environment | type | default | meaning |",
        "|---|---|---|---|---|",
        *_rows(ServiceSettings, "", ENV_PREFIX),
    ]
    return "\n".join(lines)


def presets_markdown() -> str:
    lines = ["| preset | classes (in code order) | output |", "|---|---|---|"]
    for name in PRESETS:
        config = preset(name)
        classes = ", ".join(f"`{c}`" for c in config.class_names)
        lines.append(f"| `{name}` | {classes} | `{config.output.value}` |")
    return "\n".join(lines)


def _generated_blocks() -> dict[str, str]:
    from simpletrack.server.metrics import reference_markdown as metrics_markdown

    return {
        "settings": reference_markdown(),
        "presets": presets_markdown(),
        "metrics": metrics_markdown(),
    }


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- generated:{name} ({DOC_COMMAND}) -->", f"<!-- end generated:{name} -->"


def refresh_docs(text: str) -> str:
    """``text`` with every generated block (settings, presets, metrics) rewritten from the code."""
    for name, body in _generated_blocks().items():
        begin, end = _markers(name)
        if begin not in text or end not in text:
            raise ValueError(f"missing the markers of the generated {name} block")
        start, stop = text.index(begin), text.index(end) + len(end)
        text = text[:start] + f"{begin}\n{body}\n{end}" + text[stop:]
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m simpletrack.server.settings", description=__doc__
    )
    parser.add_argument("--write", type=Path, help="refresh the generated blocks in this file")
    args = parser.parse_args(argv)
    if args.write is None:
        print(reference_markdown())
        return 0
    args.write.write_text(refresh_docs(args.write.read_text()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
