"""``simpletrack bench scale``: capacity against the number of group members, and what losing
a member costs the sensors it was serving.

For each member count M: M ``simpletrack serve`` processes on one prefix, peer mode on
127.0.0.1, each listening on its own port and connected to the others; the load generator
(bench/loadgen.py) connects to all of them. Capacity is the service benchmark's search
(bench/service.py ``sweep``), one fresh group per step. Then, for M >= 2, two fault runs,
each with a fresh group and ``fault_sensors`` sensors streaming:
- *failover*: SIGKILL one member half-way through the measured window;
- *hand-off*: SIGTERM one member at the same point.
For each sensor whose last track frame before the fault came from that member
(``TrackFrame.instance``), the time from the fault to its first track frame from another
member; and, over the frames put from 1 s before the fault to the end, how many got no track
frame and how many got more than one; the survivors' own sensors' p99 just before and just
after the fault; each member's resident memory; the load generator's longest put lag.

The members form one group (docs/SCALE.md): each sensor is tracked by one member, so before a
fault every frame gets one answer and capacity grows with M as far as the machine's cores do;
a failover publishes the dead member's last frame of each moved sensor once more, counted
apart from other repeats.
"""

from __future__ import annotations

import contextlib
import os
import signal
import statistics
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.bench.generators import Generators, generator_summary, merge_results
from simpletrack.bench.loadgen import FUSED_SENSORS
from simpletrack.bench.report import generator_line
from simpletrack.bench.service import (
    Server,
    ServiceBenchOptions,
    launch_tracker,
    load_spec,
    measure_step,
    sweep,
    wait_tracker,
)
from simpletrack.bench.stats import status_mb
from simpletrack.session import BLOCK_WAIT_BEFORE_CLOSE_US
from simpletrack.spawn import free_port

FAULTS = {"failover": signal.SIGKILL, "handoff": signal.SIGTERM}
BEFORE_FAULT_S = 1.0  # frames put this long before the fault may still be in the victim's queue
FAULT_DRAIN_S = 3.0
# The survivors' own sensors are timed over frames put this long after the fault (when the
# moved sensors' subscriptions, cache fetches and restores land on them) and as long before.
STALL_S = 3.0
MAX_LISTED = 20  # unanswered frames named in a fault run's report


@dataclass(frozen=True, slots=True)
class ScaleOptions:
    instances: tuple[int, ...]
    bench: ServiceBenchOptions  # sensors to step through, seconds per step, the load
    fault_sensors: int


def member_name(i: int) -> str:
    return f"m{i}"


@contextlib.contextmanager
def group(members: int, opts: ServiceBenchOptions, tmp: Path) -> Iterator[list[Server]]:
    """``members`` services started together, each connected to the others' endpoints."""
    ports = [free_port() for _ in range(members)]
    endpoints = [f"tcp/127.0.0.1:{p}" for p in ports]
    servers: list[Server] = []
    try:
        for i, port in enumerate(ports):
            siblings = [w for e in endpoints if e != endpoints[i] for w in ("--connect", e)]
            servers.append(
                launch_tracker(opts, tmp, port=port, instance=member_name(i), extra=siblings)
            )
        for server in servers:
            wait_tracker(server)
        yield servers
    finally:
        for server in servers:  # all at once: their drains overlap
            if server.proc.poll() is None:
                server.proc.send_signal(signal.SIGTERM)
        for server in servers:
            server.stop()


# ----------------------------------------------------------------------------- faults
def _republished(answers: list[tuple[int, str]], victim: str) -> bool:
    """One of the victim's last frames answered again by the member that took its sensor
    over (a failover publishes the last frame heard, or told, again: the victim may have been
    killed before its put reached every link; and the one after, put before its word went:
    server/told.py)."""
    if len(answers) != 2:
        return False
    (_, first), (_, second) = sorted(answers)
    return first == victim and second != victim


def fault_figures(
    answers: Sequence[Sequence[Any]],
    sent_ns: Sequence[Sequence[int]],
    fault_ns: int,
    victim: str,
    warm_ticks: int = 0,
    refusals: Sequence[Sequence[Any]] = (),
) -> dict[str, Any]:
    """What a fault of member ``victim`` at ``fault_ns`` cost, from every track frame received
    (``(sensor, seq, instance, receipt ns)``) and every put's time (``sent_ns[sensor][seq]``,
    0: not sent), all on one monotonic clock; ``refusals``: each refusal naming a frame
    (``(sensor, seq, reason)``), told with the unanswered frames it names."""
    refused = {(int(sensor), int(seq)): str(reason) for sensor, seq, reason in refusals}
    by_sensor: dict[int, list[tuple[int, str]]] = {}
    per_frame: Counter[tuple[int, int]] = Counter()
    by_frame: dict[tuple[int, int], list[tuple[int, str]]] = {}
    for sensor, seq, instance, recv in answers:
        by_sensor.setdefault(int(sensor), []).append((int(recv), str(instance)))
        per_frame[int(sensor), int(seq)] += 1
        by_frame.setdefault((int(sensor), int(seq)), []).append((int(recv), str(instance)))
    gaps_ms: list[float] = []
    not_recovered = 0
    served = 0
    first_ms: list[float] = []  # each moved sensor's first frame put after the fault
    slowest: dict[str, Any] | None = None  # the latest of them, to look it up in the logs
    bystanders: set[int] = set()  # last served by a survivor before the fault
    last_server: dict[int, str] = {}  # who answered each sensor last before the fault
    for sensor, events in by_sensor.items():
        events.sort()
        before = [inst for t, inst in events if t < fault_ns]
        if not before:
            continue
        last_server[sensor] = before[-1]
        if before[-1] != victim:
            bystanders.add(sensor)
            continue
        served += 1
        after = next((t for t, inst in events if t >= fault_ns and inst != victim), None)
        if after is None:
            not_recovered += 1
        else:
            gaps_ms.append((after - fault_ns) / 1e6)
        row = sent_ns[sensor] if sensor < len(sent_ns) else []
        k = next((k for k, t in enumerate(row) if k >= warm_ticks and t >= fault_ns), None)
        heard = by_frame.get((sensor, k), []) if k is not None else []
        if k is not None and heard:
            recv, by = min(heard)
            first_ms.append((recv - row[k]) / 1e6)
            if slowest is None or first_ms[-1] > slowest["answered_after_put_ms"]:
                slowest = {
                    "sensor": sensor,
                    "seq": k,
                    "put_after_fault_ms": round((row[k] - fault_ns) / 1e6, 1),
                    "answered_after_put_ms": first_ms[-1],
                    "by": by,
                }
    start = fault_ns - int(BEFORE_FAULT_S * 1e9)
    window = [
        (i, k)
        for i, row in enumerate(sent_ns)
        for k, t in enumerate(row)
        if k >= warm_ticks and t > 0 and t >= start
    ]
    silent = [f for f in window if per_frame[f] == 0]
    earlier = [
        per_frame[i, k]
        for i, row in enumerate(sent_ns)
        for k, t in enumerate(row)
        if k >= warm_ticks and 0 < t < start
    ]
    return {
        "victim": victim,
        "sensors_served_by_victim": served,
        **_bystanders(by_frame, sent_ns, fault_ns, bystanders, warm_ticks),
        "max_ms": round(max(gaps_ms), 1) if gaps_ms else None,
        "median_ms": round(statistics.median(gaps_ms), 1) if gaps_ms else None,
        "not_recovered": not_recovered,
        # Independent of the frame period (the time to another member's tracks includes the
        # wait for each sensor's next frame): how late the first frame after the fault was.
        "first_after_max_ms": round(max(first_ms), 1) if first_ms else None,
        "first_after_median_ms": round(statistics.median(first_ms), 1) if first_ms else None,
        # Which: the load generator's sensor index and seq (its key: loadgen's naming).
        "first_after_slowest": None
        if slowest is None
        else {**slowest, "answered_after_put_ms": round(slowest["answered_after_put_ms"], 1)},
        "window_frames": len(window),
        "zero_answers": len(silent),
        # Of them, refused with a notice (a shed frame): announced, not lost silently.
        "zero_answers_refused": sum(1 for f in silent if f in refused),
        # Each frame with no answer, to look up in the members' logs: which member served its
        # sensor before the fault and which answered the sensor's next frame.
        "unanswered": [
            {
                **_unanswered(f, sent_ns, fault_ns, last_server.get(f[0]), by_frame, victim),
                "refused": refused.get(f),
            }
            for f in silent[:MAX_LISTED]
        ],
        "republished": sum(1 for f in window if _republished(by_frame.get(f, []), victim)),
        "multiple_answers": sum(
            1 for f in window if per_frame[f] > 1 and not _republished(by_frame[f], victim)
        ),
        "answers_per_frame_before": round(sum(earlier) / len(earlier), 2) if earlier else None,
    }


def _unanswered(
    frame: tuple[int, int],
    sent_ns: Sequence[Sequence[int]],
    fault_ns: int,
    served_before: str | None,
    by_frame: dict[tuple[int, int], list[tuple[int, str]]],
    victim: str,
) -> dict[str, Any]:
    sensor, seq = frame
    put = sent_ns[sensor][seq]
    later = next(
        (
            (k, min(by_frame[sensor, k])[1])
            for k in range(seq + 1, len(sent_ns[sensor]))
            if (sensor, k) in by_frame
        ),
        None,
    )
    return {
        "sensor": sensor,
        "seq": seq,
        "put_after_fault_ms": round((put - fault_ns) / 1e6, 1),
        "served_before": served_before,
        "moved": served_before == victim,
        "next_answered": None if later is None else {"seq": later[0], "by": later[1]},
    }


def _bystanders(
    by_frame: dict[tuple[int, int], list[tuple[int, str]]],
    sent_ns: Sequence[Sequence[int]],
    fault_ns: int,
    kept: set[int],
    warm_ticks: int,
) -> dict[str, Any]:
    """Latency of the sensors a survivor served before the fault (``kept``: not moved by
    it), over the frames put in the STALL_S before it and the STALL_S after it: whether
    taking the victim's sensors over held the survivors' own sensors back."""
    span = int(STALL_S * 1e9)
    before: list[float] = []
    after: list[float] = []
    missing = 0
    for sensor in sorted(kept):
        for k, t in enumerate(sent_ns[sensor]):
            if k < warm_ticks or t <= 0 or not fault_ns - span <= t < fault_ns + span:
                continue
            events = by_frame.get((sensor, k), [])
            if not events:
                missing += t >= fault_ns
                continue
            (before if t < fault_ns else after).append((min(events)[0] - t) / 1e6)

    def p99(xs: list[float]) -> float | None:
        return round(float(np.percentile(xs, 99)), 1) if xs else None

    return {
        "bystander_sensors": len(kept),
        "bystander_p99_ms_before": p99(before),
        "bystander_p99_ms_after": p99(after),
        "bystander_max_ms_after": round(max(after), 1) if after else None,
        "bystander_unanswered_after": missing,
    }


def rss_mb(pid: int) -> float | None:
    """The process's resident memory now (None once it is gone)."""
    mb = status_mb(pid, "VmRSS")
    return None if mb is None else round(mb, 1)


def fault_run(
    members: int, fault: str, opts: ScaleOptions, tmp: Path, progress: Callable[[str], None]
) -> dict[str, Any]:
    """A fresh group streaming ``fault_sensors`` sensors; the last member is hit half-way."""
    bench = opts.bench
    unit = "vehicles" if bench.fused else "sensors"
    progress(f"{fault:8s} {members} members, {opts.fault_sensors} {unit}, {bench.seconds:g} s ...")
    with group(members, bench, tmp) as servers:
        base = load_spec(opts.fault_sensors, bench, servers)
        spec = replace(base, drain_s=FAULT_DRAIN_S, record_answers=True)
        victim = servers[-1]
        with Generators(spec, bench.generator_processes, bench.generator_cpus) as gens:
            gens.expect_all("ready", 120.0)
            gens.go()
            started = min(int(t) for t in gens.expect_all("start", bench.warmup_s + 30.0))
            at = started + int(bench.seconds * 0.5e9)
            time.sleep(max(0.0, (at - time.monotonic_ns()) / 1e9))
            # The generators' clock: CLOCK_MONOTONIC, one per machine, so every process's
            # receipt times compare with it.
            rss_before = [rss_mb(s.proc.pid) for s in servers]
            fault_ns = time.monotonic_ns()
            os.kill(victim.proc.pid, FAULTS[fault])
            # A vehicle's put to a member that died under it may block for the whole of its
            # session's wait_before_close: the run waits that out and reports it (put lag).
            gens.expect_all("end", bench.seconds + BLOCK_WAIT_BEFORE_CLOSE_US / 1e6 + 60.0)
            rss_after = [rss_mb(s.proc.pid) for s in servers[:-1]]
            result = merge_results(gens.expect_all("result", FAULT_DRAIN_S + 60.0))
    out = {
        "fault": fault,
        "signal": FAULTS[fault].name,
        "members": members,
        # Sensor streams (a fused vehicle's two each): the figures are per sensor.
        "sensors": opts.fault_sensors * (len(FUSED_SENSORS) if bench.fused else 1),
        "vehicles": opts.fault_sensors if bench.fused else None,
        **fault_figures(
            result["answers"],
            result["sent_ns"],
            fault_ns,
            victim.instance,
            spec.warm_ticks,
            result.get("refusals", ()),
        ),
        "refused_by_reason": result["refused_by_reason"],
        # Resident memory of each member just before the fault, and of the survivors (which
        # now hold the victim's sensors too) at the end of the window.
        "rss_mb_before": rss_before,
        "rss_mb_after": rss_after,
        "generator": generator_summary(
            result["generators"], result["put_lateness_s"], bench.generator_cpus
        ),
    }
    progress("        " + fault_line(out))
    return out


def fault_line(f: dict[str, Any]) -> str:
    return (
        f"{f['sensors_served_by_victim']} sensors last served by {f['victim']}: "
        f"max {f['max_ms']} ms, median {f['median_ms']} ms to another member's tracks "
        f"(their first frame after it answered {f.get('first_after_max_ms')} ms after its put "
        f"at most, median {f.get('first_after_median_ms')} ms), "
        f"{f['not_recovered']} never; of {f['window_frames']} frames around the fault "
        f"{f['zero_answers']} unanswered ({f.get('zero_answers_refused', 0)} of them refused "
        f"with a notice), {f.get('republished', 0)} of the victim's last "
        f"published again, {f['multiple_answers']} otherwise answered more than once; "
        f"the other {f['bystander_sensors']} sensors' p99 {f['bystander_p99_ms_before']} ms "
        f"before, {f['bystander_p99_ms_after']} ms after (max {f['bystander_max_ms_after']}, "
        f"{f['bystander_unanswered_after']} unanswered); members' memory "
        f"{_mb(f['rss_mb_before'])} MB before, survivors {_mb(f['rss_mb_after'])} MB after; "
        f"the load generator's longest put lag {f['generator']['lag_max_ms']} ms; "
        f"refused over the whole run: {_reasons(f.get('refused_by_reason') or {})}"
    )


def _reasons(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {reason}" for reason, n in sorted(counts.items())) or "none"


def _mb(values: Sequence[float | None]) -> str:
    return "/".join("—" if v is None else f"{v:.0f}" for v in values)


# ----------------------------------------------------------------------------- the run
def run_scale(opts: ScaleOptions, progress: Callable[[str], None] = print) -> dict[str, Any]:
    started = time.monotonic()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="simpletrack-scale-") as tmp_name:
        tmp = Path(tmp_name)
        for members in opts.instances:
            progress(f"--- {members} member{'s' if members > 1 else ''}")

            def step(kind: str, sensors: int, members: int = members) -> dict[str, Any]:
                with group(members, opts.bench, tmp) as servers:
                    return measure_step(kind, sensors, opts.bench, servers) | {"members": members}

            found = sweep(opts.bench, ("tracker",), step, progress)
            row: dict[str, Any] = {"members": members, **found}
            for fault in FAULTS:
                hit = members > 1 and opts.fault_sensors > 0
                row[fault] = fault_run(members, fault, opts, tmp, progress) if hit else None
            rows.append(row)
    one = next((r for r in rows if r["members"] == 1), None)
    base = one["capacity"]["max_sensors_passing"] if one else None
    for r in rows:
        cap = r["capacity"]["max_sensors_passing"]
        r["ratio_to_one"] = round(cap / base, 2) if cap is not None and base else None
    return {"members": rows, "elapsed_s": round(time.monotonic() - started, 1)}


def _generator_cell(gen: dict[str, Any] | None) -> str:
    """Cores busy in all generator processes, and the busiest one's."""
    if gen is None:
        return "—"
    return (
        f"{gen['cores']:g} ({gen['processes']} proc, busiest {gen['max_process_cores']:g}, "
        f"interp {gen['max_python_cores']:g})"
    )


def _cell(value: Any, unit: str = "") -> str:
    if value is None:
        return "—"
    return f"{value:g}{unit}" if isinstance(value, float) else f"{value}{unit}"


def scale_tables(doc: dict[str, Any]) -> str:
    limit = doc["options"]["p99_limit_ms"]
    lines = [
        f"capacity: most sensors at {doc['options']['rate_hz']:g} Hz with p99 < {limit:g} ms",
        "| members | capacity | ratio to 1 | cores at max | server CPU per frame at max "
        "| generator cores at max | stopped |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in doc["members"]:
        c = r["capacity"]
        at_max = next((s for s in r["steps"] if s["sensors"] == c["max_sensors_passing"]), None)
        gen = at_max["generator"] if at_max and "generator" in at_max else None
        lines.append(
            f"| {r['members']} | {_cell(c['max_sensors_passing'])} | {_cell(r['ratio_to_one'])}"
            f" | {_cell(c['server_cores_at_max'])}"
            f" | {_cell(at_max and at_max.get('server_cpu_ms_per_frame'), ' ms')}"
            f" | {_generator_cell(gen)} | {r['stopped']} |"
        )
    limited = [
        f"{r['members']} member{'s' if r['members'] > 1 else ''}, {s['sensors']} sensors: "
        + generator_line(s["generator"])
        for r in doc["members"]
        for s in r["steps"]
        if s.get("generator_limited")
    ]
    lines += limited
    lines += [
        "",
        "faults: time from the fault to another member's tracks, for the sensors the hit "
        "member served last, and how long after its put their first frame after the fault "
        "was answered; frames put from 1 s before the fault on; the other sensors' "
        f"p99 over the frames put {STALL_S:g} s before and after the fault; each member's "
        "resident memory before the fault, the survivors' at the end; the longest any put "
        "of the load generator (the vehicles) waited past its time, the fault included",
        "| members | fault | sensors | max | median | first frame after: max / median "
        "| never | frames | unanswered | "
        "victim's last again | other repeats | answers/frame before | others' p99 before "
        "-> after | memory MB before -> after | longest put lag |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["members"]:
        for fault in FAULTS:
            f = r.get(fault)
            if f is None:
                continue
            lines.append(
                f"| {r['members']} | {fault} ({f['signal']}) | {f['sensors_served_by_victim']}"
                f"/{f['sensors']} | {_cell(f['max_ms'], ' ms')} | {_cell(f['median_ms'], ' ms')}"
                f" | {_cell(f.get('first_after_max_ms'), ' ms')} / "
                f"{_cell(f.get('first_after_median_ms'), ' ms')}"
                f" | {f['not_recovered']} | {f['window_frames']} | {f['zero_answers']}"
                f" | {f.get('republished', 0)} | {f['multiple_answers']}"
                f" | {_cell(f['answers_per_frame_before'])}"
                f" | {_cell(f.get('bystander_p99_ms_before'), ' ms')} -> "
                f"{_cell(f.get('bystander_p99_ms_after'), ' ms')}"
                f" | {_mb(f.get('rss_mb_before', []))} -> {_mb(f.get('rss_mb_after', []))}"
                f" | {_cell((f.get('generator') or {}).get('lag_max_ms'), ' ms')} |"
            )
    return "\n".join(lines)
