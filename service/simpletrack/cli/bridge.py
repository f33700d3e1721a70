"""``simpletrack bridge ros2``: Autoware DetectedObjects in, TrackedObjects out, over Zenoh."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
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
from simpletrack.ros2.bridge import DEFAULT_LOG_INTERVAL_S, Ros2Bridge, service_status
from simpletrack.ros2.convert import ScoreSource
from simpletrack.ros2.labels import PRESET_LABELS, LabelMap, label_map
from simpletrack.ros2.layout import DEFAULT_OUT_TOPIC, DEFAULT_TOPIC, Layout, topic_keys

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

examples:
  simpletrack bridge ros2 --vehicle veh01                      # zenoh-bridge-ros2dds on default topics
  simpletrack bridge ros2 --vehicle veh01 --layout rmw_zenoh --domain 0 --connect tcp/127.0.0.1:7447
  simpletrack bridge ros2 --vehicle bot1 --namespace /bot1 --labels CAR=car,PEDESTRIAN=pedestrian
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
    r.add_argument("--sensor", default="objects", help="sensor id in the keys (default objects)")
    r.add_argument(
        "--layout",
        choices=[x.value for x in Layout],
        default=Layout.ROS2DDS.value,
        help="how ROS 2 topics map to Zenoh keys (default ros2dds)",
    )
    r.add_argument(
        "--topic", default=DEFAULT_TOPIC, help=f"DetectedObjects topic ({DEFAULT_TOPIC})"
    )
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
    add_client_args(r)
    r.set_defaults(func=run)


def _domain(args: argparse.Namespace) -> int:
    if args.domain is not None:
        return int(args.domain)
    raw = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
    if not raw.isdigit():
        raise UserError(f"ROS_DOMAIN_ID {raw!r} is not a number")
    return int(raw)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(levelname)s %(message)s"
    )
    prefix = check_prefix(args.prefix)
    try:
        vehicle = check_name("vehicle", args.vehicle)
        sensor = check_name("sensor", args.sensor)
        keys = topic_keys(
            Layout(args.layout),
            args.topic,
            args.out_topic,
            domain=_domain(args),
            namespace=args.namespace,
            in_key=args.in_key,
            out_key=args.out_key,
        )
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
        bridge = Ros2Bridge(
            session,
            keys,
            vehicle=vehicle,
            sensor=sensor,
            labels=labels,
            classes=classes,
            prefix=prefix,
            score=ScoreSource(args.score),
            instance=args.instance or f"ros2-bridge-{vehicle}-{sensor}",
            log_interval_s=args.log_interval,
        )
        logging.getLogger("simpletrack.ros2.bridge").info(
            "bridging %s (%s) -> %s/%s/%s, tracks -> %s; labels %s: %s",
            keys.in_key,
            keys.layout.value,
            prefix,
            vehicle,
            sensor,
            keys.out_key,
            labels.name,
            labels.describe(),
        )
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
