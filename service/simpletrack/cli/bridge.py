"""``simpletrack bridge ros2``: Autoware DetectedObjects in, TrackedObjects out, over Zenoh.
One vehicle sensor, or (``--fused``, several ``--input``) a fused vehicle's sensors in and the
vehicle's fused tracks out."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from dataclasses import dataclass
from types import FrameType

import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.client.publisher import check_name
from simpletrack.ros2.bridge import (
    DEFAULT_LOG_INTERVAL_S,
    FusedRos2Bridge,
    Ros2Bridge,
    service_status,
)
from simpletrack.ros2.convert import ScoreSource
from simpletrack.ros2.frames import DEFAULT_VEHICLE_FRAME, FrameTable, parse_extrinsic
from simpletrack.ros2.labels import PRESET_LABELS, LabelMap, label_map
from simpletrack.ros2.layout import (
    DEFAULT_OUT_TOPIC,
    DEFAULT_TOPIC,
    FusedKeys,
    Layout,
    TopicKeys,
    fused_keys,
    topic_keys,
)

DEFAULT_SENSOR = "objects"

EPILOG = f"""\
Subscribes to Autoware DetectedObjects (CDR) on a Zenoh key, publishes each message as a
detection frame on <prefix>/<vehicle>/<sensor>/detections, and publishes the service's tracks
of that sensor as TrackedObjects (CDR) on the output key. Keys (--layout):
  ros2dds    zenoh-bridge-ros2dds: topic /a/b is key a/b ([namespace/]a/b)
  rmw_zenoh  ROS 2 nodes on rmw_zenoh: <domain>/a/b/<DDS type name>/<type hash>, with the
             attachment rmw_zenoh expects
--in-key/--out-key replace the keys built from the topics. docs/ROS2.md has the ROS side.

Labels: by default the map of the running service's preset (asked through its status
queryable): {", ".join(PRESET_LABELS)}; --labels names a preset or gives LABEL=class pairs.
Objects whose label maps to no class, without classification, or not a bounding box are left
out of their frame (counted, logged). Ends on Ctrl-C or SIGTERM, printing its counts.

{ZENOH_NOTE}

A fused vehicle (the service's fusion.sensors; --fused, or --input given twice or more):
one --input SENSOR=TOPIC per sensor, each published as that sensor's frames; one
TrackedObjects output of the vehicle's fused tracks (<prefix>/<vehicle>/@vehicle/tracks),
object_id uuid5(NAMESPACE_URL, "simpletrack:<vehicle>/@vehicle/<id>"), existence_probability
the fused track's existence. Each message's header.frame_id decides what goes with it:
--vehicle-frame (base_link) the identity extrinsic, a frame given --extrinsic
FRAME=m00,...,m33 (row-major frame->vehicle) that extrinsic; with --world-frame FRAME only
that frame, with the identity pose. A message in any other frame is refused (unknown_frame).

examples:
  simpletrack bridge ros2 --vehicle veh01                      # zenoh-bridge-ros2dds on default topics
  simpletrack bridge ros2 --vehicle veh01 --layout rmw_zenoh --domain 0 --connect tcp/127.0.0.1:7447
  simpletrack bridge ros2 --vehicle bot1 --namespace /bot1 --labels CAR=car,PEDESTRIAN=pedestrian
  simpletrack bridge ros2 --vehicle veh01 --input lidar=/perception/lidar/objects \\
      --input camera=/perception/camera/objects --extrinsic camera_front=1,0,0,1.5,0,1,0,0,0,0,1,1.8,0,0,0,1
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "bridge",
        help="adapters between the service and other middlewares (ros2)",
        description="Bridges between the tracking service and other middlewares.",
    )
    sub = p.add_subparsers(dest="bridge", metavar="KIND", required=True)
    r = sub.add_parser(
        "ros2",
        help="Autoware DetectedObjects in, TrackedObjects out (zenoh-bridge-ros2dds, rmw_zenoh)",
        description="Bridge Autoware perception messages (CDR over Zenoh) to the service.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    r.add_argument("--vehicle", required=True, help="vehicle id in the service's keys")
    r.add_argument(
        "--sensor", default=None, help=f"sensor id in the keys (default {DEFAULT_SENSOR})"
    )
    r.add_argument(
        "--layout",
        choices=[x.value for x in Layout],
        default=Layout.ROS2DDS.value,
        help="how ROS 2 topics map to Zenoh keys (default ros2dds)",
    )
    r.add_argument("--topic", default=None, help=f"DetectedObjects topic ({DEFAULT_TOPIC})")
    r.add_argument(
        "--out-topic", default=DEFAULT_OUT_TOPIC, help=f"TrackedObjects topic ({DEFAULT_OUT_TOPIC})"
    )
    r.add_argument(
        "--namespace",
        default="",
        help="ROS namespace before both topics (zenoh-bridge-ros2dds 'namespace', e.g. /bot1)",
    )
    r.add_argument(
        "--domain",
        type=int,
        default=None,
        help="ROS_DOMAIN_ID of the rmw_zenoh keys (default $ROS_DOMAIN_ID or 0)",
    )
    r.add_argument("--in-key", help="Zenoh key of the DetectedObjects (replaces the layout's)")
    r.add_argument("--out-key", help="Zenoh key of the TrackedObjects (replaces the layout's)")
    r.add_argument(
        "--labels",
        help="label map: a preset name or LABEL=class pairs (default: the service's preset)",
    )
    r.add_argument(
        "--score",
        choices=[s.value for s in ScoreSource],
        default=ScoreSource.EXISTENCE.value,
        help="detection score: existence_probability (the best class probability where it is "
        "0; default) or the best classification probability",
    )
    r.add_argument(
        "--status-timeout",
        type=float,
        default=5.0,
        help="seconds to wait for the service's status when --labels is not given (5)",
    )
    r.add_argument(
        "--log-interval",
        type=float,
        default=DEFAULT_LOG_INTERVAL_S,
        help="seconds between two log lines of one kind of refusal (10)",
    )
    r.add_argument("--instance", default=None, help="bridge name in its error announcements")
    f = r.add_argument_group('a fused vehicle (docs/ROS2.md, "A fused vehicle")')
    f.add_argument(
        "--input",
        action="append",
        default=[],
        metavar="SENSOR=TOPIC",
        help="a DetectedObjects input of the vehicle and the sensor it is (repeatable; "
        "replaces --sensor/--topic); given twice or more: a fused vehicle",
    )
    f.add_argument(
        "--fused",
        action="store_true",
        help="the service fuses the vehicle's sensors: TrackedObjects of the vehicle's fused "
        "tracks (implied by two or more --input)",
    )
    f.add_argument(
        "--vehicle-frame",
        default=None,
        help=f"frame_id of objects already in the vehicle frame ({DEFAULT_VEHICLE_FRAME}): sent "
        "with the identity extrinsic; the TrackedObjects' frame",
    )
    f.add_argument(
        "--extrinsic",
        action="append",
        default=[],
        metavar="FRAME=M00,...,M33",
        help="objects in FRAME are sent with this frame->vehicle transform (16 numbers, "
        "row-major; repeatable)",
    )
    f.add_argument(
        "--world-frame",
        default=None,
        help="objects are in this world-fixed frame (e.g. map): sent with the identity pose, "
        "tracked in the world frame; no other frame is taken",
    )
    add_client_args(r)
    r.set_defaults(func=run)


def _domain(args: argparse.Namespace) -> int:
    if args.domain is not None:
        return int(args.domain)
    raw = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
    if not raw.isdigit():
        raise UserError(f"ROS_DOMAIN_ID {raw!r} is not a number")
    return int(raw)


def _single_keys(args: argparse.Namespace) -> tuple[str, TopicKeys]:
    if args.vehicle_frame is not None or args.extrinsic or args.world_frame is not None:
        raise UserError(
            "--vehicle-frame, --extrinsic and --world-frame are for a fused vehicle "
            "(--fused, or --input twice or more)"
        )
    sensor, topic = args.sensor or DEFAULT_SENSOR, args.topic or DEFAULT_TOPIC
    if args.input:  # one --input, not fused: the one-sensor bridge of that sensor and topic
        if args.sensor is not None or args.topic is not None or args.in_key is not None:
            raise UserError(
                "--input names the sensor and its topic: leave out --sensor/--topic/--in-key"
            )
        sensor, topic = _input(args.input[0])
    sensor = check_name("sensor", sensor)
    return sensor, topic_keys(
        Layout(args.layout),
        topic,
        args.out_topic,
        domain=_domain(args),
        namespace=args.namespace,
        in_key=args.in_key,
        out_key=args.out_key,
    )


def _input(spec: str) -> tuple[str, str]:
    sensor, sep, topic = spec.partition("=")
    if not sep or not sensor or not topic:
        raise ValueError(
            f"--input {spec!r} must be SENSOR=TOPIC, e.g. lidar=/perception/.../objects"
        )
    return check_name("sensor", sensor.strip()), topic.strip()


def _fused_keys(args: argparse.Namespace) -> tuple[FusedKeys, FrameTable]:
    if args.in_key is not None:
        raise UserError(
            "--in-key is for one sensor: a fused vehicle's inputs are --input SENSOR=TOPIC"
        )
    if args.input:
        if args.sensor is not None or args.topic is not None:
            raise UserError("--input names the sensor and its topic: leave out --sensor/--topic")
        inputs = [_input(spec) for spec in args.input]
    else:  # --fused with one sensor: the --sensor/--topic pair
        inputs = [
            (check_name("sensor", args.sensor or DEFAULT_SENSOR), args.topic or DEFAULT_TOPIC)
        ]
    keys = fused_keys(
        Layout(args.layout),
        inputs,
        args.out_topic,
        domain=_domain(args),
        namespace=args.namespace,
        out_key=args.out_key,
    )
    extrinsics: dict[str, tuple[float, ...]] = {}
    for spec in args.extrinsic:
        frame, matrix = parse_extrinsic(spec)
        if frame in extrinsics:
            raise ValueError(f"--extrinsic {frame} is given twice")
        extrinsics[frame] = matrix
    frames = FrameTable(
        vehicle_frame=args.vehicle_frame or DEFAULT_VEHICLE_FRAME,
        extrinsics=extrinsics,
        world_frame=args.world_frame,
    )
    return keys, frames


@dataclass(frozen=True)
class _Plan:
    """What the arguments say, checked before any session opens."""

    vehicle: str
    sensor: str | None = None  # one sensor
    single: TopicKeys | None = None
    fused: FusedKeys | None = None  # a fused vehicle
    frames: FrameTable | None = None


def _plan(args: argparse.Namespace) -> _Plan:
    try:
        vehicle = check_name("vehicle", args.vehicle)
        if args.fused or len(args.input) > 1:
            keys, frames = _fused_keys(args)
            return _Plan(vehicle, fused=keys, frames=frames)
        sensor, single = _single_keys(args)
        return _Plan(vehicle, sensor=sensor, single=single)
    except ValueError as e:
        raise UserError(str(e)) from None


def _start(
    session: zenoh.Session,
    plan: _Plan,
    args: argparse.Namespace,
    prefix: str,
    labels: LabelMap,
    classes: tuple[str, ...],
) -> Ros2Bridge | FusedRos2Bridge:
    logger = logging.getLogger("simpletrack.ros2.bridge")
    score = ScoreSource(args.score)
    if plan.fused is not None:
        keys, frames = plan.fused, plan.frames
        fused = FusedRos2Bridge(
            session,
            keys,
            vehicle=plan.vehicle,
            labels=labels,
            classes=classes,
            frames=frames,
            prefix=prefix,
            score=score,
            instance=args.instance or f"ros2-bridge-{plan.vehicle}-fused",
            log_interval_s=args.log_interval,
        )
        logger.info(
            "bridging %s (%s) -> %s/%s/<sensor>/detections, fused tracks "
            "%s/%s/@vehicle/tracks -> %s in %s; frames taken: %s; labels %s: %s",
            ", ".join(f"{i.sensor} <- {i.key}" for i in keys.inputs),
            keys.layout.value,
            prefix,
            plan.vehicle,
            prefix,
            plan.vehicle,
            keys.out_key,
            fused.frames.output_frame,
            fused.frames.describe(),
            labels.name,
            labels.describe(),
        )
        return fused
    assert plan.single is not None and plan.sensor is not None
    keys1, sensor = plan.single, plan.sensor
    bridge = Ros2Bridge(
        session,
        keys1,
        vehicle=plan.vehicle,
        sensor=sensor,
        labels=labels,
        classes=classes,
        prefix=prefix,
        score=score,
        instance=args.instance or f"ros2-bridge-{plan.vehicle}-{sensor}",
        log_interval_s=args.log_interval,
    )
    logger.info(
        "bridging %s (%s) -> %s/%s/%s, tracks -> %s; labels %s: %s",
        keys1.in_key,
        keys1.layout.value,
        prefix,
        plan.vehicle,
        sensor,
        keys1.out_key,
        labels.name,
        labels.describe(),
    )
    return bridge


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(levelname)s %(message)s"
    )
    prefix = check_prefix(args.prefix)
    plan = _plan(args)
    try:
        labels = label_map(args.labels) if args.labels else None
    except ValueError as e:
        raise UserError(str(e)) from None
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with open_client_session(client_options(args)) as session:
        labels, classes = _labels_and_classes(session, prefix, labels, args.status_timeout)
        bridge = _start(session, plan, args, prefix, labels, classes)
        try:
            bridge.run(stop)
        finally:
            bridge.close()
    print(f"simpletrack bridge ros2: {bridge.stats.summary()}", flush=True)
    return 0


def _labels_and_classes(
    session: zenoh.Session, prefix: str, labels: LabelMap | None, timeout: float
) -> tuple[LabelMap, tuple[str, ...]]:
    """The label map and the class table frames are sent with. Without --labels the running
    service's preset decides; its class table is used when it answers."""
    status = service_status(session, prefix, timeout) if timeout > 0 else None
    if labels is None:
        if status is None:
            raise UserError(
                f"no service answered under {prefix!r} within {timeout} s: start it first or "
                "give --labels (a preset name or LABEL=class pairs)"
            )
        if status.preset not in PRESET_LABELS:
            raise UserError(
                f"the service runs preset {status.preset!r}, which has no default label map: "
                "give --labels"
            )
        labels = label_map(status.preset)
    classes = tuple(status.classes) if status is not None else labels.classes
    missing = [c for c in labels.classes if c not in classes]
    if missing:
        raise UserError(
            f"--labels maps to {', '.join(missing)}, which the service does not track "
            f"(its classes: {', '.join(classes)})"
        )
    return labels, classes
