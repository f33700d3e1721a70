"""Autoware classification labels <-> the service's class names.

    labels = label_map("kitti")                         # a preset's default map
    labels = label_map("CAR=car,TRUCK=car,7=pedestrian") # or LABEL=class pairs (names or numbers)
    labels.class_of(Label.CAR)          # 'Car' (None: the label is not tracked)
    labels.label_of("Car")              # Label.CAR: the first label mapped to the class

Default maps, one per service preset (Autoware's UNKNOWN, ANIMAL, HAZARD, OVER_DRIVABLE and
UNDER_DRIVABLE map to nothing: objects with them are not tracked):
    nuscenes  CAR car, TRUCK truck, BUS bus, TRAILER trailer, MOTORCYCLE motorcycle,
              BICYCLE bicycle, PEDESTRIAN pedestrian
    kitti     CAR Car, PEDESTRIAN Pedestrian, BICYCLE Cyclist
    wod       CAR, TRUCK, BUS, TRAILER, MOTORCYCLE vehicle; BICYCLE cyclist; PEDESTRIAN pedestrian
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from simpletrack.ros2.messages import Label

PRESET_LABELS: dict[str, dict[int, str]] = {
    "nuscenes": {
        Label.CAR: "car",
        Label.TRUCK: "truck",
        Label.BUS: "bus",
        Label.TRAILER: "trailer",
        Label.MOTORCYCLE: "motorcycle",
        Label.BICYCLE: "bicycle",
        Label.PEDESTRIAN: "pedestrian",
    },
    "kitti": {Label.CAR: "Car", Label.PEDESTRIAN: "Pedestrian", Label.BICYCLE: "Cyclist"},
    "wod": {
        Label.CAR: "vehicle",
        Label.TRUCK: "vehicle",
        Label.BUS: "vehicle",
        Label.TRAILER: "vehicle",
        Label.MOTORCYCLE: "vehicle",
        Label.BICYCLE: "cyclist",
        Label.PEDESTRIAN: "pedestrian",
    },
}


@dataclass(frozen=True, slots=True)
class LabelMap:
    name: str  # the preset, or "custom"
    classes_by_label: Mapping[int, str]

    def class_of(self, label: int) -> str | None:
        return self.classes_by_label.get(label)

    def label_of(self, cls: str) -> int:
        """The first (lowest) label mapped to ``cls``; UNKNOWN for a class outside the map."""
        for label in sorted(self.classes_by_label):
            if self.classes_by_label[label] == cls:
                return label
        return Label.UNKNOWN

    @property
    def classes(self) -> tuple[str, ...]:
        """The class names, in label order, each once."""
        return tuple(dict.fromkeys(self.classes_by_label[k] for k in sorted(self.classes_by_label)))

    def describe(self) -> str:
        return ", ".join(f"{_label_name(k)}={v}" for k, v in sorted(self.classes_by_label.items()))


def _label_name(label: int) -> str:
    try:
        return Label(label).name
    except ValueError:
        return str(label)


def _label(text: str) -> int:
    t = text.strip()
    if t.isdigit():
        value = int(t)
        if value > 255:
            raise ValueError(f"label {t} is not a uint8")
        return value
    try:
        return Label[t.upper()]
    except KeyError:
        names = ", ".join(label.name for label in Label)
        raise ValueError(f"label {t!r} is neither a number nor one of {names}") from None


def label_map(spec: str) -> LabelMap:
    """A preset's default map (``nuscenes``, ``kitti``, ``wod``) or ``LABEL=class`` pairs."""
    if spec in PRESET_LABELS:
        return LabelMap(spec, dict(PRESET_LABELS[spec]))
    out: dict[int, str] = {}
    for pair in spec.split(","):
        label, sep, cls = pair.partition("=")
        if not sep or not cls.strip():
            presets = ", ".join(PRESET_LABELS)
            raise ValueError(
                f"--labels {spec!r}: expected a preset ({presets}) or LABEL=class pairs "
                "separated by commas, e.g. CAR=car,PEDESTRIAN=pedestrian"
            )
        code = _label(label)
        if code in out:
            raise ValueError(f"--labels {spec!r}: label {label.strip()} is mapped twice")
        out[code] = cls.strip()
    return LabelMap("custom", out)
