"""The Zenoh floor of ``simpletrack bench service``: a process that stands where the service
does and sends every detection payload straight back on the sensor's tracks key.

    python -m simpletrack.bench.echo --listen tcp/127.0.0.1:7447 --prefix bench

Same transport, same session set-up (a peer listening on one endpoint, multicast off), same
BLOCK congestion control as the service's publishers, one publisher declared per key. No
decoding, queueing or tracking: the latency it gives is what Zenoh and the two Python
processes cost by themselves. Prints ``ready`` once subscribed; SIGTERM/SIGINT stop it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from types import FrameType

import zenoh

from simpletrack.session import open_session

MSGPACK = zenoh.Encoding("application/msgpack")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--listen", required=True, help="endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--prefix", default="fleet", help="first key chunk(s)")
    args = parser.parse_args(argv)
    stop = threading.Event()

    def request_stop(_sig: int, _frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    with open_session(mode="peer", listen=[args.listen]) as session:
        pubs: dict[str, zenoh.Publisher] = {}

        def echo(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            out = key.removesuffix("detections") + "tracks"
            pub = pubs.get(out)
            if pub is None:
                pub = pubs[out] = session.declare_publisher(
                    out, encoding=MSGPACK, congestion_control=zenoh.CongestionControl.BLOCK
                )
            pub.put(sample.payload)

        sub = session.declare_subscriber(f"{args.prefix}/*/*/detections", echo)
        print("ready", flush=True)
        while not stop.wait(0.2):
            pass
        sub.undeclare()  # type: ignore[no-untyped-call]
    return 0


if __name__ == "__main__":
    sys.exit(main())
