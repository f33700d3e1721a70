"""Service settings: defaults, then a TOML/YAML file (``--config``), then ``SIMPLETRACK_*``
environment variables (nested with ``__``, e.g. ``SIMPLETRACK_ZENOH__MODE=client``), then flags.

``python -m simpletrack.server.settings`` prints the reference table; ``--write docs/SERVICE.md`` refreshes
the table in the docs (a test fails when it drifts).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import socket
import sys
import tomllib
from collections.abc import Iterator, Mapping
from contextvars import ContextVar
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

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
from simpletrack.server.messages import format_error
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
DOC_COMMAND = "python -m simpletrack.server.settings --write <this file>"


class Backpressure(StrEnum):
    DROP_OLDEST = "drop_oldest"  # never block Zenoh: a full worker queue drops its oldest frame
    BLOCK = "block"  # lossless: a full queue stops intake; Zenoh pushes back to BLOCK publishers


class Subscribe(StrEnum):
    WIDE = "wide"  # one subscriber on every sensor's detections
    OWNED = "owned"  # one per sensor owned or stood by for, from the vehicles' tokens


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
        default=64, description="frames waiting per worker before backpressure applies"
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
        default=Subscribe.WIDE,
        description="wide: hear every sensor's frames (any publisher); owned: subscribe per sensor owned or stood by for, found from the vehicles' advanced-publisher tokens (a plain put is not heard)",
    )
    checkpoint_interval_s: Seconds = Field(
        default=1.0,
        description="how often an owner sends each changed sensor's state to its standby member",
    )
    standby_frames: Annotated[int, Field(ge=1, le=100_000)] = Field(
        default=100,
        description="frames per sensor a standby member keeps since the last checkpoint (replayed at a takeover)",
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
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as e:
        raise ValueError(f"{path}: {e}".splitlines()[0]) from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    return data


def load_settings(
    config_file: Path | None = None, overrides: Mapping[str, Any] | None = None
) -> ServiceSettings:
    """Layer defaults < file < environment < ``overrides`` (flags). ValueError on bad input."""
    file_values = read_mapping(config_file) if config_file is not None else {}
    token = _FILE_VALUES.set(file_values)
    try:
        return ServiceSettings(**dict(overrides or {}))
    except ValidationError as e:
        raise ValueError(format_error(e)) from None
    except EnvValueError as e:
        raise ValueError(str(e)) from None
    finally:
        _FILE_VALUES.reset(token)


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
