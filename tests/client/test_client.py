"""The client library against a real ``simpletrack serve`` on 127.0.0.1: round trip, fleet-wide
subscription by key expression, async iteration, errors coming back, and clean shutdown."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from simpletrack.client.publisher import Box, DetectionPublisher
from simpletrack.client.subscriber import TrackMessage, TrackSubscriber
from simpletrack.core.boxes import Boxes
from simpletrack.session import ZenohOptions
from simpletrack.wire import ErrorReason, FrameError
from tests.service_helpers import ROOT, ServiceProcess, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh
CLASSES = ("Car", "Pedestrian", "Cyclist")  # the service's default preset (kitti)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("svc"), instance="clients-test")
    yield svc
    svc.stop()


def options(svc: ServiceProcess) -> ZenohOptions:
    return ZenohOptions(connect=[svc.endpoint])


def cars(k: int, n: int = 2) -> Boxes:
    """n cars 8 m apart driving along +x at 10 m/s, frame k at 10 Hz."""
    params = [[10.0 + k, 8.0 * i, 0.8, 0.0, 4.0, 1.8, 1.6] for i in range(n)]
    return Boxes.from_arrays(params, [0.9] * n, [0] * n)


def collect(sub: TrackSubscriber, n: int, timeout: float = 10.0) -> list[TrackMessage]:
    out: list[TrackMessage] = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        msg = sub.recv(timeout=0.2)
        if msg is not None:
            out.append(msg)
    return out


def test_round_trip_keeps_ids_and_boxes(service: ServiceProcess) -> None:
    with (
        TrackSubscriber.connect(options=options(service), vehicle="rt", sensor="lidar") as sub,
        DetectionPublisher.connect("rt", "lidar", classes=CLASSES, options=options(service)) as pub,
    ):
        assert pub.wait_for_service(10)
        time.sleep(0.3)  # the subscription reaches the service
        for k in range(6):
            assert pub.publish(cars(k), stamp_ns=stamp(k)) == k
        got = collect(sub, 6)
    assert [m.seq for m in got] == list(range(6))
    assert all((m.vehicle, m.sensor) == ("rt", "lidar") for m in got)
    # The "kitti" preset outputs tentative tracks too: two tracks every frame, same ids.
    ids = [tuple(sorted(m.tracks.id.tolist())) for m in got]
    assert len(ids[0]) == 2 and set(ids) == {ids[0]}
    last = got[-1].boxes()
    np.testing.assert_allclose(np.sort(last.x), [15.0, 15.0], atol=0.2)
    assert got[-1].class_names() == ["Car", "Car"]


def test_fleet_wide_and_per_vehicle_subscriptions(service: ServiceProcess) -> None:
    streams = [("fa", "lidar"), ("fa", "radar"), ("fb", "lidar"), ("fb", "radar")]
    with (
        TrackSubscriber.connect(options=options(service), key_expr="fleet/f$*/*/tracks") as fleet,
        TrackSubscriber.connect(options=options(service), vehicle="fb") as one_vehicle,
        TrackSubscriber.connect(options=options(service), sensor="radar") as one_sensor_kind,
    ):
        pubs = [
            DetectionPublisher.connect(v, s, classes=CLASSES, options=options(service))
            for v, s in streams
        ]
        try:
            assert pubs[0].wait_for_service(10)
            time.sleep(0.3)
            for k in range(3):
                for pub in pubs:
                    pub.publish(cars(k, n=1), stamp_ns=stamp(k))
            all_msgs = collect(fleet, 12)
            fb = collect(one_vehicle, 6)
            radar = collect(one_sensor_kind, 6)
        finally:
            for pub in pubs:
                pub.close()
    assert sorted({(m.vehicle, m.sensor) for m in all_msgs}) == sorted(streams)
    assert len(all_msgs) == 12
    assert {m.vehicle for m in fb} == {"fb"} and len(fb) == 6
    assert {m.sensor for m in radar} == {"radar"} and len(radar) == 6
    # Per stream, frames arrive in order.
    for v, s in streams:
        assert [m.seq for m in all_msgs if (m.vehicle, m.sensor) == (v, s)] == [0, 1, 2]


def test_callback_delivery(service: ServiceProcess) -> None:
    got: list[TrackMessage] = []
    with (
        TrackSubscriber.connect(options=options(service), vehicle="cb", callback=got.append) as sub,
        DetectionPublisher.connect("cb", "lidar", classes=CLASSES, options=options(service)) as pub,
    ):
        assert pub.wait_for_service(10)
        time.sleep(0.3)
        for k in range(3):
            pub.publish(cars(k), stamp_ns=stamp(k))
        wait_for(lambda: len(got) == 3, 10, "three track frames by callback")
        assert sub.recv(timeout=0) is None  # callbacks take the frames; nothing is buffered
    assert [m.seq for m in got] == [0, 1, 2]


def test_async_iterator(service: ServiceProcess) -> None:
    async def main() -> list[int]:
        async with TrackSubscriber.connect(options=options(service), vehicle="as") as sub:
            with DetectionPublisher.connect(
                "as", "lidar", classes=CLASSES, options=options(service)
            ) as pub:
                assert pub.wait_for_service(10)
                await asyncio.sleep(0.3)
                for k in range(4):
                    pub.publish(cars(k), stamp_ns=stamp(k))
                seqs = []

                async def take() -> None:
                    async for msg in sub:
                        seqs.append(msg.seq)
                        if len(seqs) == 4:
                            return

                await asyncio.wait_for(take(), timeout=10)
                return seqs

    assert asyncio.run(main()) == [0, 1, 2, 3]


def test_errors_come_back_by_callback_and_iterator(service: ServiceProcess) -> None:
    seen: list[FrameError] = []
    with DetectionPublisher.connect(
        "er", "lidar", classes=CLASSES, options=options(service), on_error=seen.append
    ) as pub:
        assert pub.wait_for_service(10)
        time.sleep(0.3)
        pub.publish(cars(0), stamp_ns=stamp(0))
        # A class the service does not track: refused as unknown_class, naming the seq.
        bad = [Box(12, 0, 0.8, 0, 4, 1.8, 1.6, 0.9, "Tram")]
        seq = pub.publish(bad, stamp_ns=stamp(1))
        err = next(pub.errors(timeout=10), None)
        wait_for(lambda: len(seen) == 1, 5, "the error callback")
    assert err is not None, "no error came back"
    assert err.reason is ErrorReason.UNKNOWN_CLASS
    assert err.seq == seq == 1
    assert "Tram" in err.detail
    assert seen == [err]
    assert pub.errors_received == 1


def test_publisher_input_forms_agree(service: ServiceProcess) -> None:
    """Boxes, BoxArrays and a list of Box give the service the same frame."""
    from simpletrack.wire.convert import boxes_to_wire

    boxes = cars(0, n=1)
    as_list = [Box(10, 0, 0.8, 0, 4, 1.8, 1.6, 0.9, "Car")]
    with (
        TrackSubscriber.connect(options=options(service), vehicle="fm") as sub,
        DetectionPublisher.connect("fm", "a", classes=CLASSES, options=options(service)) as pa,
        DetectionPublisher.connect("fm", "b", classes=CLASSES, options=options(service)) as pb,
        DetectionPublisher.connect("fm", "c", classes=CLASSES, options=options(service)) as pc,
    ):
        assert pa.wait_for_service(10)
        time.sleep(0.3)
        pa.publish(boxes, stamp_ns=stamp(0))
        pb.publish(boxes_to_wire(boxes, CLASSES), stamp_ns=stamp(0))
        pc.publish(as_list, stamp_ns=stamp(0))
        got = {m.sensor: m for m in collect(sub, 3)}
    assert sorted(got) == ["a", "b", "c"]
    for m in got.values():
        np.testing.assert_allclose(m.boxes().params, boxes.params, atol=1e-5)


def test_close_wakes_blocked_consumers_at_once(service: ServiceProcess) -> None:
    sub = TrackSubscriber.connect(options=options(service), vehicle="nobody")
    ended = threading.Event()

    def consume() -> None:
        for _ in sub:  # blocks: nothing is published for this vehicle
            pass
        ended.set()

    consumer = threading.Thread(target=consume)
    consumer.start()
    time.sleep(0.2)
    t = time.monotonic()
    sub.close()
    consumer.join(timeout=1.0)
    assert ended.is_set() and not consumer.is_alive()
    assert time.monotonic() - t < 1.0
    assert sub.recv(timeout=0.1) is None  # closed and drained: returns, never blocks


def test_a_process_that_forgets_close_still_exits(service: ServiceProcess, tmp_path: Path) -> None:
    """Zenoh's callback threads are not daemons: without the exit hook this script hangs."""
    script = tmp_path / "forgetful.py"
    script.write_text(
        textwrap.dedent(
            f"""
            import threading
            from simpletrack.client.publisher import DetectionPublisher
            from simpletrack.client.subscriber import TrackSubscriber
            from simpletrack.session import ZenohOptions
            o = ZenohOptions(connect=["{service.endpoint}"])
            sub = TrackSubscriber.connect(options=o)
            cb = TrackSubscriber.connect(options=o, callback=lambda m: None)
            pub = DetectionPublisher.connect("fg", "lidar", classes=["Car"], options=o)
            threading.Thread(target=lambda: [None for _ in sub]).start()  # blocked consumer
            pub.publish([])
            print("bye", flush=True)
            """
        )
    )
    proc = subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=30
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "bye"


def test_bad_ids_are_refused_before_anything_is_sent(service: ServiceProcess) -> None:
    with pytest.raises(ValueError, match="vehicle id"):
        DetectionPublisher.connect("a/b", "lidar", classes=CLASSES, options=options(service))
    with pytest.raises(ValueError, match="sensor id"):
        TrackSubscriber.connect(options=options(service), sensor="li dar")
    with DetectionPublisher.connect(
        "sq", "lidar", classes=CLASSES, options=options(service)
    ) as pub:
        assert pub.publish(cars(0), seq=5) == 5  # skipping ahead is fine
        assert pub.publish(cars(1)) == 6
        with pytest.raises(ValueError, match="seq only grows"):
            pub.publish(cars(2), seq=6)


def test_watch_shows_each_stream(
    service: ServiceProcess, capsys: pytest.CaptureFixture[str]
) -> None:
    from simpletrack.cli.main import main

    def publish() -> None:
        with DetectionPublisher.connect(
            "wt", "lidar", classes=CLASSES, options=options(service)
        ) as pub:
            pub.wait_for_service(10)
            for k in range(25):
                pub.publish(cars(k), stamp_ns=stamp(k))
                time.sleep(0.1)

    sender = threading.Thread(target=publish)
    sender.start()
    code = main(
        ["watch", "--connect", service.endpoint, "--keys", "fleet/wt/*/tracks",
         "--duration", "3", "--interval", "1"]
    )  # fmt: skip
    sender.join()
    out = capsys.readouterr().out
    assert code == 0
    assert "wt/lidar seq" in out and "tracks 2 confirmed" in out
    last = out.strip().splitlines()[-1]
    assert last.startswith("watch: ") and "from 1 stream(s)" in last
