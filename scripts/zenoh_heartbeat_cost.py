"""What the vehicles' heartbeats cost a member that holds many sensors, in Zenoh alone.

A receiving session like a member's: per sensor an advanced subscriber (history, late
publishers, heartbeat recovery: the service's own options), a tracks subscriber and a tracks
publisher. A child process like a fleet: per sensor an advanced publisher (cache, heartbeat
every ``--heartbeat`` s, as ``DetectionPublisher``) putting 10 KB at ``--rate`` Hz. The
receiver's CPU (user + system, all its threads) over the window is printed per sensor count,
with heartbeats, with heartbeats and each publisher's heartbeat key declared on the receiving
session (as server/subscriptions.py does), and without heartbeats (plain publishers), the rows
alternated.

    .venv/bin/python scripts/zenoh_heartbeat_cost.py --sensors 150,300,600 --rate 0.1
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from typing import Any

import zenoh
from zenoh import ext

from simpletrack.session import ZenohOptions

PAYLOAD = b"x" * 10_000


def key(i: int, what: str) -> str:
    return f"cost/v{i // 6}/s{i % 6}/{what}"


def fleet(endpoint: str, sensors: int, rate: float, seconds: float, heartbeat: float) -> None:
    session = zenoh.open(ZenohOptions(connect=[endpoint]).to_config())
    pubs: list[Any] = []
    for i in range(sensors):
        if heartbeat > 0:
            pubs.append(
                ext.declare_advanced_publisher(
                    session,
                    key(i, "detections"),
                    cache=ext.CacheConfig(max_samples=100),
                    sample_miss_detection=ext.MissDetectionConfig(heartbeat=heartbeat),
                    publisher_detection=True,
                )
            )
        else:
            pubs.append(session.declare_publisher(key(i, "detections")))
    time.sleep(3)  # the member's subscribers match
    start, k = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        wait = start + k / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        for p in pubs:
            p.put(PAYLOAD)
        k += 1
    session.close()


def member(
    endpoint: str, sensors: int, rate: float, seconds: float, heartbeat: float, declare: bool
) -> str:
    session = zenoh.open(ZenohOptions(listen=[endpoint]).to_config())
    heard = [0]
    sources: dict[str, tuple[str, int]] = {}

    def count(sample: zenoh.Sample) -> None:
        heard[0] += 1
        info = sample.source_info
        if info is not None and info.source_id is not None:
            sources[str(sample.key_expr)] = (str(info.source_id.zid), int(info.source_id.eid))

    held: list[Any] = []
    for i in range(sensors):
        held.append(
            ext.declare_advanced_subscriber(
                session,
                key(i, "detections"),
                count,
                history=ext.HistoryConfig(detect_late_publishers=True, max_samples=10),
                recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None),
            )
        )
        held.append(
            session.declare_subscriber(
                key(i, "tracks"), count, allowed_origin=zenoh.Locality.REMOTE
            )
        )
        held.append(session.declare_publisher(key(i, "tracks")))
    args = [endpoint, sensors, rate, seconds + 5, heartbeat]
    child = subprocess.Popen([sys.executable, __file__, "--fleet", *map(str, args)])
    time.sleep(4)  # the fleet's declarations, a first round of frames
    if declare:  # a heartbeat's key is its publisher's token's: the key, zid and eid
        for k, (zid, eid) in list(sources.items()):
            held.append(session.declare_keyexpr(f"{k}/@adv/pub/{zid}/{eid}/_"))
    time.sleep(1)
    r0, h0 = resource.getrusage(resource.RUSAGE_SELF), heard[0]
    time.sleep(seconds)
    r1, h1 = resource.getrusage(resource.RUSAGE_SELF), heard[0]
    child.wait()
    session.close()
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    hb = f"every {heartbeat:g} s" if heartbeat > 0 else "none"
    hb += f", {len(sources)} keys declared" if declare else ""
    per_frame = cpu / max(h1 - h0, 1) * 1e6
    return (
        f"| {sensors} | {rate:g} Hz | {hb} | {h1 - h0} | {cpu / seconds:.3f} | {per_frame:.0f} µs |"
    )


def main() -> None:
    if sys.argv[1:2] == ["--fleet"]:
        endpoint, n, rate, seconds, heartbeat = sys.argv[2:7]
        fleet(endpoint, int(n), float(rate), float(seconds), float(heartbeat))
        return
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sensors", default="150,300,600", help="sensor counts, comma-separated")
    p.add_argument("--rate", type=float, default=0.1, help="frames per second per sensor")
    p.add_argument("--heartbeat", type=float, default=0.5, help="the publishers' period, s")
    p.add_argument("--seconds", type=float, default=10.0, help="the measured window")
    p.add_argument("--port", type=int, default=27461)
    a = p.parse_args()
    endpoint = f"tcp/127.0.0.1:{a.port}"
    print("| sensors | rate | heartbeat | frames heard | member's cores | CPU per frame |")
    print("|---|---|---|---|---|---|")
    for n in [int(s) for s in a.sensors.split(",")]:
        for hb, declare in ((a.heartbeat, False), (a.heartbeat, True), (0.0, False)):
            print(member(endpoint, n, a.rate, a.seconds, hb, declare), flush=True)


if __name__ == "__main__":
    main()
