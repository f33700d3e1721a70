"""The JSON twins' rows (simpletrack.mcap.rows) without a recording: float32 values as their
shortest decimals, every TrackFrame version, messages without a table as they are."""

from __future__ import annotations

import dataclasses
import json

import msgpack
import numpy as np

from simpletrack.mcap.foxglove import FoxgloveChannels, foxglove_schema
from simpletrack.mcap.rows import _short, twin
from simpletrack.wire import encode_track_frame
from tests.mcap.test_ros2 import tracks
from tests.mcap.twins import check_twin
from tests.service_helpers import stamp


def test_float32_values_are_their_shortest_decimals() -> None:
    rng = np.random.default_rng(7)
    for scale in (1e-4, 0.1, 1.0, 30.0, 1e3, 1e5):
        values = (rng.standard_normal(20_000) * scale).astype(np.float32)
        short = _short(values)
        assert (short.astype(np.float32) == values).all(), scale  # the very float32
        assert short.tolist() == [float(v) for v in values.astype(str)], scale  # numpy's print
    special = np.float32([0.0, -0.0, np.nan, np.inf, 0.8, 13.0])
    assert json.dumps(_short(special).tolist()) == "[0.0, -0.0, NaN, Infinity, 0.8, 13.0]"


def test_every_track_frame_version_gives_rows() -> None:
    full = tracks(2)
    for version, arrays in (
        (1, dataclasses.replace(full, covariance=None, age_s=None, time_since_update_s=None)),
        (2, full),
        (3, full),
    ):
        payload = encode_track_frame(
            vehicle="v", sensor="s", seq=2, stamp_ns=stamp(2), frame_id="map", pose=None,
            key_frame=True, instance="a", received_ns=1, published_ns=2, tracks=arrays,
            schema_version=version, epoch=5 << 16 if version == 3 else None,
        )  # fmt: skip
        (derived, *_) = FoxgloveChannels().derive("fleet/v/s/tracks", "tracks", "v", "s", payload)
        value = json.loads(derived.data)
        check_twin(value, payload, "TrackFrame")
        assert ("age_s" in value["tracks"][0]) == (version > 1)
        fields = json.loads(foxglove_schema("TrackFrame"))["properties"]["tracks"]["items"]
        assert set(value["tracks"][0]) <= set(fields["properties"])


def test_a_message_without_a_table_is_shown_as_it_is() -> None:
    error = {"schema_version": 1, "vehicle": "v", "reason": "malformed", "detail": "x"}
    assert twin("FrameError", error) is error
    assert twin("TrackFrame", msgpack.unpackb(msgpack.packb({"tracks": "no table"}))) is None
