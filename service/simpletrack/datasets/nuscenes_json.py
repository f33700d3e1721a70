"""nuScenes detection results in, a nuScenes tracking submission out
(``simpletrack track nuscenes --detections results.json --samples SAMPLES --out submission.json``).

Both files are the formats nuscenes-devkit defines (``nuscenes/eval/common/loaders.py``
``load_prediction`` with ``DetectionBox``, resp. ``TrackingBox``):

- detection results: ``{"meta": {...}, "results": {sample_token: [box, ...]}}``, a box
  ``{"sample_token", "translation": [x, y, z], "size": [w, l, h], "rotation": [w, x, y, z],
  "velocity": [vx, vy], "detection_name", "detection_score", "attribute_name"}`` in the global
  frame, every sample of the evaluated scenes present (``[]`` when it has no box);
- tracking submission: the same ``meta``, and per sample ``{"sample_token", "translation",
  "size", "rotation", "velocity", "tracking_id", "tracking_name", "tracking_score"}``, at most
  500 boxes a sample, every sample of the tracked scenes present.

A results file has no scenes and no time order, only sample tokens. Both come from the
nuScenes sample table (``sample.json``: ``token``, ``scene_token``, ``timestamp`` in
microseconds, ``prev``/``next``), read from ``--samples`` (the file, or the table folder such as
``<dataroot>/v1.0-trainval``; ``scene.json`` beside it, when present, names the scenes).
A scene's samples are tracked in timestamp order, the frame's stamp in seconds from the
scene's first sample. The boxes are global already, so the tracker runs in the global frame
with no ego pose.

Boxes map to the tracker's z-up boxes as the detection files' reader does
(simpletrack.datasets.nuscenes): centre ``(x, y, z)`` = ``translation`` (the box centre),
``yaw`` the heading about z of the rotation (a quaternion's pitch and roll are dropped),
``l, w, h`` = ``size[1], size[0], size[2]``; and back, the rotation a pure yaw quaternion.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import MotionModel, TrackerConfig
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.nuscenes import TYPE_NAMES, SceneFrame

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

# nuscenes-devkit's DETECTION_NAMES (the same 10 classes as the detection files' types) and
# its tracking challenge's classes (eval/tracking/configs/tracking_nips_2019.json).
DETECTION_NAMES = tuple(TYPE_NAMES.values())
TRACKING_NAMES = ("bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck")
MAX_BOXES_PER_SAMPLE = 500  # the tracking challenge's max_boxes_per_sample
US_PER_S = 1_000_000
_REPR_LIMIT = 80


class FormatError(ValueError):
    """Input that is not what the nuScenes formats say, naming the sample and the field."""


# ----------------------------------------------------------------------------- boxes
def yaw_of_quaternions(q: F64) -> F64:
    """(N, 4) quaternions ``w, x, y, z`` -> (N,) heading about z in [-pi, pi): the angle of
    the rotated x axis in the xy plane (pyquaternion's ``yaw_pitch_roll[0]``, which the
    nuScenes devkit and the reference use). Any norm but 0."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    w, x, y, z = q.T
    yaw = np.arctan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)  # [-pi, pi]
    return np.asarray(np.where(yaw >= np.pi, -np.pi, yaw), dtype=np.float64)


def yaw_quaternions(yaw: F64) -> F64:
    """(N,) headings -> (N, 4) unit quaternions ``w, x, y, z`` of pure rotations about z."""
    half = np.asarray(yaw, dtype=np.float64).reshape(-1) / 2.0
    zero = np.zeros_like(half)
    return np.column_stack([np.cos(half), zero, zero, np.sin(half)])


def nuscenes_to_tracker(translation: F64, size: F64, rotation: F64) -> F64:
    """nuScenes boxes (translation (N, 3), size (N, 3) ``w, l, h``, rotation (N, 4)) ->
    (N, 7) tracker params ``x, y, z, yaw, l, w, h``."""
    t = np.asarray(translation, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(size, dtype=np.float64).reshape(-1, 3)
    out = np.empty((t.shape[0], 7))
    out[:, 0:3] = t
    out[:, 3] = yaw_of_quaternions(rotation)
    out[:, 4] = s[:, 1]
    out[:, 5] = s[:, 0]
    out[:, 6] = s[:, 2]
    return out


def tracker_to_nuscenes(params: F64) -> tuple[F64, F64, F64]:
    """Inverse of :func:`nuscenes_to_tracker`: (translation, size ``w, l, h``, rotation)."""
    p = np.asarray(params, dtype=np.float64).reshape(-1, 7)
    return p[:, 0:3].copy(), p[:, [5, 4, 6]].copy(), yaw_quaternions(p[:, 3])


# ----------------------------------------------------------------------------- sample table
@dataclass(frozen=True, slots=True)
class Sample:
    token: str
    scene_token: str
    timestamp: int  # microseconds


@dataclass(frozen=True, slots=True)
class Scene:
    token: str
    name: str  # scene.json's name, else the token
    samples: tuple[Sample, ...]  # in time order

    def stamp(self, sample: Sample) -> float:
        """Seconds from the scene's first sample."""
        return (sample.timestamp - self.samples[0].timestamp) / US_PER_S


@dataclass(frozen=True, slots=True)
class SampleTable:
    """Which scene each sample belongs to and when, from nuScenes' sample (and scene) table."""

    source: Path
    samples: dict[str, Sample]
    scenes: dict[str, Scene]  # by scene token, in order of first appearance in sample.json

    def scene_of(self, name_or_token: str) -> Scene:
        if name_or_token in self.scenes:
            return self.scenes[name_or_token]
        for scene in self.scenes.values():
            if scene.name == name_or_token:
                return scene
        raise FormatError(f"no scene {name_or_token!r} in {self.source}")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= _REPR_LIMIT else text[: _REPR_LIMIT - 3] + "..."


def _load_json(path: Path, what: str) -> Any:
    try:
        with path.open() as f:
            return json.load(f)
    except OSError as exc:
        raise FormatError(f"{what} {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{what} {path} is not JSON: {exc}") from None


def read_samples(path: Path) -> SampleTable:
    """nuScenes' ``sample.json`` (or the table folder holding it); ``scene.json`` beside it,
    when present, names the scenes. Each record needs ``token``, ``scene_token`` and
    ``timestamp`` (integer microseconds); other fields are ignored."""
    path = Path(path)
    file = path / "sample.json" if path.is_dir() else path
    if not file.is_file():
        where = f"no sample.json in {path}" if path.is_dir() else f"{path} does not exist"
        raise FormatError(f"--samples: {where} (nuScenes' sample table, e.g. v1.0-trainval/)")
    records = _load_json(file, "--samples")
    if not isinstance(records, list):
        raise FormatError(f"--samples {file}: must be a JSON list of sample records")
    samples: dict[str, Sample] = {}
    by_scene: dict[str, list[Sample]] = {}
    for i, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise FormatError(f"--samples {file}: record {i} is not an object")
        token = rec.get("token")
        if not isinstance(token, str) or not token:
            raise FormatError(f"--samples {file}: record {i}: field 'token' must be a string")
        scene = rec.get("scene_token")
        if not isinstance(scene, str) or not scene:
            raise FormatError(
                f"--samples {file}: sample {token}: field 'scene_token' must be a string, "
                f"got {_short(scene)}"
            )
        stamp = rec.get("timestamp")
        if type(stamp) is not int or not 0 <= stamp < 2**63:
            raise FormatError(
                f"--samples {file}: sample {token}: field 'timestamp' must be an integer "
                f"(microseconds), got {_short(stamp)}"
            )
        if token in samples:
            raise FormatError(f"--samples {file}: sample {token} is listed twice")
        sample = Sample(token=token, scene_token=scene, timestamp=stamp)
        samples[token] = sample
        by_scene.setdefault(scene, []).append(sample)
    names = _scene_names(file.parent / "scene.json")
    scenes: dict[str, Scene] = {}
    for token, members in by_scene.items():
        members.sort(key=lambda s: s.timestamp)
        for a, b in pairwise(members):
            if a.timestamp == b.timestamp:
                raise FormatError(
                    f"--samples {file}: samples {a.token} and {b.token} of scene {token} have "
                    f"the same timestamp {a.timestamp}"
                )
        scenes[token] = Scene(token=token, name=names.get(token, token), samples=tuple(members))
    return SampleTable(source=file, samples=samples, scenes=scenes)


def _scene_names(path: Path) -> dict[str, str]:
    if not path.is_file():
        return {}
    records = _load_json(path, "scene table")
    if not isinstance(records, list):
        raise FormatError(f"scene table {path}: must be a JSON list of scene records")
    names: dict[str, str] = {}
    for i, rec in enumerate(records):
        if not (
            isinstance(rec, dict)
            and isinstance(rec.get("token"), str)
            and isinstance(rec.get("name"), str)
        ):
            raise FormatError(f"scene table {path}: record {i} needs string 'token' and 'name'")
        names[rec["token"]] = rec["name"]
    return names


# ----------------------------------------------------------------------------- detections
@dataclass(frozen=True, slots=True)
class SampleDetections:
    """One sample's boxes, every detection class: params (N, 7) in the tracker's layout."""

    params: F64
    score: F64
    name: I32  # index into DETECTION_NAMES
    velocity: F64  # (N, 2); NaN where the file has none


@dataclass(frozen=True, slots=True)
class DetectionResults:
    source: Path
    meta: dict[str, Any]
    samples: dict[str, SampleDetections]  # by sample token, in file order


_NUMBER = (int, float)


def _numbers(box: dict[str, Any], key: str, n: int, where: str) -> list[float]:
    if key not in box:
        raise FormatError(f"{where}: missing field {key!r}")
    value = box[key]
    if not (isinstance(value, list) and len(value) == n and all(type(v) in _NUMBER for v in value)):
        raise FormatError(f"{where}: field {key!r} must be {n} numbers, got {_short(value)}")
    return value


def _velocity(box: dict[str, Any], where: str) -> list[float]:
    value = box.get("velocity")
    if value is None:
        return [math.nan, math.nan]
    if not (
        isinstance(value, list)
        and len(value) == 2
        and all(v is None or type(v) in _NUMBER for v in value)
    ):
        raise FormatError(f"{where}: field 'velocity' must be 2 numbers, got {_short(value)}")
    return [math.nan if v is None else v for v in value]


def _check_box(box: Any, token: str, where: str) -> tuple[list[float], ...]:
    """One box's translation, size, rotation, velocity, [class index] and [score], checked."""
    if not isinstance(box, dict):
        raise FormatError(f"{where}: must be an object, got {_short(box)}")
    if box.get("sample_token", token) != token:
        raise FormatError(
            f"{where}: field 'sample_token' is {_short(box['sample_token'])}, not the "
            "sample it is listed under"
        )
    translation = _numbers(box, "translation", 3, where)
    size = _numbers(box, "size", 3, where)
    rotation = _numbers(box, "rotation", 4, where)
    velocity = _velocity(box, where)
    cls = box.get("detection_name")
    if cls not in DETECTION_NAMES:
        got = "missing field 'detection_name'" if "detection_name" not in box else None
        raise FormatError(
            f"{where}: {got or f'unknown detection_name {_short(cls)}'}; the nuScenes "
            f"detection classes are {', '.join(DETECTION_NAMES)}"
        )
    if "detection_score" not in box:
        raise FormatError(f"{where}: missing field 'detection_score'")
    score = box["detection_score"]
    if type(score) not in _NUMBER:
        raise FormatError(f"{where}: field 'detection_score' must be a number, got {_short(score)}")
    return translation, size, rotation, velocity, [DETECTION_NAMES.index(cls)], [score]


def _sample_detections(token: str, boxes: Any, source: Path) -> SampleDetections:
    where0 = f"--detections {source}: sample {token}"
    if not isinstance(boxes, list):
        raise FormatError(f"{where0}: must be a list of boxes, got {_short(boxes)}")
    n = len(boxes)
    t, s, r, v = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 4)), np.empty((n, 2))
    score, name = np.empty(n), np.empty(n, dtype=np.int32)
    for i, box in enumerate(boxes):
        where = f"{where0}, box {i}"
        fields = _check_box(box, token, where)
        try:
            t[i], s[i], r[i], v[i], name[i : i + 1], score[i : i + 1] = fields
        except OverflowError:
            raise FormatError(f"{where}: a number too large for a float") from None
    for key, values, rule, ok in (
        ("translation", t, "finite", np.isfinite(t).all(axis=1)),
        ("size", s, "finite and positive", (np.isfinite(s) & (s > 0)).all(axis=1)),
        ("rotation", r, "finite, not all 0", np.isfinite(r).all(axis=1) & (r != 0).any(axis=1)),
        ("detection_score", score, "in [0, 1]", (score >= 0) & (score <= 1)),
    ):
        if not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            got = values[i].tolist()
            raise FormatError(f"{where0}, box {i}: field {key!r} must be {rule}, got {got}")
    return SampleDetections(params=nuscenes_to_tracker(t, s, r), score=score, name=name, velocity=v)


def read_detections(path: Path) -> DetectionResults:
    """A nuScenes detection-results JSON, every box checked (FormatError names the sample,
    the box's index and the field). ``velocity`` may be missing or null (NaN here);
    ``attribute_name`` and any other field are ignored."""
    path = Path(path)
    if not path.is_file():
        raise FormatError(f"--detections {path} does not exist")
    data = _load_json(path, "--detections")
    if not isinstance(data, dict):
        raise FormatError(f"--detections {path}: must be a JSON object with 'meta' and 'results'")
    for key in ("meta", "results"):
        if not isinstance(data.get(key), dict):
            got = "missing" if key not in data else f"not an object: {_short(data[key])}"
            raise FormatError(
                f"--detections {path}: field {key!r} is {got} (a nuScenes detection-results "
                "JSON: {'meta': {...}, 'results': {sample_token: [box, ...]}})"
            )
    results: dict[str, Any] = data.pop("results")
    samples = {}
    for token in list(results):
        samples[token] = _sample_detections(token, results.pop(token), path)
    return DetectionResults(source=path, meta=data["meta"], samples=samples)


# ----------------------------------------------------------------------------- tracking
def scenes_to_track(
    detections: DetectionResults, table: SampleTable, scenes: Sequence[str] = ()
) -> list[Scene]:
    """The scenes to track: the named ones (names or tokens), else every scene with a sample
    in the results, by name. Every sample of the results must be in the table,
    and every sample of a tracked scene in the results."""
    unknown = [t for t in detections.samples if t not in table.samples]
    if unknown:
        more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
        raise FormatError(
            f"--detections {detections.source}: sample {unknown[0]}{more} is not in --samples "
            f"{table.source}, so it has no scene and no timestamp (another nuScenes version?)"
        )
    if scenes:
        chosen = [table.scene_of(s) for s in scenes]
    else:
        present = {table.samples[t].scene_token for t in detections.samples}
        chosen = sorted(
            (s for s in table.scenes.values() if s.token in present), key=lambda s: s.name
        )
    for scene in chosen:
        missing = [s for s in scene.samples if s.token not in detections.samples]
        if missing:
            k = scene.samples.index(missing[0])
            raise FormatError(
                f"--detections {detections.source}: sample {missing[0].token} (scene "
                f"{scene.name}, frame {k} of {len(scene.samples)}) is missing from 'results'; "
                f"the format lists every sample, [] when it has no box ({len(missing)} missing "
                "in this scene)"
            )
    return chosen


def scene_frames(
    detections: DetectionResults, scene: Scene, classes: Sequence[str], *, velocity: bool = False
) -> list[SceneFrame]:
    """The scene's samples as tracker frames in time order, keeping only boxes of ``classes``
    (codes = positions), as simpletrack.datasets.nuscenes.read_scene gives a scene file.
    ``velocity``: give the boxes the detector's velocity (non-finite ones refused)."""
    code_of_name = np.array([classes.index(n) if n in classes else -1 for n in DETECTION_NAMES])
    out = []
    for k, sample in enumerate(scene.samples):
        d = detections.samples[sample.token]
        cls = code_of_name[d.name].astype(np.int32)
        rows = np.flatnonzero(cls >= 0)
        vel = None
        if velocity:
            vel = d.velocity[rows]
            bad = ~np.isfinite(vel).all(axis=1)
            if bad.any():
                i = int(rows[np.flatnonzero(bad)[0]])
                raise FormatError(
                    f"--detections {detections.source}: sample {sample.token}, box {i}: field "
                    f"'velocity' must be finite for motion constant_velocity, got "
                    f"{d.velocity[i].tolist()}"
                )
        boxes = Boxes(params=d.params[rows], score=d.score[rows], cls=cls[rows], velocity=vel)
        out.append(SceneFrame(index=k, stamp=scene.stamp(sample), boxes=boxes))
    return out


def check_tracking_classes(config: TrackerConfig) -> None:
    """The config's classes must be nuScenes tracking names (they name the output's boxes)."""
    odd = [c for c in config.class_names if c not in TRACKING_NAMES]
    if odd:
        raise FormatError(
            f"the preset's classes {', '.join(odd)} are not nuScenes tracking classes "
            f"({', '.join(TRACKING_NAMES)}); use --preset nuscenes"
        )


@dataclass(frozen=True, slots=True)
class SampleTracks:
    scene: Scene
    frame: int
    sample: Sample
    boxes: list[dict[str, Any]]  # the submission's boxes of this sample
    dropped: int  # boxes over MAX_BOXES_PER_SAMPLE left out (lowest scores)


def track_scenes(
    detections: DetectionResults, scenes: Iterable[Scene], config: TrackerConfig
) -> Iterator[SampleTracks]:
    """Track each scene with its own tracker, as simpletrack.eval.track_nuscenes.track_scene
    tracks a scene file (one tracker for all classes; ids per scene and class from 0, in the
    order of birth). ``tracking_id`` is ``<scene name>_<class>_<id>``, unique in the whole
    submission (the devkit averages a track's score over its id within a scene, across
    classes)."""
    check_tracking_classes(config)
    names = list(config.class_names)
    velocity = config.motion is MotionModel.CONSTANT_VELOCITY
    for scene in scenes:
        tracker = Tracker(config)
        local: list[dict[int, int]] = [{} for _ in names]
        frames = scene_frames(detections, scene, names, velocity=velocity)
        for sample, fr in zip(scene.samples, frames, strict=True):
            tracks = tracker.step(Frame(boxes=fr.boxes, stamp=fr.stamp))
            order = np.argsort(tracks.boxes.cls, kind="stable").tolist()
            codes, raw = tracks.boxes.cls.tolist(), tracks.ids.tolist()
            ids = [local[codes[i]].setdefault(raw[i], len(local[codes[i]])) for i in order]
            boxes = _submission_boxes(scene.name, sample.token, names, tracks, order, ids)
            dropped = max(0, len(boxes) - MAX_BOXES_PER_SAMPLE)
            if dropped:
                best = sorted(range(len(boxes)), key=lambda j: -boxes[j]["tracking_score"])
                boxes = [boxes[j] for j in sorted(best[:MAX_BOXES_PER_SAMPLE])]
            yield SampleTracks(scene, fr.index, sample, boxes, dropped)


def _submission_boxes(
    scene: str, token: str, names: list[str], tracks: Tracks, order: list[int], ids: list[int]
) -> list[dict[str, Any]]:
    translation, size, rotation = tracker_to_nuscenes(tracks.boxes.params)
    t, s, r = translation.tolist(), size.tolist(), rotation.tolist()
    v = tracks.velocity[:, :2].tolist()
    score = tracks.boxes.score.tolist()
    codes = tracks.boxes.cls.tolist()
    out = []
    for k, i in enumerate(order):
        cls = names[codes[i]]
        out.append(
            {
                "sample_token": token,
                "translation": t[i],
                "size": s[i],
                "rotation": r[i],
                "velocity": v[i],
                "tracking_id": f"{scene}_{cls}_{ids[k]}",
                "tracking_name": cls,
                "tracking_score": float(score[i]),
            }
        )
    return out


def write_submission(
    f: TextIO, meta: dict[str, Any], samples: Iterable[SampleTracks]
) -> tuple[int, int, int]:
    """Stream a tracking submission JSON: ``meta`` and each sample's boxes as they come.
    Returns (samples, boxes, boxes dropped over the per-sample limit)."""
    f.write('{"meta":' + json.dumps(meta, separators=(",", ":")) + ',"results":{')
    n_samples = n_boxes = n_dropped = 0
    for st in samples:
        if n_samples:
            f.write(",")
        f.write(json.dumps(st.sample.token) + ":")
        f.write(json.dumps(st.boxes, separators=(",", ":"), allow_nan=False))
        n_samples += 1
        n_boxes += len(st.boxes)
        n_dropped += st.dropped
    f.write("}}\n")
    return n_samples, n_boxes, n_dropped
