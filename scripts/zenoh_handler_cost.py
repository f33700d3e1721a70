"""What a Python callable costs as a Zenoh handler, against ``Callback(fn, indirect=False)``.

A plain callable gets a Python thread of its own per subscriber (and per miss listener),
woken for each sample; an ``indirect=False`` callback runs on Zenoh's own thread. A member
holds a tracks subscriber and a miss listener per stream, so this is per stream held.

- ``threads``: ``--thread-streams`` advanced subscribers, each with a miss listener, and as
  many plain subscribers, in a fresh process; its threads and resident memory before and
  after.
- ``cpu``: ``--subscribers`` plain subscribers hearing 10 KB messages at 10 Hz each from a
  child process (``zenoh_heartbeat_cost.py``'s fleet, without heartbeats); the receiver's
  CPU (user + system) per message over ``--seconds``.

Rows alternate between the handlers, ``--rounds`` times; ``cpu`` also for a ``RingChannel(1)``
(nothing runs per message; a standby's tracks subscriber as one was tried and taken back,
docs/BENCHMARKS.md).

    .venv/bin/python scripts/zenoh_handler_cost.py --subscribers 40 --rounds 3
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh
from zenoh import ext
from zenoh_heartbeat_cost import key  # this folder's: the fleet's keys

from simpletrack.session import ZenohOptions

RATE_HZ = 10.0


def handler(kind: str, fn: Callable[[Any], None]) -> Any:
    if kind == "ring":  # the newest sample kept in Zenoh, read when wanted: no Python
        return zenoh.handlers.RingChannel(1)
    return fn if kind == "plain" else zenoh.handlers.Callback(fn, indirect=False)


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        line = next(x for x in f if x.startswith("VmRSS"))
    return int(line.split()[1]) / 1024


def threads_row(kind: str, n: int, endpoint: str) -> str:
    session = zenoh.open(ZenohOptions(listen=[endpoint]).to_config())
    before, mb = len(os.listdir("/proc/self/task")), rss_mb()
    keep: list[Any] = []
    for i in range(n):
        sub = ext.declare_advanced_subscriber(
            session,
            f"cost/{i}/detections",
            zenoh.handlers.Callback(lambda s: None, indirect=False),
            history=ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None),
        )
        keep += [sub, sub.sample_miss_listener(handler(kind, lambda m: None))]
        keep.append(session.declare_subscriber(f"cost/{i}/tracks", handler(kind, lambda s: None)))
    time.sleep(1.0)
    after = len(os.listdir("/proc/self/task"))
    row = f"threads {kind:6} {n} streams: +{after - before} threads, +{rss_mb() - mb:.1f} MB"
    session.close()
    return row


def cpu_row(kind: str, n: int, endpoint: str, seconds: float) -> str:
    session = zenoh.open(ZenohOptions(listen=[endpoint]).to_config())
    heard, lock = [0], threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        sample.payload.to_bytes()
        with lock:
            heard[0] += 1

    subs = [
        session.declare_subscriber(key(i, "detections"), handler(kind, on_sample)) for i in range(n)
    ]
    # zenoh_heartbeat_cost.py's fleet without heartbeats: plain publishers of 10 KB.
    fleet = [sys.executable, str(Path(__file__).with_name("zenoh_heartbeat_cost.py")), "--fleet"]
    child = subprocess.Popen([*fleet, endpoint, str(n), str(RATE_HZ), str(seconds + 2.0), "0"])
    time.sleep(4.0)  # matched (the fleet waits 3 s), sending
    r0, h0 = resource.getrusage(resource.RUSAGE_SELF), heard[0]
    time.sleep(seconds)
    r1, h1 = resource.getrusage(resource.RUSAGE_SELF), heard[0]
    child.wait()
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    # A ring calls nothing: count the messages sent in the window instead.
    msgs = round(n * RATE_HZ * seconds) if kind == "ring" else max(1, h1 - h0)
    del subs
    session.close()
    return (
        f"cpu     {kind:6} {n} subscribers: {msgs} messages, {cpu / msgs * 1e6:.1f} us per message"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subscribers", type=int, default=40)
    ap.add_argument("--thread-streams", type=int, default=1000)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--endpoint", default="tcp/127.0.0.1:17461")
    ap.add_argument("--threads-of", choices=("plain", "direct"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.threads_of:
        print(threads_row(a.threads_of, a.thread_streams, a.endpoint), flush=True)
        return
    for kind in ("plain", "direct"):  # each in a fresh process: no threads of the other
        subprocess.run(
            [
                sys.executable,
                __file__,
                "--threads-of",
                kind,
                "--thread-streams",
                str(a.thread_streams),
                "--endpoint",
                a.endpoint,
            ],
            check=True,
        )
    for _ in range(a.rounds):
        for kind in ("plain", "direct", "ring"):
            print(cpu_row(kind, a.subscribers, a.endpoint, a.seconds), flush=True)


if __name__ == "__main__":
    main()
