"""The wire <-> core adapter: the column layout, round trips in float32, track-state codes,
ignored classes, and the exact columns the service puts on the wire for a fixed input."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from simpletrack.core import jit
from simpletrack.core.boxes import Boxes
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.lifecycle import TrackState, UpdateKind
from simpletrack.server.finite import first_non_finite
from simpletrack.wire import (
    BoxArrays,
    DecodedDetections,
    TrackArrays,
    WireTrackState,
    decode_detection_frame,
    encode_detection_frame,
    encode_track_frame,
)
from simpletrack.wire.codec import Rejection
from simpletrack.wire.convert import (
    boxes_from_wire,
    boxes_to_wire,
    frame_from_wire,
    pack_tracks_checked,
    pack_vehicle_tracks_checked,
    track_boxes_from_wire,
    tracks_from_wire,
    tracks_to_wire,
    vehicle_tracks_to_wire,
    wire_states,
)
from simpletrack.wire.reasons import ErrorReason
from simpletrack.wire.vehicle_tracks import decode_vehicle_track_frame, encode_vehicle_track_frame

CLASSES = ("Car", "Pedestrian")
F32, F64, I32, I64 = np.float32, np.float64, np.int32, np.int64


def assert_identical(got: Any, want: Any) -> None:
    """Same fields, and every array with the same dtype, shape and bytes."""
    assert type(got) is type(want)
    for f in dataclasses.fields(want):
        g, w = getattr(got, f.name), getattr(want, f.name)
        if isinstance(w, np.ndarray):
            assert isinstance(g, np.ndarray), f.name
            assert (g.dtype, g.shape) == (w.dtype, w.shape), f.name
            assert g.tobytes() == w.tobytes(), f"{f.name}: {g} != {w}"
        elif dataclasses.is_dataclass(w):
            assert_identical(g, w)
        else:
            assert g == w, f.name


def random_boxes(n: int, velocity: bool) -> Boxes:
    rng = np.random.default_rng(n)
    params = np.column_stack(
        [rng.normal(0, 30, (n, 3)), rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 5, (n, 3))]
    )
    return Boxes.from_arrays(
        params,
        rng.uniform(0, 1, n),
        rng.integers(0, len(CLASSES), n),
        rng.normal(0, 5, (n, 2)) if velocity else None,
    )


# --- the fixed inputs and what the service puts on the wire for them -------------------------
def three_tracks() -> Tracks:
    """One tentative, one confirmed and updated, one confirmed but coasting."""
    return Tracks(
        ids=np.array([0, 1, 2], I64),
        boxes=Boxes.from_arrays(
            [
                [1, 2, 3, 0.5, 4, 5, 6],
                [-1, -2, 0.25, -1.5, 0.75, 0.5, 1.75],
                [10, 0, 0, 3, 4, 2, 1.5],
            ],
            [0.9, 0.125, 0.3],
            [0, 1, 0],
        ),
        velocity=np.array([[1, 0, 0], [0, -0.5, 0], [2.5, 1, 0.125]], F64),
        state=np.array([TrackState.TENTATIVE, TrackState.CONFIRMED, TrackState.CONFIRMED], np.int8),
        update=np.array([UpdateKind.MATCHED, UpdateKind.MATCHED, UpdateKind.COASTED], np.int8),
        hits=np.array([1, 5, 7], I32),
        age=np.array([1, 6, 9], I32),
        time_since_update=np.array([0, 0, 2], I32),
    )


RECORDED_TRACKS = TrackArrays(
    classes=CLASSES,
    id=np.array([100, 101, 102], I64),
    class_index=np.array([0, 1, 0], I32),
    center=np.array([[1, 2, 3], [-1, -2, 0.25], [10, 0, 0]], F32),
    size=np.array([[4, 5, 6], [0.75, 0.5, 1.75], [4, 2, 1.5]], F32),
    yaw=np.array([0.5, -1.5, 3], F32),
    score=np.array([0.9, 0.125, 0.3], F64),
    velocity=np.array([[1, 0, 0], [0, -0.5, 0], [2.5, 1, 0.125]], F32),
    state=np.array([0, 1, 2], I32),  # tentative, confirmed, coasting
    hits=np.array([1, 5, 7], I32),
    age=np.array([1, 6, 9], I32),
    time_since_update=np.array([0, 0, 2], I32),
)

POSE = np.array([[1, 0, 0, 5], [0, 1, 0, -2], [0, 0, 1, 0.5], [0, 0, 0, 1]], F64)


def three_detections() -> DecodedDetections:
    """A car, a van the tracker ignores (code -1) and a pedestrian, decoded as the service does."""
    arrays = BoxArrays(
        classes=("Car", "Van", "Pedestrian"),
        class_index=np.array([0, 1, 2], I32),
        center=np.array([[1, 2, 3], [7, 7, 7], [-1, -2, 0.25]], F32),
        size=np.array([[4, 5, 6], [3, 3, 3], [0.75, 0.5, 1.75]], F32),
        yaw=np.array([0.5, 1, -1.5], F32),
        score=np.array([0.9, 0.8, 0.125], F64),
        velocity=np.array([[1, 0], [2, 2], [0, -0.5]], F32),
    )
    payload = encode_detection_frame(
        vehicle="v", sensor="s", seq=3, stamp_ns=10**9, frame_id="lidar", boxes=arrays,
        pose=POSE, key_frame=False,
    )  # fmt: skip
    decoded = decode_detection_frame(payload, class_codes={"Car": 0, "Van": -1, "Pedestrian": 1})
    assert isinstance(decoded, DecodedDetections), decoded
    return decoded


RECORDED_FRAME = Frame(
    boxes=Boxes(
        params=np.array([[1, 2, 3, 0.5, 4, 5, 6], [-1, -2, 0.25, -1.5, 0.75, 0.5, 1.75]], F64),
        score=np.array([0.9, 0.125], F64),
        cls=np.array([0, 1], I32),
        velocity=np.array([[1, 0], [0, -0.5]], F64),
    ),
    stamp=2.5,
    pose=POSE,
    key_frame=False,
)


def test_tracks_to_wire_gives_the_recorded_columns() -> None:
    assert_identical(tracks_to_wire(three_tracks(), 100, CLASSES), RECORDED_TRACKS)


def test_frame_from_wire_gives_the_recorded_frame_and_counts_the_ignored_box() -> None:
    frame, ignored = frame_from_wire(three_detections(), 2.5)
    assert ignored == 1
    assert_identical(frame, RECORDED_FRAME)


@pytest.mark.parametrize("velocity", [False, True])
def test_the_compiled_rows_are_the_numpy_ones(
    velocity: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """frame_from_wire's one compiled call (core/input_kernels.py detection_rows) gives the
    numpy path's frame: the same rows, values, dtypes and ignored count, with ignored
    classes anywhere, none, all, and no boxes."""
    from simpletrack.wire import convert

    if not jit.compiled():
        pytest.skip("kernels run uncompiled: frame_from_wire takes the numpy path then")
    rng = np.random.default_rng(11)
    cases = [(n, rng.integers(-1, len(CLASSES), n).astype(I32)) for n in (0, 1, 9, 300)]
    cases += [(5, np.full(5, -1, I32)), (5, np.zeros(5, I32))]
    for n, codes in cases:
        w = boxes_to_wire(random_boxes(n, velocity), CLASSES)
        payload = encode_detection_frame(
            vehicle="v", sensor="s", seq=1, stamp_ns=1, frame_id="f", boxes=w
        )
        decoded = decode_detection_frame(payload)
        assert isinstance(decoded, DecodedDetections)
        decoded = dataclasses.replace(decoded, codes=codes)
        got = frame_from_wire(decoded, 2.5)
        with monkeypatch.context() as m:
            m.setattr(convert, "_compiled", False)
            want = frame_from_wire(decoded, 2.5)
        assert got[1] == want[1] == int((codes < 0).sum())
        assert_identical(got[0], want[0])
        assert got[0].boxes.params.flags.c_contiguous


# The service's own copies, until pool.py calls the adapter; then delete these two tests.
def test_boxes_to_wire_splits_the_core_row_into_centre_yaw_and_size() -> None:
    boxes = Boxes.from_arrays([[1, 2, 3, 0.5, 4, 5, 6]], [0.75], [1], [[7, 8]])
    w = boxes_to_wire(boxes, CLASSES)
    assert w.classes == CLASSES
    assert w.center.tolist() == [[1, 2, 3]] and w.center.dtype == F32
    assert w.yaw.tolist() == [0.5] and w.yaw.dtype == F32
    assert w.size.tolist() == [[4, 5, 6]] and w.size.dtype == F32
    assert w.score.tolist() == [0.75] and w.score.dtype == F64
    assert w.class_index.tolist() == [1] and w.class_index.dtype == I32
    assert w.velocity is not None and w.velocity.tolist() == [[7, 8]]


@pytest.mark.parametrize("velocity", [False, True])
def test_boxes_survive_the_wire_within_float32(velocity: bool) -> None:
    boxes = random_boxes(50, velocity)
    back = boxes_from_wire(boxes_to_wire(boxes, CLASSES))
    np.testing.assert_array_equal(back.params, boxes.params.astype(F32).astype(F64))
    np.testing.assert_allclose(back.params, boxes.params, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(back.score, boxes.score)  # scores stay float64
    np.testing.assert_array_equal(back.cls, boxes.cls)
    if velocity:
        assert boxes.velocity is not None and back.velocity is not None
        np.testing.assert_allclose(back.velocity, boxes.velocity, rtol=1e-6, atol=1e-5)
    else:
        assert back.velocity is None


def test_empty_boxes_survive_the_wire() -> None:
    back = boxes_from_wire(boxes_to_wire(Boxes.empty(), CLASSES))
    assert len(back) == 0 and back.params.shape == (0, 7)


def test_a_class_code_without_a_name_is_refused() -> None:
    with pytest.raises(ValueError, match="class code 2"):
        boxes_to_wire(Boxes.from_arrays(np.ones((1, 7)), [0.5], [2]), CLASSES)


def test_boxes_of_ignored_classes_are_dropped() -> None:
    w = boxes_to_wire(random_boxes(4, velocity=True), CLASSES)
    kept = boxes_from_wire(w, codes=np.array([-1, 0, -1, 1], I32))
    assert kept.cls.tolist() == [0, 1]
    np.testing.assert_array_equal(kept.params[:, 0], w.center[[1, 3], 0].astype(F64))
    assert kept.velocity is not None and kept.velocity.shape == (2, 2)


def test_wire_states_codes_tentative_confirmed_and_coasting() -> None:
    states = wire_states(three_tracks())
    assert states.dtype == I32
    assert states.tolist() == [
        WireTrackState.TENTATIVE,
        WireTrackState.CONFIRMED,
        WireTrackState.COASTING,
    ]


def test_tracks_come_back_from_the_wire_with_coasting_read_as_confirmed() -> None:
    tracks = three_tracks()
    back = tracks_from_wire(tracks_to_wire(tracks, 0, CLASSES))
    np.testing.assert_array_equal(back.ids, tracks.ids)
    np.testing.assert_array_equal(back.boxes.params, tracks.boxes.params)  # exact in float32
    np.testing.assert_array_equal(back.boxes.cls, tracks.boxes.cls)
    np.testing.assert_array_equal(back.velocity, tracks.velocity)
    assert back.state.tolist() == [TrackState.TENTATIVE, TrackState.CONFIRMED, TrackState.CONFIRMED]
    assert back.update.tolist() == [UpdateKind.MATCHED, UpdateKind.MATCHED, UpdateKind.COASTED]
    assert back.time_since_update.tolist() == [0, 0, 2]


def test_track_boxes_use_the_callers_class_table_and_drop_the_rest() -> None:
    w = tracks_to_wire(three_tracks(), 0, CLASSES)
    own = track_boxes_from_wire(w)
    assert own.cls.tolist() == [0, 1, 0]
    assert own.velocity is not None and own.velocity.tolist() == [[1, 0], [0, -0.5], [2.5, 1]]
    peds = track_boxes_from_wire(w, classes=("Cyclist", "Pedestrian"))
    assert peds.cls.tolist() == [1]
    assert peds.params.tolist() == [[-1, -2, 0.25, -1.5, 0.75, 0.5, 1.75]]


def test_class_codes_follow_the_callers_table_as_it_changes() -> None:
    """The decoder remembers each table of class names it has looked up for a mapping; a
    mapping changed since is looked up again (an unknown class is refused at once)."""
    boxes = BoxArrays(
        classes=("car", "bus"),
        class_index=np.array([0, 1, 0], np.int32),
        center=np.zeros((3, 3), np.float32),
        size=np.ones((3, 3), np.float32),
        yaw=np.zeros(3, np.float32),
        score=np.full(3, 0.5),
    )
    payload = encode_detection_frame(
        vehicle="v", sensor="s", seq=1, stamp_ns=1, frame_id="f", boxes=boxes
    )
    codes = {"car": 3, "bus": -1}
    first = decode_detection_frame(payload, class_codes=codes)
    assert not isinstance(first, Rejection) and first.codes is not None
    assert first.codes.tolist() == [3, -1, 3]
    again = decode_detection_frame(payload, class_codes=codes)
    assert not isinstance(again, Rejection) and again.codes is not None
    assert again.codes.tolist() == [3, -1, 3]
    codes["car"] = 5
    changed = decode_detection_frame(payload, class_codes=codes)
    assert not isinstance(changed, Rejection) and changed.codes is not None
    assert changed.codes.tolist() == [5, -1, 5]
    del codes["bus"]
    refused = decode_detection_frame(payload, class_codes=codes)
    assert isinstance(refused, Rejection)
    assert (refused.reason, refused.field) == (ErrorReason.UNKNOWN_CLASS, "boxes.classes.1")


def random_tracks(n: int, covariance: bool, seed: int) -> Tracks:
    """n tracks of every state, with or without a covariance, ages in seconds."""
    rng = np.random.default_rng(seed)
    cov = rng.normal(0, 2, (n, 6, 6))
    return Tracks(
        ids=rng.integers(0, 10**6, n).astype(I64),
        boxes=random_boxes(n, False),
        velocity=rng.normal(0, 5, (n, 3)),
        state=rng.integers(0, 3, n).astype(np.int8),
        update=rng.integers(0, 2, n).astype(np.int8),
        hits=rng.integers(0, 50, n).astype(I32),
        age=rng.integers(0, 90, n).astype(I32),
        time_since_update=rng.integers(0, 3, n).astype(I32),
        covariance=(cov + cov.transpose(0, 2, 1)) if covariance else None,
        age_s=rng.uniform(0, 9, n),
        time_since_update_s=rng.uniform(0, 0.3, n),
    )


def poisoned(tracks: Tracks, rng: np.random.Generator) -> Tracks:
    """One or two values of the float columns NaN, inf, or past float32's range (inf once
    sent as float32; 3.4028235e38 rounds to float32's largest, 3.4028236e38 too)."""
    params, velocity = tracks.boxes.params.copy(), tracks.velocity.copy()
    score, age_s = tracks.boxes.score.copy(), np.array(tracks.age_s)
    cov = None if tracks.covariance is None else tracks.covariance.copy()
    columns = [a for a in (params, velocity, score, age_s, cov) if a is not None]
    for _ in range(int(rng.integers(1, 3))):
        values = columns[int(rng.integers(len(columns)))]
        bad = [np.nan, np.inf, -np.inf, 1e39, -1e39, 3.4028235e38, 3.4028236e38]
        values.flat[int(rng.integers(values.size))] = bad[int(rng.integers(len(bad)))]
    boxes = dataclasses.replace(tracks.boxes, params=params, score=score)
    return dataclasses.replace(tracks, boxes=boxes, velocity=velocity, covariance=cov, age_s=age_s)


HEADER: dict[str, Any] = {
    "vehicle": "v7",
    "sensor": "lidar_top",
    "seq": 2**40,
    "stamp_ns": 1_700_000_000_123_456_789,
    "frame_id": "map",
    "key_frame": False,
    "instance": "tracker-0",
    "received_ns": 1_700_000_000_200_000_000,
    "published_ns": 1_700_000_000_210_000_000,
}


@pytest.mark.parametrize("covariance", [True, False])
def test_the_packed_tracks_are_the_encoders_bytes_with_the_guards_finding(
    covariance: bool,
) -> None:
    """pack_tracks_checked (one compiled call) gives the bytes encode_track_frame writes for
    tracks_to_wire's columns, for each version and epoch, and the finite guard's first
    non-finite (column, row): on ordinary tracks, on none, at every msgpack size boundary
    of the count and the columns (fixint/uint8/uint16, bin8/16/32), with long class tables,
    and on tracks with NaN, inf or values past float32 anywhere in their float columns."""
    if not jit.compiled():
        assert pack_tracks_checked(three_tracks(), 0, CLASSES, 3) is None
        pytest.skip("kernels run uncompiled: the service takes tracks_to_wire then")
    rng = np.random.default_rng(5)
    many = tuple(f"class_{k}_{'x' * k}" for k in range(40))  # array16, str8 names
    cases = [(random_tracks(n, covariance, n), CLASSES) for n in (0, 1, 7, 127, 128, 140)]
    cases += [(random_tracks(n, covariance, n), many) for n in (255, 256, 3200)]
    cases += [(poisoned(random_tracks(30, covariance, k), rng), CLASSES) for k in range(200)]
    found = 0
    for k, (tracks, classes) in enumerate(cases):
        with np.errstate(all="ignore"):  # the numpy path's casts overflow where poisoned
            want = tracks_to_wire(tracks, 1000, classes)
        bad = first_non_finite(want)
        found += bad is not None
        for version in (1, 2, 3):
            checked = pack_tracks_checked(tracks, 1000, classes, version)
            assert checked is not None
            packed, got_bad = checked
            assert got_bad == bad
            if bad is not None:
                assert packed == b""
                continue
            epoch = None if k % 2 else k
            pose = None if k % 3 else [float(v) for v in range(16)]
            expected = encode_track_frame(
                **HEADER, pose=pose, tracks=want, schema_version=version, epoch=epoch
            )
            got = encode_track_frame(
                **HEADER, pose=pose, tracks=packed, schema_version=version, epoch=epoch
            )
            assert got == expected, (len(tracks.ids), version, epoch)
    assert found > 100  # most poisoned ones are refused (not: values rounding into range, a
    # covariance entry below the diagonal)


VEHICLE: dict[str, Any] = {
    "vehicle": "v7",
    "seq": 2**33,
    "stamp_ns": 1_700_000_000_123_456_789,
    "sensor_seq": 12,
    "frame_id": "base_link",
    "instance": "tracker-0",
    "received_ns": 1_700_000_000_200_000_000,
    "published_ns": 1_700_000_000_210_000_000,
}


@pytest.mark.parametrize("covariance", [True, False])
def test_a_vehicle_s_packed_tracks_are_the_encoders_bytes(covariance: bool) -> None:
    """pack_vehicle_tracks_checked gives the bytes encode_vehicle_track_frame writes for
    vehicle_tracks_to_wire's columns (the map's size moving from a fixmap to map 16 and
    within it, with and without an epoch, a pose, 1-3 sensors); None where a value is NaN
    or inf (the columns' way then names it); ValueError for a misshapen column."""
    if not jit.compiled():
        assert (
            pack_vehicle_tracks_checked(three_tracks(), np.ones(3), np.ones((3, 1)), CLASSES, 1)
            is None
        )
        pytest.skip("kernels run uncompiled: the service takes vehicle_tracks_to_wire then")
    rng = np.random.default_rng(6)
    for k, n in enumerate((0, 1, 7, 128, 140, 3200)):
        tracks = random_tracks(n, covariance, n)
        sensors = ["lidar", "camera", "radar"][: 1 + k % 3]
        existence = rng.uniform(0, 1, n)
        stamps = rng.integers(-1, 2**62, (n, len(sensors)))
        packed = pack_vehicle_tracks_checked(tracks, existence, stamps, CLASSES, len(sensors))
        assert packed is not None
        wire = vehicle_tracks_to_wire(tracks, existence, stamps, CLASSES)
        for epoch in (None, 0, 2**63 - 1):
            args = dict(
                VEHICLE, sensor=sensors[0], sensors=sensors, sensor_state=["ok"] * len(sensors),
                pose=None if k % 2 else [float(v) for v in range(16)], epoch=epoch,
            )  # fmt: skip
            got = encode_vehicle_track_frame(**args, tracks=packed)
            assert got == encode_vehicle_track_frame(**args, tracks=wire), (n, epoch)
            decoded = decode_vehicle_track_frame(got)
            assert not isinstance(decoded, Rejection) and decoded[0].epoch == epoch
    tracks = random_tracks(5, covariance, 5)
    existence, stamps = rng.uniform(0, 1, 5), np.zeros((5, 2), np.int64)
    for bad in (np.nan, np.inf):
        poisoned_existence = existence.copy()
        poisoned_existence[3] = bad
        assert pack_vehicle_tracks_checked(tracks, poisoned_existence, stamps, CLASSES, 2) is None
    nan_score = dataclasses.replace(tracks.boxes, score=np.full(5, np.nan))
    nan_tracks = dataclasses.replace(tracks, boxes=nan_score)
    assert pack_vehicle_tracks_checked(nan_tracks, existence, stamps, CLASSES, 2) is None
    with pytest.raises(ValueError, match="sensor_stamp_ns"):
        pack_vehicle_tracks_checked(tracks, existence, stamps, CLASSES, 3)
    with pytest.raises(ValueError, match="existence"):
        pack_vehicle_tracks_checked(tracks, existence[:4], stamps, CLASSES, 2)


def test_packed_tracks_need_a_version() -> None:
    """The encoder cannot tell which columns packed bytes carry: it wants the version."""
    if not jit.compiled():
        pytest.skip("kernels run uncompiled")
    tracks = random_tracks(3, True, 3)
    checked = pack_tracks_checked(tracks, 0, CLASSES, 3)
    assert checked is not None
    for version in (None, 4):
        with pytest.raises(ValueError, match="packed tracks need a TrackFrame schema_version"):
            encode_track_frame(**HEADER, pose=None, tracks=checked[0], schema_version=version)
    assert pack_tracks_checked(tracks, 0, CLASSES, 4) is None


def test_the_packing_kernel_runs_the_same_as_python() -> None:
    """The kernel's own Python function (what it runs without numba) writes the same bytes."""
    from simpletrack.core.packing_kernels import pack_columns
    from simpletrack.wire import convert

    for n, cov in ((0, True), (5, False), (300, True)):
        t = random_tracks(n, cov, n)
        b = t.boxes
        args = (
            t.ids, 1000, b.params, b.score, b.cls, t.velocity, t.state, t.time_since_update,
            t.hits, t.age, convert._NO_COVARIANCE if t.covariance is None else t.covariance,
            cov, t.age_s, t.time_since_update_s, convert._classes_entry(CLASSES),
            convert._KEYS, convert._KEY_AT, convert._INCLUDE[3, cov],
        )  # fmt: skip
        plain, column, row = pack_columns.py(*args)
        assert (column, row) == (-1, -1)
        if jit.compiled():
            compiled = pack_columns(*args)
            assert compiled[0].tobytes() == plain.tobytes()
        want = tracks_to_wire(t, 1000, CLASSES)
        frame = encode_track_frame(**HEADER, pose=None, tracks=want, schema_version=3)
        assert plain.tobytes() in frame
