"""Bird's-eye-view pictures of a tracked sequence: per-frame PNGs, a trajectory overview, and
an animation (GIF through pillow, MP4 through ffmpeg when installed).

Tracks are drawn filled in a colour of their own (the same id keeps its colour in every
picture), ground truth as black dashed outlines, detections as thin grey outlines. x points
right and y up, in metres, in the frame the boxes were recorded in (z-up; KITTI camera boxes
are converted on reading, so x is forward and y to the left of the camera there).
"""

from __future__ import annotations

import colorsys
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure

from simpletrack.core.geometry import bev_corners
from simpletrack.datasets.track_files import FrameBoxes, Sequence

F64 = npt.NDArray[np.float64]

_EMPTY = FrameBoxes(
    ids=np.zeros(0, dtype=np.int64),
    params=np.zeros((0, 7)),
    cls=np.zeros(0, dtype=np.str_),
    score=np.zeros(0),
)


@dataclass(frozen=True, slots=True)
class PlotStyle:
    width: int = 900  # pixels
    height: int = 900
    dpi: int = 100
    margin: float = 4.0  # metres around everything drawn
    tail: int = 15  # frames of trajectory behind each track in per-frame pictures
    labels: bool = True


def id_colour(track_id: int) -> tuple[float, float, float]:
    """A stable, well-spread colour per id: golden-ratio steps around the hue circle."""
    hue = (track_id * 0.618033988749895) % 1.0
    sat = 0.65 + 0.3 * ((track_id * 0.37) % 1.0)
    return colorsys.hsv_to_rgb(hue, sat, 0.85)


def extent(layers: Iterable[Sequence], frames: Iterable[int], margin: float) -> tuple[F64, F64]:
    """(xmin, xmax), (ymin, ymax) covering every box of the given frames, plus a margin."""
    wanted = set(frames)
    pts = [
        bev_corners(fb.params).reshape(-1, 2)
        for layer in layers
        for k, fb in layer.items()
        if k in wanted and len(fb)
    ]
    if not pts:
        return np.array([-10.0, 10.0]), np.array([-10.0, 10.0])
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - margin, allp.max(axis=0) + margin
    return np.array([lo[0], hi[0]]), np.array([lo[1], hi[1]])


def _new_figure(style: PlotStyle) -> tuple[Figure, Axes]:
    fig = Figure(figsize=(style.width / style.dpi, style.height / style.dpi), dpi=style.dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes(_AXES_BOX)
    return fig, ax


_AXES_BOX = (0.08, 0.07, 0.88, 0.86)  # left, bottom, width, height (figure fractions)


def _frame_axes(ax: Axes, xlim: F64, ylim: F64, style: PlotStyle) -> None:
    # Equal metres on both axes: widen the shorter range to the axes' pixel shape rather
    # than distort the boxes.
    px_w, px_h = _AXES_BOX[2] * style.width, _AXES_BOX[3] * style.height
    xr, yr = float(xlim[1] - xlim[0]), float(ylim[1] - ylim[0])
    per_px = max(xr / px_w, yr / px_h)
    xc, yc = float(xlim.mean()), float(ylim.mean())
    ax.set_xlim(xc - per_px * px_w / 2, xc + per_px * px_w / 2)
    ax.set_ylim(yc - per_px * px_h / 2, yc + per_px * px_h / 2)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, linewidth=0.4, alpha=0.4)


def _heading_segments(params: F64) -> F64:
    front = params[:, :2] + 0.5 * params[:, 4:5] * np.stack(
        [np.cos(params[:, 3]), np.sin(params[:, 3])], axis=1
    )
    return np.stack([params[:, :2], front], axis=1)


def draw_frame(
    ax: Axes,
    tracks: FrameBoxes,
    truth: FrameBoxes | None,
    detections: FrameBoxes | None,
    history: dict[int, list[tuple[float, float]]],
    style: PlotStyle,
) -> None:
    if detections is not None and len(detections):
        ax.add_collection(
            PolyCollection(
                list(bev_corners(detections.params)),
                facecolors="none",
                edgecolors="0.55",
                linewidths=0.7,
                zorder=1,
            )
        )
    if truth is not None and len(truth):
        ax.add_collection(
            PolyCollection(
                list(bev_corners(truth.params)),
                facecolors="none",
                edgecolors="black",
                linewidths=1.0,
                linestyles="--",
                zorder=2,
            )
        )
    if len(tracks):
        colours = [id_colour(int(i)) for i in tracks.ids]
        ax.add_collection(
            PolyCollection(
                list(bev_corners(tracks.params)),
                facecolors=[(*c, 0.35) for c in colours],
                edgecolors=colours,
                linewidths=1.4,
                zorder=3,
            )
        )
        ax.add_collection(
            LineCollection(
                list(_heading_segments(tracks.params)), colors=colours, linewidths=1.4, zorder=4
            )
        )
        tails = [np.array(history[int(i)]) for i in tracks.ids if len(history.get(int(i), [])) > 1]
        tail_colours = [id_colour(int(i)) for i in tracks.ids if len(history.get(int(i), [])) > 1]
        if tails:
            ax.add_collection(LineCollection(tails, colors=tail_colours, linewidths=1.0, zorder=3))
        if style.labels:
            for i, p, c in zip(tracks.ids.tolist(), tracks.params, colours, strict=True):
                ax.annotate(
                    str(i),
                    (p[0], p[1]),
                    xytext=(4, 4),
                    textcoords="offset points",
                    fontsize=7,
                    color=c,
                    zorder=5,
                )


def _legend(ax: Axes, have_truth: bool, have_dets: bool) -> None:
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=id_colour(7), linewidth=2, label="track (colour = id)")]
    if have_truth:
        handles.append(Line2D([], [], color="black", linestyle="--", label="ground truth"))
    if have_dets:
        handles.append(Line2D([], [], color="0.55", linewidth=0.8, label="detection"))
    ax.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.8)


def _update_history(
    history: dict[int, list[tuple[float, float]]], tracks: FrameBoxes, tail: int
) -> None:
    for i, p in zip(tracks.ids.tolist(), tracks.params, strict=True):
        h = history.setdefault(i, [])
        h.append((float(p[0]), float(p[1])))
        del h[:-tail]


def render_frames(
    tracks: Sequence,
    truth: Sequence | None = None,
    detections: Sequence | None = None,
    frames: list[int] | None = None,
    style: PlotStyle | None = None,
    title: str = "",
) -> Iterable[tuple[int, Figure]]:
    """One figure per frame (all frames of any layer when ``frames`` is None), on a fixed extent."""
    style = style or PlotStyle()
    layers = [s for s in (tracks, truth, detections) if s is not None]
    if frames is None:
        frames = sorted({k for layer in layers for k in layer})
    xlim, ylim = extent(layers, frames, style.margin)
    history: dict[int, list[tuple[float, float]]] = {}
    for k in frames:
        fig, ax = _new_figure(style)
        _frame_axes(ax, xlim, ylim, style)
        trk = tracks.get(k, _EMPTY)
        _update_history(history, trk, style.tail)
        draw_frame(
            ax,
            trk,
            None if truth is None else truth.get(k, _EMPTY),
            None if detections is None else detections.get(k, _EMPTY),
            history,
            style,
        )
        _legend(ax, truth is not None, detections is not None)
        ax.set_title(f"{title}  frame {k}  ·  {len(trk)} tracks".strip(" ·"), fontsize=10)
        yield k, fig


def save_frames(
    out_dir: Path,
    tracks: Sequence,
    truth: Sequence | None = None,
    detections: Sequence | None = None,
    frames: list[int] | None = None,
    style: PlotStyle | None = None,
    title: str = "",
) -> list[Path]:
    """Write ``out_dir/frame_NNNNNN.png`` for every frame; returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, fig in render_frames(tracks, truth, detections, frames, style, title):
        path = out_dir / f"frame_{k:06d}.png"
        fig.savefig(path)
        paths.append(path)
    return paths


def save_animation(
    path: Path,
    tracks: Sequence,
    truth: Sequence | None = None,
    detections: Sequence | None = None,
    frames: list[int] | None = None,
    style: PlotStyle | None = None,
    fps: float = 10.0,
    title: str = "",
) -> Path:
    """An animated GIF (pillow) or MP4 (ffmpeg, when installed) of the sequence."""
    from matplotlib.animation import FFMpegWriter, PillowWriter

    style = style or PlotStyle()
    if path.suffix.lower() == ".mp4":
        if shutil.which("ffmpeg") is None:
            raise RuntimeError("writing MP4 needs ffmpeg on PATH; write a .gif instead")
        writer: PillowWriter | FFMpegWriter = FFMpegWriter(fps=fps)  # type: ignore[arg-type]
    else:
        writer = PillowWriter(fps=fps)  # type: ignore[arg-type]
    path.parent.mkdir(parents=True, exist_ok=True)
    # Each frame is drawn on its own figure, rasterised, and shown in one "player" figure
    # that the writer grabs from: the writer needs a single figure for the whole animation.
    player = Figure(figsize=(style.width / style.dpi, style.height / style.dpi), dpi=style.dpi)
    FigureCanvasAgg(player)
    screen = player.add_axes((0, 0, 1, 1))
    screen.set_axis_off()
    image = None
    with writer.saving(player, str(path), style.dpi):
        for _, fig in render_frames(tracks, truth, detections, frames, style, title):
            rgba = rasterise(fig)
            if image is None:
                image = screen.imshow(rgba, interpolation="none")
            else:
                image.set_data(rgba)
            writer.grab_frame()
    return path


def rasterise(fig: Figure) -> npt.NDArray[np.uint8]:
    """The figure's pixels, (H, W, 4) RGBA."""
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)
    canvas.draw()  # type: ignore[no-untyped-call]
    pixels = canvas.buffer_rgba()  # type: ignore[no-untyped-call]
    return np.array(pixels, dtype=np.uint8)  # a copy: the canvas buffer is reused


def save_overview(
    path: Path,
    tracks: Sequence,
    truth: Sequence | None = None,
    style: PlotStyle | None = None,
    title: str = "",
) -> Path:
    """One picture of every trajectory: each track id's path in its colour, its last box drawn,
    ground-truth paths as thin black dashes."""
    style = style or PlotStyle()
    layers = [s for s in (tracks, truth) if s is not None]
    frames = sorted({k for layer in layers for k in layer})
    xlim, ylim = extent(layers, frames, style.margin)
    fig, ax = _new_figure(style)
    _frame_axes(ax, xlim, ylim, style)
    if truth is not None:
        paths, _ = _paths(truth, frames)
        if paths:
            ax.add_collection(
                LineCollection(
                    [p[:, :2] for p in paths.values()],
                    colors="black",
                    linewidths=0.7,
                    linestyles="--",
                    alpha=0.7,
                    zorder=1,
                )
            )
    paths, last = _paths(tracks, frames)
    ids = sorted(paths)
    colours = [id_colour(i) for i in ids]
    if ids:
        ax.add_collection(
            LineCollection([paths[i][:, :2] for i in ids], colors=colours, linewidths=1.6, zorder=2)
        )
        ends = np.array([last[i] for i in ids])
        # Tracks of a few frames (often false positives) are drawn faint, not hidden.
        lived = np.array([len(paths[i]) >= 5 for i in ids])
        ax.add_collection(
            PolyCollection(
                list(bev_corners(ends)),
                facecolors=[(*c, 0.4 if ok else 0.1) for c, ok in zip(colours, lived, strict=True)],
                edgecolors=[(*c, 1.0 if ok else 0.3) for c, ok in zip(colours, lived, strict=True)],
                zorder=3,
            )
        )
        starts = np.array([paths[i][0, :2] for i in ids])
        ax.scatter(starts[:, 0], starts[:, 1], s=8, c=colours, marker="o", zorder=3)
        if style.labels:
            for i, c in zip(ids, colours, strict=True):
                if len(paths[i]) < 5:
                    continue  # short-lived tracks would bury the rest under labels
                ax.annotate(
                    str(i),
                    (last[i][0], last[i][1]),
                    xytext=(4, 4),
                    textcoords="offset points",
                    fontsize=7,
                    color=c,
                )
    _legend(ax, truth is not None, False)
    span = f"frames {frames[0]}-{frames[-1]}" if frames else "no frames"
    ax.set_title(f"{title}  {len(ids)} tracks, {span}".strip(), fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def _paths(seq: Sequence, frames: list[int]) -> tuple[dict[int, F64], dict[int, F64]]:
    """Per id: its centres over time (T, 3) and its last box (7,)."""
    pts: dict[int, list[F64]] = {}
    last: dict[int, F64] = {}
    for k in frames:
        fb = seq.get(k)
        if fb is None:
            continue
        for i, p in zip(fb.ids.tolist(), fb.params, strict=True):
            if i < 0:
                continue
            pts.setdefault(i, []).append(p[:3])
            last[i] = p
    return {i: np.array(v) for i, v in pts.items()}, last
