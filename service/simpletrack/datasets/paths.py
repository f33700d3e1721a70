"""Where the datasets are. There is no default folder: a command that reads a dataset takes
``--data FOLDER``, or without it the ``SIMPLETRACK_DATA`` environment variable, the folder that
holds them all::

    $SIMPLETRACK_DATA/kitti/                     labels/, calib/, detections/pointrcnn/
    $SIMPLETRACK_DATA/nuscenes/centerpoint_val/  scene-*.txt (CenterPoint detections)
    $SIMPLETRACK_DATA/reference/                 the reference implementation's results

With neither, the command says in one line what to pass and what the folder must hold
(``MissingData``), rather than looking for a folder of a development checkout that an
installed user never had.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

ENV = "SIMPLETRACK_DATA"


@dataclass(frozen=True, slots=True)
class Layout:
    """One dataset as a command's ``--data`` takes it."""

    what: str  # what is missing, for the message: "KITTI data"
    sub: str  # its folder under $SIMPLETRACK_DATA ("" for that folder itself)
    holds: str  # what the folder given to --data must hold


DATA = Layout("data folder", "", "kitti/ and nuscenes/centerpoint_val/")
KITTI = Layout("KITTI data", "kitti", "labels/, calib/, detections/pointrcnn/")
NUSCENES = Layout("nuScenes detections", "nuscenes/centerpoint_val", "scene-*.txt files")


class MissingData(LookupError):
    """Neither ``--data`` nor ``SIMPLETRACK_DATA``; ``str()`` is the one-line message."""


def data_root() -> Path | None:
    """``$SIMPLETRACK_DATA``, or None when it is unset or empty."""
    value = os.environ.get(ENV, "").strip()
    return Path(value).expanduser() if value else None


def missing_message(layout: Layout) -> str:
    """The one line a command prints when it has no folder for ``layout``."""
    env = f"{ENV} to the folder holding {layout.sub}/" if layout.sub else f"{ENV} to it"
    return f"no {layout.what}: pass --data FOLDER (with {layout.holds}) or set {env}"


def data_dir(given: Path | None, layout: Layout) -> Path:
    """The folder a command reads ``layout`` from: ``--data`` (``given``) if given, else
    ``$SIMPLETRACK_DATA/<layout.sub>``; ``MissingData`` with neither."""
    if given is not None:
        return given
    root = data_root()
    if root is None:
        raise MissingData(missing_message(layout))
    return root / layout.sub if layout.sub else root


def default_help(layout: Layout) -> str:
    """How a ``--data`` option's help names its default."""
    return f"default: ${ENV}/{layout.sub}" if layout.sub else f"default: ${ENV}"
