"""ServiceStatus versions 1 and 2 (fused vehicles), the new error reasons, and a snapshot of a
fused vehicle's tracker (sensor ``@vehicle``): what each reader takes and refuses."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from simpletrack.wire import (
    ErrorReason,
    FrameError,
    Rejection,
    SensorCondition,
    SensorSnapshot,
    ServiceStatus,
    decode_message,
    encode,
    generate,
    models,
)
from simpletrack.wire.codec import pack
from simpletrack.wire.messages import to_map
from tests.wire.test_validator_agrees import BASES, _assert_agree


def _status(version: int) -> dict[str, Any]:
    return copy.deepcopy(BASES["ServiceStatus" if version == 2 else "ServiceStatusV1"])


def test_both_versions_decode_and_version_1_has_no_vehicles() -> None:
    old = decode_message(pack(_status(1)), ServiceStatus)
    assert isinstance(old, ServiceStatus) and old.schema_version == 1 and old.vehicles == []
    assert "vehicles" not in to_map(old)
    new = decode_message(pack(_status(2)), ServiceStatus)
    assert isinstance(new, ServiceStatus) and new.schema_version == 2
    (vehicle,) = new.vehicles
    assert vehicle.vehicle == "truck-07" and vehicle.late_frames == 2
    assert [s.state for s in vehicle.sensors] == [SensorCondition.CLOCK, SensorCondition.OK]
    assert vehicle.sensors[0].offset_m == [0.5, -0.25] and vehicle.sensors[1].offset_m is None
    assert decode_message(encode(new), ServiceStatus) == new


def test_version_2_without_vehicles_reads_an_empty_list() -> None:
    obj = _status(2)
    del obj["vehicles"]
    status = decode_message(pack(obj), ServiceStatus)
    assert isinstance(status, ServiceStatus) and status.vehicles == []


def test_version_1_holding_vehicles_is_an_extra_field() -> None:
    obj = _status(2)
    obj["schema_version"] = 1
    out = decode_message(pack(obj), ServiceStatus)
    assert isinstance(out, Rejection) and (out.reason, out.field) == (
        ErrorReason.EXTRA_FIELD,
        "vehicles",
    )
    _assert_agree("ServiceStatusV1", obj)


@pytest.mark.parametrize("version", [0, 3])
def test_other_versions_are_refused(version: int) -> None:
    obj = _status(2)
    obj["schema_version"] = version
    out = decode_message(pack(obj), ServiceStatus)
    assert isinstance(out, Rejection) and out.reason is ErrorReason.WRONG_VERSION


def test_the_pydantic_twin_of_each_version() -> None:
    new = decode_message(pack(_status(2)), models.ServiceStatus)
    assert isinstance(new, models.ServiceStatus) and new.vehicles[0].seq == 1042
    assert decode_message(encode(new), models.ServiceStatus) == new
    old = decode_message(pack(_status(1)), models.ServiceStatus)
    assert isinstance(old, models.ServiceStatusV1) and not hasattr(old, "vehicles")


@pytest.mark.parametrize(
    ("path", "value", "reason", "field"),
    [
        (("state",), "asleep", "invalid_value", "vehicles.0.sensors.0.state"),
        (("offset_m",), [1.0], "invalid_value", "vehicles.0.sensors.0.offset_m"),
        (("detail",), "x" * 257, "invalid_value", "vehicles.0.sensors.0.detail"),
        (("frames",), -1, "invalid_value", "vehicles.0.sensors.0.frames"),
        (("idle_s",), "1", "wrong_type", "vehicles.0.sensors.0.idle_s"),
    ],
)
def test_a_bad_fused_sensor_names_its_place(
    path: tuple[str, ...], value: Any, reason: str, field: str
) -> None:
    obj = _status(2)
    obj["vehicles"][0]["sensors"][0][path[0]] = value
    out = decode_message(pack(obj), ServiceStatus)
    assert isinstance(out, Rejection) and (out.reason.value, out.field) == (reason, field)
    _assert_agree("ServiceStatus", obj)


@pytest.mark.parametrize("reason", [ErrorReason.LATE, ErrorReason.SENSOR_FLAGGED])
def test_the_fusion_reasons_travel(reason: ErrorReason) -> None:
    payload = generate._error(reason, None, "why")
    err = decode_message(payload, FrameError)
    assert isinstance(err, FrameError) and err.reason is reason


@pytest.mark.parametrize(
    ("sensor", "ok"),
    [("@vehicle", True), ("lidar_top", True), ("@vehicles", False), ("@x", False), ("a/b", False)],
)
def test_a_snapshot_may_be_of_a_fused_vehicle(sensor: str, ok: bool) -> None:
    obj = {**copy.deepcopy(BASES["SensorSnapshot"]), "sensor": sensor}
    out = decode_message(pack(obj), SensorSnapshot)
    assert isinstance(out, SensorSnapshot) is ok, out
    if not ok:
        assert isinstance(out, Rejection) and (out.reason, out.field) == (
            ErrorReason.INVALID_VALUE,
            "sensor",
        )
    _assert_agree("SensorSnapshot", obj)
