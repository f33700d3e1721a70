"""``simpletrack plot``: valid pictures of the asked size, each track in its own colour."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simpletrack.cli.main import main
from simpletrack.plot import id_colour

FRAMES = 12


def write_recording(path: Path, streams: tuple[str, ...] = ("veh00/lidar",)) -> None:
    """Two tracks (ids 4 and 9) driving apart, as `simpletrack record --format jsonl` writes."""
    with path.open("w") as f:
        for stream in streams:
            vehicle, sensor = stream.split("/")
            for k in range(FRAMES):
                tracks = [
                    {
                        "id": 4,
                        "cls": "vehicle",
                        "box": [2.0 * k, 0, 0.8, 0, 4.5, 1.9, 1.6],
                        "score": 0.9,
                    },
                    {
                        "id": 9,
                        "cls": "cyclist",
                        "box": [0, 1.5 * k + 5, 0.8, 1.57, 1.8, 0.7, 1.7],
                        "score": 0.8,
                    },
                ]
                f.write(
                    json.dumps(
                        {
                            "vehicle": vehicle,
                            "sensor": sensor,
                            "seq": k,
                            "stamp_ns": k,
                            "tracks": tracks,
                        }
                    )
                    + "\n"
                )


def colour_present(png: Path, rgb: tuple[float, float, float], tol: int = 12) -> bool:
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    target = np.round(np.array(rgb) * 255).astype(int)
    return bool((np.abs(img - target).max(axis=2) <= tol).any())


def test_overview_png_has_the_asked_size_and_each_id_its_colour(tmp_path: Path) -> None:
    rec = tmp_path / "tracks.jsonl"
    write_recording(rec)
    out = tmp_path / "overview.png"
    assert main(["plot", str(rec), "--out", str(out), "--size", "640x480"]) == 0
    with Image.open(out) as img:
        assert img.format == "PNG" and img.size == (640, 480)
    assert colour_present(out, id_colour(4)) and colour_present(out, id_colour(9))
    assert id_colour(4) != id_colour(9)


def test_per_frame_pngs_with_truth_and_a_frame_range(tmp_path: Path) -> None:
    rec = tmp_path / "tracks.jsonl"
    write_recording(rec)
    out = tmp_path / "frames"
    assert main(["plot", str(rec), "--truth", str(rec), "--frames", "2:6", "--out", str(out),
                 "--size", "500x400"]) == 0  # fmt: skip
    pngs = sorted(out.glob("*.png"))
    assert [p.name for p in pngs] == [f"frame_{k:06d}.png" for k in range(2, 6)]
    for p in pngs:
        with Image.open(p) as img:
            img.verify()
        with Image.open(p) as img:
            assert img.size == (500, 400)


def test_gif_animation(tmp_path: Path) -> None:
    rec = tmp_path / "tracks.jsonl"
    write_recording(rec)
    out = tmp_path / "anim.gif"
    assert main(["plot", str(rec), "--frames", "0:5", "--out", str(out), "--size", "300x300"]) == 0
    with Image.open(out) as img:
        assert img.format == "GIF" and img.size == (300, 300)
        assert getattr(img, "n_frames", 1) == 5


def test_kitti_results_and_labels(tmp_path: Path) -> None:
    # frame id type 0 0 alpha x1 y1 x2 y2 h w l x y z rot_y score (camera frame)
    rows = [
        f"{k} 7 Car 0 0 0 100 100 200 200 1.5 1.6 3.9 {-2 + 0.1 * k:.2f} 1.6 {12 + k} -1.57 3.0"
        for k in range(FRAMES)
    ]
    results = tmp_path / "0000.txt"
    results.write_text("\n".join(rows) + "\n")
    labels = tmp_path / "labels.txt"
    labels.write_text(
        "\n".join(r.rsplit(" ", 1)[0] for r in rows)  # 17 columns
        + "\n0 -1 DontCare -1 -1 -10 1 1 2 2 -1000 -1000 -1000 -10 -1 -1 -1\n"
    )
    out = tmp_path / "kitti.png"
    assert main(["plot", str(results), "--truth", str(labels), "--out", str(out)]) == 0
    with Image.open(out) as img:
        assert img.size == (900, 900)
    assert colour_present(out, id_colour(7))


def test_mistakes_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "tracks.jsonl"
    write_recording(rec, streams=("veh00/lidar", "veh01/lidar"))
    cases = (
        ([str(tmp_path / "missing.jsonl"), "--out", str(tmp_path / "a.png")], "no such file"),
        ([str(rec), "--out", str(tmp_path / "a.png")], "--stream"),
        ([str(rec), "--stream", "veh09/x", "--out", str(tmp_path / "a.png")], "veh09/x"),
        ([str(rec), "--stream", "veh00/lidar", "--out", str(tmp_path / "a.jpg")], "--out"),
        (
            [
                str(rec),
                "--stream",
                "veh00/lidar",
                "--size",
                "big",
                "--out",
                str(tmp_path / "a.png"),
            ],
            "--size",
        ),
        (
            [
                str(rec),
                "--stream",
                "veh00/lidar",
                "--frames",
                "50:60",
                "--out",
                str(tmp_path / "a.png"),
            ],
            "--frames",
        ),
    )
    for args, word in cases:
        assert main(["plot", *args]) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("simpletrack plot: error: ") and word in err, err
        assert len(err.strip().splitlines()) == 1
