"""ROS 2 type hashes (REP-2011 ``RIHS01_<sha256>``) of the messages in ``msg/``, computed from
the .msg files themselves, and the DDS type names: both are chunks of an rmw_zenoh key.

    type_hash("autoware_perception_msgs/msg/TrackedObjects")   # 'RIHS01_3559bd4e...'
    dds_type_name("autoware_perception_msgs/msg/TrackedObjects")
    # 'autoware_perception_msgs::msg::dds_::TrackedObjects_'

The hash is sha256 over the JSON of the type's description (its fields: name, type id, array
capacity, string capacity, nested type name; constants and defaults are not part of it) and
of every type it references, sorted by name, with Python's default JSON separators.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

MSG_DIR = Path(__file__).resolve().parent / "msg"

# type_description_interfaces/msg/FieldType.msg
NESTED_TYPE = 1
_PRIMITIVE_IDS = {
    "int8": 2,
    "uint8": 3,
    "int16": 4,
    "uint16": 5,
    "int32": 6,
    "uint32": 7,
    "int64": 8,
    "uint64": 9,
    "float32": 10,
    "float64": 11,
    "bool": 15,
    "string": 17,
}
BOUNDED_STRING = 21
# Offsets of the array kinds added to the element's id.
FIXED_ARRAY, BOUNDED_SEQUENCE, UNBOUNDED_SEQUENCE = 48, 96, 144

_ARRAY = re.compile(r"^(?P<base>[^\[\]]+)(\[(?P<bounded><=)?(?P<size>\d*)\])?$")


@dataclass(frozen=True, slots=True)
class FieldDesc:
    name: str
    type_id: int
    capacity: int = 0
    string_capacity: int = 0
    nested_type_name: str = ""

    def as_json(self) -> dict[str, object]:
        return {
            "name": self.name,
            "type": {
                "type_id": self.type_id,
                "capacity": self.capacity,
                "string_capacity": self.string_capacity,
                "nested_type_name": self.nested_type_name,
            },
        }


def parse_msg(text: str, type_name: str) -> list[FieldDesc]:
    """The fields of one .msg definition (``type_name`` is ``pkg/msg/Name``)."""
    package = type_name.split("/")[0]
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        typ, _, rest = line.partition(" ")
        rest = rest.strip()
        if "=" in rest:  # a constant: not part of the description
            continue
        name = rest.split()[0]
        fields.append(_field(name, typ, package, type_name))
    return fields


def _field(name: str, typ: str, package: str, owner: str) -> FieldDesc:
    m = _ARRAY.match(typ)
    if m is None:
        raise ValueError(f"{owner}: field {name!r} has an unreadable type {typ!r}")
    base, size = m["base"], m["size"]
    offset, capacity = 0, 0
    if m.group(2) is not None:
        if m["bounded"]:
            offset, capacity = BOUNDED_SEQUENCE, int(size)
        elif size:
            offset, capacity = FIXED_ARRAY, int(size)
        else:
            offset = UNBOUNDED_SEQUENCE
    if base.startswith("string<="):
        return FieldDesc(name, offset + BOUNDED_STRING, capacity, int(base[8:]))
    if base in _PRIMITIVE_IDS:
        return FieldDesc(name, offset + _PRIMITIVE_IDS[base], capacity)
    if "/" in base:
        pkg, _, msg = base.partition("/")
        nested = f"{pkg}/msg/{msg.removeprefix('msg/')}"
    elif base == "Header":  # the one name .msg files may use without its package
        nested = "std_msgs/msg/Header"
    else:
        nested = f"{package}/msg/{base}"
    return FieldDesc(name, offset + NESTED_TYPE, capacity, 0, nested)


@cache
def definitions() -> dict[str, list[FieldDesc]]:
    """Every message in ``msg/<package>/<Name>.msg`` by ``pkg/msg/Name``."""
    out = {}
    for path in sorted(MSG_DIR.glob("*/*.msg")):
        type_name = f"{path.parent.name}/msg/{path.stem}"
        out[type_name] = parse_msg(path.read_text(encoding="utf-8"), type_name)
    return out


def _referenced(type_name: str, defs: dict[str, list[FieldDesc]], seen: set[str]) -> None:
    if type_name not in defs:
        raise ValueError(f"message {type_name!r} is not among the definitions in {MSG_DIR}")
    for f in defs[type_name]:
        if f.nested_type_name and f.nested_type_name not in seen:
            seen.add(f.nested_type_name)
            _referenced(f.nested_type_name, defs, seen)


def _description(type_name: str, defs: dict[str, list[FieldDesc]]) -> dict[str, object]:
    return {"type_name": type_name, "fields": [f.as_json() for f in defs[type_name]]}


@cache
def type_hash(type_name: str) -> str:
    defs = definitions()
    seen: set[str] = set()
    _referenced(type_name, defs, seen)
    seen.discard(type_name)
    doc = {
        "type_description": _description(type_name, defs),
        "referenced_type_descriptions": [_description(t, defs) for t in sorted(seen)],
    }
    return "RIHS01_" + hashlib.sha256(json.dumps(doc).encode("utf-8")).hexdigest()


def dds_type_name(type_name: str) -> str:
    """``pkg/msg/Name`` as DDS (and rmw_zenoh) name it: ``pkg::msg::dds_::Name_``."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
