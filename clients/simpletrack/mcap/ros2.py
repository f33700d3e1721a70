"""A ROS 2 bag next to a recording (``simpletrack record --format mcap --ros2``): the same
frames as Autoware messages, in an MCAP file of rosbag2's layout, which ROS 2 tools read as a
bag (the tests read it with ``rosbags``):

    profile       ``ros2`` (the file holds nothing else: rosbag2 and rosbags refuse a file whose
                  channels mix encodings, so the msgpack channels stay in the recording)
    schemas       ``autoware_perception_msgs/msg/DetectedObjects`` and ``.../TrackedObjects``,
                  encoding ``ros2msg``: the type's .msg file, then each type it uses, depth
                  first, as rosbag2 writes them (``message_definition``)
    channels      message encoding ``cdr``; metadata ``offered_qos_profiles`` (reliable,
                  volatile, keep last 10) and ``topic_type_hash`` (RIHS01)
    messages      the CDR bytes (with their encapsulation header), log time = receive time,
                  publish time = the frame's stamp, sequence = its seq, as on the raw channels
    topics        /simpletrack/<vehicle>/<sensor>/detected_objects    a sensor's detections
                  /simpletrack/<vehicle>/<sensor>/tracked_objects     its tracks
                  /simpletrack/<vehicle>/tracked_objects              a fused vehicle's tracks

A vehicle or sensor name is made a ROS name (``ros_name``): characters other than letters,
digits and ``_`` become ``_``, runs of ``_`` one, and a leading digit gets a ``_`` before it
(``veh-01`` -> ``veh_01``, ``0100`` -> ``_0100``); two streams whose names would meet on one
topic are kept apart by ``_2``, ``_3``... after the later one's last name. No topic ends in a
key leaf, so ``replay mcap`` could never take one for detections (and it reads only
``msgpack`` channels).

The conversion itself is the ROS 2 bridge's (``simpletrack.ros2``), handed in by the CLI as a
``Ros2Messages`` (this tool does not import the bridge: docs/ARCHITECTURE.md)."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path
from typing import BinaryIO, Protocol

from mcap.writer import Writer

from simpletrack.mcap.format import METADATA_NAME, ROS2_PROFILE, TOOL, version
from simpletrack.wire.keys import DETECTIONS, TRACKS, VEHICLE_STREAM

MESSAGE_ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"
TOPIC_ROOT = "simpletrack"
DETECTED_TOPIC = "detected_objects"
TRACKED_TOPIC = "tracked_objects"
SUFFIX = ".ros2.mcap"
# rosbag2's layout (Jazzy, metadata version 9) of one offered profile: ROS 2's default
# (reliable, volatile, keep last) with a depth of 10; 0 s is "the default" for the durations.
QOS_PROFILES = """\
- history: keep_last
  depth: 10
  reliability: reliable
  durability: volatile
  deadline:
    sec: 0
    nsec: 0
  lifespan:
    sec: 0
    nsec: 0
  liveliness: automatic
  liveliness_lease_duration:
    sec: 0
    nsec: 0
  avoid_ros_namespace_conventions: false"""
_DELIMITER = "=" * 80
# rosbag2_storage_mcap's reading of a .msg file's field types (message_definition_cache.cpp).
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "string"} | {
    f"{sign}int{bits}" for sign in ("", "u") for bits in (8, 16, 32, 64)
}


class Ros2Messages(Protocol):
    """The ROS 2 side of the bag: what a frame becomes, and where the .msg files are."""

    msg_dir: Path  # <package>/<Name>.msg
    labels: str  # how classes became labels, for the bag's metadata

    def convert(
        self, leaf: str, vehicle: str, sensor: str, payload: bytes
    ) -> tuple[str, bytes] | None:
        """(ROS 2 type name, CDR bytes) of a raw message, or None (refused by the wire's
        checks, or a leaf with no ROS 2 message)."""
        ...

    def type_hash(self, type_name: str) -> str: ...


def default_path(out: Path) -> Path:
    """The bag next to ``out``: ``field.mcap`` -> ``field.ros2.mcap``."""
    return out.with_name(out.name.removesuffix(".mcap") + SUFFIX)


def ros_name(name: str) -> str:
    """A vehicle or sensor id as a ROS 2 name token (letters, digits, single ``_``, no leading
    digit)."""
    token = re.sub(r"_{2,}", "_", re.sub(r"[^A-Za-z0-9_]", "_", name))
    return "_" + token if token[:1].isdigit() else token


def _names(vehicle: str, sensor: str) -> tuple[str, ...]:
    if sensor == VEHICLE_STREAM:
        return (ros_name(vehicle),)
    return ros_name(vehicle), ros_name(sensor)


def _text(type_name: str, msg_dir: Path) -> str:
    package, *_, name = type_name.split("/")
    return (msg_dir / package / f"{name}.msg").read_text(encoding="utf-8")


@cache
def message_definition(type_name: str, msg_dir: Path) -> str:
    """The ``ros2msg`` schema text of ``pkg/msg/Name`` as rosbag2 writes it: the .msg file as
    it is, then for each type it uses (``pkg/Name``, in sorted order, depth first, each once)
    a newline, a line of 80 ``=``, ``MSG: pkg/Name`` and that type's text likewise."""
    seen: set[str] = set()

    def append(name: str) -> str:
        text = _text(name, msg_dir)
        package = name.split("/")[0]
        used = set()
        for match in _FIELD_TYPE.finditer(text):
            field_type = match[1]
            if field_type not in _PRIMITIVES:
                used.add(field_type if "/" in field_type else f"{package}/{field_type}")
        out = text
        for dep in sorted(used):
            if dep not in seen:
                seen.add(dep)
                out += f"\n{_DELIMITER}\nMSG: {dep}\n" + append(dep)
        return out

    return append(type_name)


class Ros2Bag:
    """The bag file: channels and schemas registered on a topic's first message. ``add`` runs
    on the recorder's writer thread only; ``messages`` counts what was written, ``skipped``
    the frames the wire's checks refused (no message)."""

    def __init__(self, path: Path, prefix: str, messages: Ros2Messages) -> None:
        self.path = path
        self._messages = messages
        self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(self._file)
        self._writer.start(profile=ROS2_PROFILE, library=f"simpletrack {version()}")
        self._writer.add_metadata(
            METADATA_NAME,
            {"tool": TOOL, "version": version(), "prefix": prefix, "labels": messages.labels},
        )
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str, str], int] = {}
        self._owners: dict[tuple[str, ...], tuple[str, str]] = {}  # topic names -> stream
        self._closed = False
        self.messages = 0
        self.skipped = 0

    def topic(self, vehicle: str, sensor: str, leaf: str) -> str:
        """The topic of a stream's detections or tracks (a fused vehicle's: sensor
        ``@vehicle``), kept apart from any other stream's."""
        names = _names(vehicle, sensor)
        n = 1
        while self._owners.setdefault(names, (vehicle, sensor)) != (vehicle, sensor):
            n += 1
            names = (*_names(vehicle, sensor)[:-1], f"{_names(vehicle, sensor)[-1]}_{n}")
        last = DETECTED_TOPIC if leaf == DETECTIONS else TRACKED_TOPIC
        return "/" + "/".join((TOPIC_ROOT, *names, last))

    def _channel(self, vehicle: str, sensor: str, leaf: str, type_name: str) -> int:
        channel = self._channels.get((vehicle, sensor, leaf))
        if channel is None:
            schema = self._schemas.get(type_name)
            if schema is None:
                text = message_definition(type_name, self._messages.msg_dir)
                schema = self._writer.register_schema(type_name, SCHEMA_ENCODING, text.encode())
                self._schemas[type_name] = schema
            channel = self._writer.register_channel(
                self.topic(vehicle, sensor, leaf),
                MESSAGE_ENCODING,
                schema,
                metadata={
                    "offered_qos_profiles": QOS_PROFILES,
                    "topic_type_hash": self._messages.type_hash(type_name),
                },
            )
            self._channels[(vehicle, sensor, leaf)] = channel
        return channel

    def add(
        self,
        leaf: str,
        vehicle: str,
        sensor: str,
        payload: bytes,
        *,
        log_time: int,
        publish_time: int,
        sequence: int,
    ) -> None:
        """A raw message of a detections or tracks key as its Autoware message."""
        if leaf not in (DETECTIONS, TRACKS):
            return
        try:
            converted = self._messages.convert(leaf, vehicle, sensor, payload)
        except Exception:  # a frame the conversion cannot take: counted, the bag goes on
            converted = None
        if converted is None:
            self.skipped += 1
            return
        type_name, data = converted
        channel = self._channel(vehicle, sensor, leaf, type_name)
        self._writer.add_message(
            channel, log_time=log_time, data=data, publish_time=publish_time, sequence=sequence
        )
        self.messages += 1

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
