"""nuScenes detection results in, a nuScenes tracking submission out
(``simpletrack track nuscenes --detections``): the box mapping, scenes and time order from the
sample table, the submission's fields, the same tracks as ``track nuscenes`` on the same boxes,
and one-line errors for bad input.

``fixtures/nuscenes`` is synthetic (made-up objects, tokens and times): ``detections.json`` a
detection-results JSON of two scenes (4 and 5 samples, one sample with no box, barriers,
a one-off false positive; neither its samples nor ``v1.0-synthetic/sample.json`` in time
order) and the sample and scene tables it needs. nuscenes-devkit 1.2.0's ``load_prediction``
reads it (DetectionBox) and the submission made from it (TrackingBox); docs/NUSCENES.md."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from simpletrack.cli.main import main
from simpletrack.core.boxes import wrap_angle
from simpletrack.core.config import MotionModel, preset
from simpletrack.datasets.nuscenes import TYPE_NAMES, read_scene
from simpletrack.datasets.nuscenes_json import (
    DETECTION_NAMES,
    MAX_BOXES_PER_SAMPLE,
    TRACKING_NAMES,
    FormatError,
    nuscenes_to_tracker,
    read_detections,
    read_samples,
    scene_frames,
    scenes_to_track,
    track_scenes,
    tracker_to_nuscenes,
    yaw_of_quaternions,
)
from simpletrack.eval.track_nuscenes import track_scene

FIXTURE = Path(__file__).parent / "fixtures" / "nuscenes"
DETECTIONS = FIXTURE / "detections.json"
TABLES = FIXTURE / "v1.0-synthetic"
DETS = (
    Path(__file__).resolve().parents[2].parent / "shared" / "data" / "nuscenes" / "centerpoint_val"
)
# The fields of nuscenes-devkit's TrackingBox that a submission carries.
SUBMISSION_FIELDS = {
    "sample_token", "translation", "size", "rotation", "velocity",
    "tracking_id", "tracking_name", "tracking_score",
}  # fmt: skip


def run_fixture(tmp_path: Path, detections: Path = DETECTIONS, samples: Path = TABLES) -> Any:
    out = tmp_path / "submission.json"
    rc = main(
        [
            "track", "nuscenes", "--detections", str(detections), "--samples", str(samples),
            "--out", str(out),
        ]
    )  # fmt: skip
    assert rc == 0
    return json.loads(out.read_text())


# ----------------------------------------------------------------------------- boxes
def test_a_nuscenes_box_maps_to_the_trackers_layout() -> None:
    # A car heading 90 degrees (along +y): size w, l, h; a pure yaw quaternion w, x, y, z.
    c = math.cos(math.pi / 4)
    params = nuscenes_to_tracker(
        np.array([[600.0, 1600.0, 1.0]]), np.array([[1.9, 4.6, 1.7]]), np.array([[c, 0, 0, c]])
    )[0]
    assert params[:3].tolist() == [600.0, 1600.0, 1.0]
    assert params[3] == pytest.approx(math.pi / 2)
    assert params[4:].tolist() == [4.6, 1.9, 1.7]  # l, w, h


def test_yaw_is_the_heading_of_the_rotated_x_axis() -> None:
    # Any quaternion, any norm: the heading of R @ [1, 0, 0] in the xy plane.
    rng = np.random.default_rng(0)
    q = rng.normal(size=(300, 4)) * rng.uniform(0.2, 3.0, (300, 1))
    u = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = u.T
    heading = np.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))  # R[1, 0], R[0, 0]
    assert np.allclose(wrap_angle(yaw_of_quaternions(q) - heading), 0, atol=1e-12)
    assert (yaw_of_quaternions(q) >= -math.pi).all() and (yaw_of_quaternions(q) < math.pi).all()


def test_tracker_boxes_go_to_nuscenes_and_back() -> None:
    rng = np.random.default_rng(1)
    params = np.column_stack(
        [rng.uniform(-900, 900, (200, 3)), rng.uniform(-math.pi, math.pi - 1e-9, 200),
         rng.uniform(0.3, 12, (200, 3))]
    )  # fmt: skip
    translation, size, rotation = tracker_to_nuscenes(params)
    assert np.allclose(np.linalg.norm(rotation, axis=1), 1)
    assert (rotation[:, 1:3] == 0).all()
    back = nuscenes_to_tracker(translation, size, rotation)
    assert (back[:, [0, 1, 2, 4, 5, 6]] == params[:, [0, 1, 2, 4, 5, 6]]).all()
    assert np.allclose(wrap_angle(back[:, 3] - params[:, 3]), 0, atol=1e-12)


# ----------------------------------------------------------------------------- scenes and time
def test_samples_are_grouped_into_scenes_and_ordered_by_timestamp() -> None:
    table = read_samples(TABLES)
    dets = read_detections(DETECTIONS)
    scenes = scenes_to_track(dets, table)
    assert [s.name for s in scenes] == ["scene-a", "scene-b"]
    a = scenes[0]
    assert [round(a.stamp(s), 6) for s in a.samples] == [0.0, 0.499812, 1.000345, 1.500101]
    frames = scene_frames(dets, a, list(preset("nuscenes").class_names))
    car = preset("nuscenes").class_code("car")
    xs = [fr.boxes.params[fr.boxes.cls == car, 0][0] for fr in frames]
    assert xs == sorted(xs)  # a car driving forward, frame by frame
    # Barriers are no tracking class; the one-off bicycle is in frame 1 only.
    assert [len(fr.boxes) for fr in frames] == [3, 4, 3, 3]
    # The sample table's file or its folder; scene.json beside it names the scenes.
    assert read_samples(TABLES / "sample.json").scenes == table.scenes
    b = table.scene_of("scene-b")
    assert scenes_to_track(dets, table, ["scene-b"]) == scenes_to_track(dets, table, [b.token])
    assert [s.name for s in scenes_to_track(dets, table, [b.token])] == ["scene-b"]


def test_the_fixture_gives_a_complete_submission(tmp_path: Path) -> None:
    sub = run_fixture(tmp_path)
    det = json.loads(DETECTIONS.read_text())
    assert sub["meta"] == det["meta"]
    assert set(sub["results"]) == set(det["results"])  # every sample, the empty one too
    ids: dict[str, set[str]] = {}
    for token, boxes in sub["results"].items():
        assert 0 < len(boxes) <= MAX_BOXES_PER_SAMPLE
        for b in boxes:
            assert set(b) == SUBMISSION_FIELDS
            assert b["sample_token"] == token
            assert b["tracking_name"] in TRACKING_NAMES
            assert type(b["tracking_score"]) is float and 0 <= b["tracking_score"] <= 1
            assert isinstance(b["tracking_id"], str)
            assert len(b["translation"]) == 3 and len(b["size"]) == 3 and len(b["velocity"]) == 2
            assert len(b["rotation"]) == 4
            ids.setdefault(b["tracking_id"], set()).add(b["tracking_name"])
    # One track per object and scene (the input in no time order), ids unique across classes.
    assert sorted(ids) == sorted(
        f"scene-{s}_{c}_0" for s in "ab" for c in ("bicycle", "car", "pedestrian", "truck")
    )
    assert all(len(names) == 1 for names in ids.values())
    # The car's box in the submission is its detection's, the first time it is seen.
    first = sub["results"][read_samples(TABLES).scene_of("scene-a").samples[0].token]
    car = next(b for b in first if b["tracking_name"] == "car")
    det_car = next(b for b in det["results"][car["sample_token"]] if b["detection_name"] == "car")
    assert car["translation"] == det_car["translation"]
    assert car["size"] == det_car["size"]
    assert np.allclose(car["rotation"], det_car["rotation"], atol=1e-6)


def test_more_than_500_tracks_in_a_sample_keep_the_500_best(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    token, scene = "t" * 32, "s" * 32
    boxes = [
        {
            "sample_token": token, "translation": [10.0 * (i % 30), 10.0 * (i // 30), 1.0],
            "size": [1.9, 4.5, 1.6], "rotation": [1.0, 0.0, 0.0, 0.0], "velocity": [0.0, 0.0],
            "detection_name": "car", "detection_score": 0.05 + 0.9 * i / 520,
            "attribute_name": "",
        }
        for i in range(520)
    ]  # fmt: skip
    (tmp_path / "d.json").write_text(json.dumps({"meta": {}, "results": {token: boxes}}))
    (tmp_path / "sample.json").write_text(
        json.dumps([{"token": token, "scene_token": scene, "timestamp": 1}])
    )
    sub = run_fixture(tmp_path, tmp_path / "d.json", tmp_path / "sample.json")
    scores = sorted(b["tracking_score"] for b in sub["results"][token])
    assert len(scores) == MAX_BOXES_PER_SAMPLE and scores[0] == pytest.approx(0.05 + 0.9 * 20 / 520)
    assert "left out 20 lowest-scored boxes" in capsys.readouterr().out


def test_constant_velocity_motion_takes_the_detectors_velocity(tmp_path: Path) -> None:
    det = json.loads(DETECTIONS.read_text())
    table = read_samples(TABLES)
    config = preset("nuscenes").with_overrides(motion=MotionModel.CONSTANT_VELOCITY)
    scene = table.scene_of("scene-a")
    out = list(track_scenes(read_detections(DETECTIONS), [scene], config))
    car = next(b for b in out[0].boxes if b["tracking_name"] == "car")
    det_car = next(b for b in det["results"][car["sample_token"]] if b["detection_name"] == "car")
    assert car["velocity"] == det_car["velocity"]
    # Without it a box cannot move: refused, naming the sample and the field.
    for boxes in det["results"].values():
        for b in boxes:
            b.pop("velocity")
    (tmp_path / "r.json").write_text(json.dumps(det))
    no_velocity = read_detections(tmp_path / "r.json")  # fine for the Kalman filter
    first = scene.samples[0].token
    with pytest.raises(FormatError, match=rf"sample {first}, box 0: field 'velocity' must be fin"):
        list(track_scenes(no_velocity, [scene], config))


# ----------------------------------------------------------------------------- same tracks
def _token(scene: str, k: int) -> str:
    return hashlib.md5(f"{scene}/{k}".encode()).hexdigest()


def _results_from_scene_files(
    tmp_path: Path, scenes: tuple[str, ...], n_frames: int
) -> tuple[Path, Path, dict[str, tuple[str, int]]]:
    """The detection files' boxes (every class) as a detection-results JSON, and a sample
    table: one sample every 0.5 s, as `track nuscenes` times the files' frames."""
    names = list(TYPE_NAMES.values())
    results: dict[str, list[dict[str, Any]]] = {}
    samples, scene_rows, where = [], [], {}
    for s, scene in enumerate(scenes):
        frames = read_scene(DETS / f"{scene}.txt", names)[:n_frames]
        base = 1_533_000_000_000_000 + 10**9 * s
        for fr in frames:
            token = _token(scene, fr.index)
            where[token] = (scene, fr.index)
            samples.append(
                {"token": token, "timestamp": base + 500_000 * fr.index,
                 "scene_token": _token(scene, -1), "prev": "", "next": ""}
            )  # fmt: skip
            t, size, rot = tracker_to_nuscenes(fr.boxes.params)
            results[token] = [
                {
                    "sample_token": token, "translation": t[i].tolist(), "size": size[i].tolist(),
                    "rotation": rot[i].tolist(), "velocity": [0.0, 0.0],
                    "detection_name": names[int(fr.boxes.cls[i])],
                    "detection_score": float(fr.boxes.score[i]), "attribute_name": "",
                }
                for i in range(len(fr.boxes))
            ]  # fmt: skip
        scene_rows.append({"token": _token(scene, -1), "name": scene})
    # Neither file in time order.
    meta = {"use_camera": False, "use_lidar": True, "use_radar": False, "use_map": False,
            "use_external": False}  # fmt: skip
    det = tmp_path / "results.json"
    det.write_text(json.dumps({"meta": meta, "results": dict(reversed(list(results.items())))}))
    (tmp_path / "tables").mkdir()
    (tmp_path / "tables" / "sample.json").write_text(json.dumps(samples[::-1]))
    (tmp_path / "tables" / "scene.json").write_text(json.dumps(scene_rows))
    return det, tmp_path / "tables", where


@pytest.mark.data
@pytest.mark.skipif(not DETS.is_dir(), reason="needs ../shared/data/nuscenes")
def test_detections_json_gives_the_tracks_of_the_detection_files(tmp_path: Path) -> None:
    scenes, n_frames = ("scene-0003", "scene-0012"), 12
    det, tables, where = _results_from_scene_files(tmp_path, scenes, n_frames)
    sub = run_fixture(tmp_path, det, tables)
    got = []
    yaws = []
    for token, boxes in sub["results"].items():
        scene, frame = where[token]
        for b in boxes:
            prefix, cls, n = b["tracking_id"].rsplit("_", 2)
            assert (prefix, cls) == (scene, b["tracking_name"])
            (x, y, z), (w, length, h) = b["translation"], b["size"]
            yaws.append(float(yaw_of_quaternions(np.array(b["rotation"]))[0]))
            got.append(
                {"scene": scene, "frame": frame, "cls": cls, "id": int(n),
                 "box": [round(v, 2) for v in (x, y, z, length, w, h)],
                 "score": round(b["tracking_score"], 4)}
            )  # fmt: skip
    config = preset("nuscenes")  # the command's defaults: exact overlap, stable ties
    want, want_yaws = [], []
    for scene in scenes:
        for row in track_scene(DETS / f"{scene}.txt", config):
            if row["frame"] < n_frames:
                box = row["box"]
                want_yaws.append(box[3])
                want.append({**row, "box": box[:3] + box[4:]})
                del want[-1]["state"]
    assert len(want) > 1000 and len({r["cls"] for r in want}) >= 4
    assert got == want
    assert np.allclose(wrap_angle(np.array(yaws) - np.array(want_yaws)), 0, atol=6e-5)


# ----------------------------------------------------------------------------- bad input
def _edit(det: dict[str, Any], fn: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    det = copy.deepcopy(det)
    fn(det)
    return det


def _box(det: dict[str, Any]) -> dict[str, Any]:
    box: dict[str, Any] = next(iter(det["results"].values()))[0]
    return box


FIRST = next(iter(json.loads(DETECTIONS.read_text())["results"]))


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: _box(d).__setitem__(key, value)


def _drop(key: str) -> Callable[[dict[str, Any]], None]:
    return lambda d: _box(d).pop(key)


BAD_DETECTIONS = {
    "missing translation": (_drop("translation"), rf"sample {FIRST}, box 0: missing field 'translation'"),
    "missing score": (_drop("detection_score"), r"box 0: missing field 'detection_score'"),
    "missing name": (_drop("detection_name"), r"box 0: missing field 'detection_name'"),
    "unknown name": (_set("detection_name", "van"), r"box 0: unknown detection_name 'van'; the nuScenes detection classes are pedestrian, car, "),
    "NaN size": (_set("size", [1.9, float("nan"), 1.6]), r"box 0: field 'size' must be finite and positive, got \[1.9, nan, 1.6\]"),
    "NaN score": (_set("detection_score", float("nan")), r"box 0: field 'detection_score' must be in \[0, 1\], got nan"),
    "inf translation": (_set("translation", [1.0, float("inf"), 0.0]), r"box 0: field 'translation' must be finite"),
    "zero rotation": (_set("rotation", [0, 0, 0, 0]), r"box 0: field 'rotation' must be finite, not all 0"),
    "short size": (_set("size", [1.9, 4.6]), r"box 0: field 'size' must be 3 numbers, got \[1.9, 4.6\]"),
    "string number": (_set("translation", ["1", 2, 3]), r"box 0: field 'translation' must be 3 numbers"),
    "bool score": (_set("detection_score", True), r"box 0: field 'detection_score' must be a number, got True"),
    "huge number": (_set("translation", [10**400, 0, 0]), r"box 0: a number too large for a float"),
    "bad velocity": (_set("velocity", [1.0]), r"box 0: field 'velocity' must be 2 numbers"),
    "other sample": (_set("sample_token", "x"), r"box 0: field 'sample_token' is 'x', not the sample"),
    "box not an object": (lambda d: d["results"][FIRST].__setitem__(0, [1, 2]), r"box 0: must be an object"),
    "sample not a list": (lambda d: d["results"].__setitem__(FIRST, {}), rf"sample {FIRST}: must be a list of boxes"),
    "no results": (lambda d: d.pop("results"), r"field 'results' is missing \(a nuScenes detection-results JSON"),
    "no meta": (lambda d: d.pop("meta"), r"field 'meta' is missing"),
    "sample with no scene": (lambda d: d["results"].__setitem__("f" * 32, []), rf"sample {'f' * 32} is not in --samples .*, so it has no scene and no timestamp"),
    "sample of a scene missing": (lambda d: d["results"].pop(FIRST), rf"sample {FIRST} \(scene scene-b, frame 4 of 5\) is missing from 'results'; .*\[\] when it has no box"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_DETECTIONS))
def test_bad_detections_are_one_line_errors_naming_sample_and_field(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edit, message = BAD_DETECTIONS[case]
    path = tmp_path / "results.json"
    path.write_text(json.dumps(_edit(json.loads(DETECTIONS.read_text()), edit)))
    out = tmp_path / "submission.json"
    rc = main(
        ["track", "nuscenes", "--detections", str(path), "--samples", str(TABLES),
         "--out", str(out)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.startswith("simpletrack track: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert re.search(message, err), err
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


def _samples_edit(fn: Callable[[list[dict[str, Any]]], None]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = json.loads((TABLES / "sample.json").read_text())
    fn(rows)
    return rows


BAD_SAMPLES = {
    "no timestamp": (lambda r: r[0].pop("timestamp"), r"sample \w+: field 'timestamp' must be an integer \(microseconds\), got None"),
    "float timestamp": (lambda r: r[0].__setitem__("timestamp", 1.5), r"field 'timestamp' must be an integer"),
    "no scene": (lambda r: r[0].pop("scene_token"), r"sample \w+: field 'scene_token' must be a string"),
    "no token": (lambda r: r[0].pop("token"), r"record 0: field 'token' must be a string"),
    "twice": (lambda r: r.append(dict(r[0])), r"sample \w+ is listed twice"),
    "same time": (lambda r: r[1].__setitem__("timestamp", r[0]["timestamp"]), r"samples \w+ and \w+ of scene \w+ have the same timestamp"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_SAMPLES))
def test_bad_sample_tables_are_one_line_errors(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edit, message = BAD_SAMPLES[case]
    (tmp_path / "sample.json").write_text(json.dumps(_samples_edit(edit)))
    rc = main(
        ["track", "nuscenes", "--detections", str(DETECTIONS), "--samples", str(tmp_path),
         "--out", str(tmp_path / "out.json")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert re.search(message, err), err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--detections", str(DETECTIONS), "--out", "x.json"], "--detections needs --samples: nuScenes' sample table"),
        (["--detections", str(DETECTIONS), "--samples", str(TABLES)], "--detections needs --out"),
        (["--samples", str(TABLES)], "--samples goes with --detections"),
        (["--detections", "nope.json", "--samples", str(TABLES), "--out", "x.json"], "--detections nope.json does not exist"),
        (["--detections", str(DETECTIONS), "--samples", str(FIXTURE), "--out", "x.json"], "--samples: no sample.json in"),
        (["--detections", str(TABLES / "scene.json"), "--samples", str(TABLES), "--out", "x.json"], "must be a JSON object with 'meta' and 'results'"),
        (["--detections", str(DETECTIONS), "--samples", str(TABLES), "--out", "x.json", "--scenes", "scene-z"], "no scene 'scene-z' in"),
        (["--detections", str(DETECTIONS), "--samples", str(TABLES), "--out", "x.json", "--preset", "wod"], "are not nuScenes tracking classes"),
        (["--detections", str(DETECTIONS), "--samples", str(TABLES), "--out", "x.json", "--reference", "r.jsonl"], "does not go with --detections"),
    ],
)  # fmt: skip
def test_bad_arguments_are_one_line_errors(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["track", "nuscenes", *args])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and message in err, err


def test_text_that_is_not_json_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "r.json").write_text('{"meta": {}, "results": {')
    rc = main(
        ["track", "nuscenes", "--detections", str(tmp_path / "r.json"), "--samples", str(TABLES),
         "--out", str(tmp_path / "o.json")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "is not JSON" in err and err.count("\n") == 1, err


def test_every_detection_name_is_known() -> None:
    assert set(TRACKING_NAMES) < set(DETECTION_NAMES) and len(DETECTION_NAMES) == 10
    assert set(preset("nuscenes").class_names) == set(TRACKING_NAMES)
