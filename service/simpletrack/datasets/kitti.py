"""KITTI tracking files: PointRCNN detections, labels, calibration, and tracking results.

Camera boxes are rows ``h, w, l, x, y, z, rot_y`` (the KITTI column order): ``(x, y, z)`` is the
bottom-face centre in the left camera frame (x right, y down, z forward).

The tracker works in a z-up frame. Our documented choice (the reference harness's, so our
tracks compare with its tracks):
``X = z_cam, Y = -x_cam, Z = -y_cam + h/2`` (box centre), ``yaw = wrap(-rot_y - pi/2)``;
``l, w, h`` unchanged. ``tracker_to_camera`` is its exact inverse.
Scores: detection logits become probabilities ``1 / (1 + exp(-logit))`` for the tracker, and
tracker probabilities are written back as logits ``log(p / (1 - p))``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes, wrap_angle
from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Tracks

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

KITTI_CLASSES = ("Car", "Pedestrian", "Cyclist")
TRAIN_SEQUENCES = ("0000", "0002", "0003", "0004", "0005", "0007", "0009", "0011", "0017", "0020")
FRAME_PERIOD = 0.1  # 10 Hz
H, W, L, X, Y, Z, RY = range(7)

# Image (width, height) by the left camera's focal length, i.e. by recording day. The KITTI
# tracking sequences come from three days with different image sizes; the reference result
# files clip their 2D boxes to these.
IMAGE_SIZE_BY_FOCAL = {721.5377: (1242, 375), 707.0493: (1224, 370), 718.856: (1238, 374)}
DEFAULT_IMAGE_SIZE = (1242, 375)
# Corners nearer than this to the image plane are left out of the 2D box, as in the reference.
MIN_CORNER_DEPTH = 0.1
# Probabilities are clipped this far from 0 and 1 before the logit, which stays finite (+-34.5).
PROB_EPS = 1e-15


# ----------------------------------------------------------------------------- frames
def camera_to_tracker(cam: F64) -> F64:
    """(N, 7) camera boxes -> (N, 7) tracker params ``x, y, z, yaw, l, w, h`` (z up)."""
    cam = np.asarray(cam, dtype=np.float64).reshape(-1, 7)
    out = np.empty_like(cam)
    out[:, 0] = cam[:, Z]
    out[:, 1] = -cam[:, X]
    out[:, 2] = -cam[:, Y] + cam[:, H] / 2
    out[:, 3] = wrap_angle(-cam[:, RY] - np.pi / 2)
    out[:, 4] = cam[:, L]
    out[:, 5] = cam[:, W]
    out[:, 6] = cam[:, H]
    return out


def tracker_to_camera(params: F64) -> F64:
    """Inverse of :func:`camera_to_tracker`; ``rot_y`` wrapped into [-pi, pi)."""
    p = np.asarray(params, dtype=np.float64).reshape(-1, 7)
    cam = np.empty_like(p)
    cam[:, H] = p[:, 6]
    cam[:, W] = p[:, 5]
    cam[:, L] = p[:, 4]
    cam[:, X] = -p[:, 1]
    cam[:, Y] = p[:, 6] / 2 - p[:, 2]
    cam[:, Z] = p[:, 0]
    cam[:, RY] = wrap_angle(-p[:, 3] - np.pi / 2)
    return cam


def logit_to_prob(logit: F64) -> F64:
    return np.asarray(1.0 / (1.0 + np.exp(-np.asarray(logit, dtype=np.float64))))


def prob_to_logit(p: F64) -> F64:
    q = np.clip(np.asarray(p, dtype=np.float64), PROB_EPS, 1.0 - PROB_EPS)
    return np.asarray(np.log(q) - np.log1p(-q))


# ----------------------------------------------------------------------------- calibration
@dataclass(frozen=True, slots=True)
class Calib:
    p2: F64  # (3, 4) left colour camera projection
    image_size: tuple[int, int]  # width, height


def read_calib(path: Path) -> Calib:
    """P2 from a KITTI tracking calib file, and the image size its camera implies."""
    for line in path.read_text().splitlines():
        key, _, rest = line.partition(":")
        if key.strip() == "P2":
            p2 = np.array(rest.split(), dtype=np.float64).reshape(3, 4)
            break
    else:
        raise ValueError(f"{path}: no P2 line")
    size = DEFAULT_IMAGE_SIZE
    for focal, wh in IMAGE_SIZE_BY_FOCAL.items():
        if abs(p2[0, 0] - focal) < 1e-3:
            size = wh
    return Calib(p2=p2, image_size=size)


def box_corners(cam: F64) -> F64:
    """(N, 8, 3) corners of camera boxes: bottom face first, then top (y - h)."""
    c, s = np.cos(cam[:, RY])[:, None], np.sin(cam[:, RY])[:, None]
    length, w, h = cam[:, L, None], cam[:, W, None], cam[:, H, None]
    dl = length * np.array([0.5, 0.5, -0.5, -0.5, 0.5, 0.5, -0.5, -0.5])
    dw = w * np.array([0.5, -0.5, -0.5, 0.5, 0.5, -0.5, -0.5, 0.5])
    dy = -h * np.array([0, 0, 0, 0, 1, 1, 1, 1])
    x = c * dl + s * dw + cam[:, X, None]
    y = dy + cam[:, Y, None]
    z = -s * dl + c * dw + cam[:, Z, None]
    return np.stack([x, y, z], axis=-1)


def project_boxes(cam: F64, calib: Calib) -> F64:
    """(N, 4) image boxes ``x1 y1 x2 y2``: the hull of the projected corners that are in front
    of the camera, clipped to the image. All corners behind: a zero box at the origin."""
    if len(cam) == 0:
        return np.zeros((0, 4))
    corners = box_corners(cam)
    hom = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=-1) @ calib.p2.T
    front = corners[..., 2] >= MIN_CORNER_DEPTH
    depth = np.where(front, hom[..., 2], 1.0)
    u, v = hom[..., 0] / depth, hom[..., 1] / depth
    box = np.stack(
        [
            np.where(front, u, np.inf).min(axis=1),
            np.where(front, v, np.inf).min(axis=1),
            np.where(front, u, -np.inf).max(axis=1),
            np.where(front, v, -np.inf).max(axis=1),
        ],
        axis=1,
    )
    width, height = calib.image_size
    box[:, [0, 2]] = np.clip(box[:, [0, 2]], 0, width - 1)
    box[:, [1, 3]] = np.clip(box[:, [1, 3]], 0, height - 1)
    box[~front.any(axis=1)] = 0.0
    return box


def observation_angle(cam: F64) -> F64:
    """KITTI's alpha: the yaw relative to the ray to the box, in [-pi, pi)."""
    return wrap_angle(cam[:, RY] - np.arctan2(cam[:, X], cam[:, Z]))


# ----------------------------------------------------------------------------- detections
@dataclass(frozen=True, slots=True)
class Detections:
    """One sequence's detections of one class: ``frame`` (N,), ``cam`` (N, 7), ``logit`` (N,),
    ``box2d`` (N, 4) as the detector wrote it."""

    frame: I64
    cam: F64
    logit: F64
    box2d: F64

    def __len__(self) -> int:
        return int(self.frame.shape[0])


def read_detections(path: Path) -> Detections:
    """A PointRCNN file ``frame, type, x1, y1, x2, y2, score, h, w, l, x, y, z, rot_y, alpha``."""
    text = path.read_text()
    if not text.strip():
        return Detections(np.zeros(0, np.int64), np.zeros((0, 7)), np.zeros(0), np.zeros((0, 4)))
    try:
        rows = np.loadtxt(text.splitlines(), delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: not a PointRCNN detection file ({exc})") from None
    if rows.shape[1] != 15:
        raise ValueError(f"{path}: expected 15 comma-separated columns, got {rows.shape[1]}")
    return Detections(
        frame=rows[:, 0].astype(np.int64),
        cam=rows[:, 7:14].copy(),
        logit=rows[:, 6].copy(),
        box2d=rows[:, 2:6].copy(),
    )


def detection_path(data_dir: Path, class_name: str, seq: str) -> Path:
    return data_dir / "detections" / "pointrcnn" / class_name / f"{seq}.txt"


def label_frame_count(path: Path) -> int:
    """Frames in a sequence as the evaluator counts them: last labelled frame + 1."""
    last = -1
    for line in path.read_text().splitlines():
        if line.strip():
            last = max(last, int(line.split(maxsplit=1)[0]))
    return last + 1


@dataclass(frozen=True, slots=True)
class SequenceFrame:
    index: int
    boxes: Boxes
    stamp: float


def load_sequence(
    data_dir: Path, seq: str, config: TrackerConfig, classes: Sequence[str]
) -> list[SequenceFrame]:
    """Every frame of a sequence (empty ones included, so the tracker ages its tracks) with
    the detections of ``classes`` as tracker boxes; class codes from ``config``."""
    per_class: list[tuple[int, Detections]] = []
    for name in classes:
        code = config_class_code(config, name)
        path = detection_path(data_dir, name, seq)
        if not path.is_file():
            raise FileNotFoundError(f"no detections for {name} in sequence {seq}: {path}")
        per_class.append((code, read_detections(path)))
    n_frames = 0
    for _, det in per_class:
        n_frames = max(n_frames, int(det.frame.max(initial=-1)) + 1)
    label = data_dir / "labels" / f"{seq}.txt"
    if label.is_file():
        n_frames = max(n_frames, label_frame_count(label))

    frame = np.concatenate([d.frame for _, d in per_class])
    params = camera_to_tracker(np.concatenate([d.cam for _, d in per_class]))
    score = logit_to_prob(np.concatenate([d.logit for _, d in per_class]))
    cls = np.concatenate([np.full(len(d), code, np.int32) for code, d in per_class])
    order = np.argsort(frame, kind="stable")
    frame, params, score, cls = frame[order], params[order], score[order], cls[order]
    bounds = np.searchsorted(frame, np.arange(n_frames + 1))
    out = []
    for k in range(n_frames):
        sl = slice(bounds[k], bounds[k + 1])
        out.append(
            SequenceFrame(
                index=k,
                boxes=Boxes.from_arrays(params[sl], score[sl], cls[sl]),
                stamp=k * FRAME_PERIOD,
            )
        )
    return out


# Other names a tracker config may give a KITTI class (the WOD preset says "vehicle").
CLASS_ALIASES = {"car": ("car", "vehicle"), "pedestrian": ("pedestrian",), "cyclist": ("cyclist",)}


def config_class_code(config: TrackerConfig, name: str) -> int:
    """The config's code for a KITTI class name (case-insensitive, aliases allowed)."""
    known = [n.lower() for n in config.class_names]
    for alias in CLASS_ALIASES.get(name.lower(), (name.lower(),)):
        if alias in known:
            return known.index(alias)
    raise KeyError(f"class {name!r} is not in the tracker config ({', '.join(config.class_names)})")


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True, slots=True)
class ResultRows:
    """Tracking results of one sequence, one row per box: ``cam`` (N, 7) camera boxes,
    ``score`` as written (a logit)."""

    frame: I64
    track_id: I64
    type_name: tuple[str, ...]
    cam: F64
    score: F64

    @classmethod
    def concat(cls, parts: Iterable[ResultRows]) -> ResultRows:
        items = list(parts)
        if not items:
            return cls(
                np.zeros(0, np.int64), np.zeros(0, np.int64), (), np.zeros((0, 7)), np.zeros(0)
            )
        return cls(
            frame=np.concatenate([p.frame for p in items]),
            track_id=np.concatenate([p.track_id for p in items]),
            type_name=tuple(t for p in items for t in p.type_name),
            cam=np.concatenate([p.cam for p in items]),
            score=np.concatenate([p.score for p in items]),
        )

    def by_frame(self) -> ResultRows:
        """The rows sorted by frame (stable: a frame's rows keep their order)."""
        order = np.argsort(self.frame, kind="stable")
        return ResultRows(
            frame=self.frame[order],
            track_id=self.track_id[order],
            type_name=tuple(self.type_name[i] for i in order),
            cam=self.cam[order],
            score=self.score[order],
        )


def tracks_to_rows(frame: int, ids: I64, boxes: Boxes, class_names: Sequence[str]) -> ResultRows:
    """A frame's tracker output (z-up boxes, probabilities) as result rows."""
    return ResultRows(
        frame=np.full(len(boxes), frame, np.int64),
        track_id=np.asarray(ids, dtype=np.int64),
        type_name=tuple(class_names[int(c)] for c in boxes.cls),
        cam=tracker_to_camera(boxes.params),
        score=prob_to_logit(boxes.score),
    )


def format_results(rows: ResultRows, calib: Calib) -> str:
    """KITTI tracking result lines: ``frame id type 0 0 alpha x1 y1 x2 y2 h w l x y z rot_y
    score``, six decimals, as the reference files."""
    box2d = project_boxes(rows.cam, calib)
    alpha = observation_angle(rows.cam)
    nums = np.column_stack([alpha, box2d, rows.cam, rows.score])
    lines = []
    for f, i, t, vals in zip(rows.frame, rows.track_id, rows.type_name, nums, strict=True):
        lines.append(f"{int(f)} {int(i)} {t} 0 0 " + " ".join(f"{v:.6f}" for v in vals))
    return "".join(line + "\n" for line in lines)


def result_class_names(config: TrackerConfig, classes: Sequence[str]) -> list[str]:
    """The config's class names with ``classes`` (KITTI type names) in their place: results
    carry KITTI's names whatever the config calls its classes."""
    names = list(config.class_names)
    for cls in classes:
        names[config_class_code(config, cls)] = cls
    return names


def write_tracked(
    out_dir: Path,
    seq: str,
    frames: Sequence[SequenceFrame],
    outputs: Sequence[Tracks],
    class_names: Sequence[str],
    calib: Calib,
) -> Path:
    """A tracked sequence's result file (``write_results`` of every frame's tracks)."""
    rows = ResultRows.concat(
        tracks_to_rows(f.index, t.ids, t.boxes, class_names)
        for f, t in zip(frames, outputs, strict=True)
    )
    return write_results(out_dir, seq, rows, calib)


def write_results(out_dir: Path, seq: str, rows: ResultRows, calib: Calib) -> Path:
    """``out_dir/data_0/<seq>.txt`` (all classes of the sequence, sorted by frame)."""
    ordered = rows.by_frame()
    path = out_dir / "data_0" / f"{seq}.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(format_results(ordered, calib))
    return path
