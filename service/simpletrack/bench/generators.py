"""The load generator as several processes: one step's sensors split over N spawned
loadgen.py processes, each with its own Zenoh session and its block of the sensors
(bench/shares.py), optionally pinned to a fixed set of CPUs; their results merged into the
one result a single process gives, and the verdict whether the generator, rather than the
service, limited the step.

Why: one process has a ceiling (its interpreter lock, and the CPU the service leaves it): on
a 16-core host a single generator fell 1.5 s behind its schedule at 320 sensors at 10 Hz, and
the benchmark measured it instead of the service. Each process still times its own frames
with its own clock (put and answer in one process), so no latency compares two clocks.

Protocol (loadgen.py) with every process: "ready", then "go" to all, back to back (each
schedules its ticks from its own receipt of "go", 50 ms on, so they start within the time
the parent takes to write N messages), "start", "end", "result".
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
import time
from collections import Counter
from collections.abc import Collection, Sequence
from dataclasses import replace
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.bench import loadgen
from simpletrack.bench.shares import split_sensors

# A generator this late at p99 did not offer the load it was asked. The p99, not the max: one
# scheduler stall on a shared machine delays a burst of puts once, and is no limit.
LAG_P99_LIMIT_MS = 10.0
# An interpreter (a process's Python threads) this busy is at its limit; so is a pinned CPU
# set this busy on average.
BUSY_CORES = 0.9
BLOCKED_SHARE = 0.5  # puts blocked this much of the window: Zenoh pushed back, not the CPU


class BenchError(RuntimeError):
    """A step could not run (server did not start, load generator failed): one line."""


def expect(conn: Connection, what: str, timeout: float) -> Any:
    if not conn.poll(timeout):
        raise BenchError(f"load generator: no {what!r} message within {timeout:.0f} s")
    try:
        tag, value = conn.recv()
    except EOFError:  # it died before it could say why (its stderr has the traceback)
        raise BenchError(f"load generator: exited while {what!r} was awaited") from None
    if tag == "error":
        raise BenchError(f"load generator: {value}")
    if tag != what:
        raise BenchError(f"load generator: expected {what!r}, got {tag!r}")
    return value


def usable_cpus() -> set[int]:
    """The CPUs a process started from here may pin itself to: what the kernel grants a
    thread asking for every CPU. Wider than ``os.sched_getaffinity(0)`` when the bench runs
    under ``taskset`` (the members' CPUs), which must not keep the generator off the others;
    the thread is a probe, so this process's own affinity stays as it is."""
    found: set[int] = set()

    def probe() -> None:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, range(os.cpu_count() or 1))
        found.update(os.sched_getaffinity(0))

    thread = threading.Thread(target=probe, name="cpu-probe")
    thread.start()
    thread.join()
    return found


def parse_cpu_list(text: str, allowed: Collection[int]) -> tuple[int, ...]:
    """``"0-3"``, ``"0,1,2,3"``, ``"0-1,4"`` -> the CPUs, sorted; every one must be in
    ``allowed`` (usable_cpus()). ValueError naming the bad item otherwise."""
    cpus: set[int] = set()
    for item in text.split(","):
        low, dash, high = item.strip().partition("-")
        try:
            first = int(low)
            last = int(high) if dash else first
        except ValueError:
            raise ValueError(
                f"{item.strip()!r} is not a CPU number or a range such as 0-3"
            ) from None
        if first < 0 or last < first:
            raise ValueError(f"{item.strip()!r} is not a range from a low CPU to a higher one")
        cpus.update(range(first, last + 1))
    missing = cpus - set(allowed)
    if missing:
        raise ValueError(
            f"CPU {cpu_ranges(missing)} is not one this machine lets the generator use "
            f"(usable: {cpu_ranges(allowed)})"
        )
    return tuple(sorted(cpus))


def cpu_ranges(cpus: Collection[int]) -> str:
    """{0, 1, 2, 5} -> "0-2,5": the form the list is given in, short for any count."""
    out: list[str] = []
    for cpu in sorted(cpus):
        if out and out[-1].rpartition("-")[2] == str(cpu - 1):
            out[-1] = f"{out[-1].partition('-')[0]}-{cpu}"
        else:
            out.append(str(cpu))
    return ",".join(out)


# ----------------------------------------------------------------------------- the processes
class Generators:
    """The spawned load-generator processes of one step, spoken to as one; a context manager
    that leaves none running. Every process is given the whole CPU set (the budget is the
    set, and the kernel spreads their interpreter and Zenoh threads over it)."""

    def __init__(self, spec: loadgen.LoadSpec, processes: int, cpus: Sequence[int] = ()) -> None:
        parts = len(split_sensors(spec.sensors, processes))
        self.specs = [replace(spec, part=p, parts=parts, cpus=tuple(cpus)) for p in range(parts)]
        self.procs: list[BaseProcess] = []
        self.conns: list[Connection] = []

    def __enter__(self) -> Generators:
        ctx = multiprocessing.get_context("spawn")  # never fork a process that may hold Zenoh
        try:
            for spec in self.specs:
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=loadgen.run, args=(child, spec), daemon=True)
                proc.start()
                child.close()
                self.procs.append(proc)
                self.conns.append(parent)
        except BaseException:
            self._stop(at_once=True)
            raise
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        # After a failure the others may wait on "go" for good: no point joining them.
        self._stop(at_once=kind is not None)

    def _stop(self, at_once: bool) -> None:
        for proc in self.procs:
            if not at_once:
                proc.join(10)
            if proc.is_alive():
                proc.kill()
                proc.join(5)
        for conn in self.conns:
            conn.close()

    def expect_all(self, what: str, timeout: float) -> list[Any]:
        """Message ``what`` from every process, in process order, within ``timeout`` in all."""
        deadline = time.monotonic() + timeout
        out = []
        for p, conn in enumerate(self.conns):
            try:
                out.append(expect(conn, what, max(0.0, deadline - time.monotonic())))
            except BenchError as exc:
                if len(self.conns) == 1:
                    raise
                raise BenchError(f"{exc} (process {p} of {len(self.conns)})") from None
        return out

    def go(self) -> None:
        for conn in self.conns:
            conn.send("go")


# ----------------------------------------------------------------------------- the results
SUMMED = (
    "sent",
    "received",
    "refused",
    "lost",
    "unexpected",
    "window_sent",
    "window_received",
    "window_refused",
    "received_during_window",
    "loadgen_cpu_s",
)
# Joined in process order.
POOLED = ("latency_s", "put_lateness_s", "answers", "refusals", "sent_ns")


def merge_results(results: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The results of the processes of one step as one process's (loadgen._result), plus
    ``generators``: each process's own figures. Counts add up; latencies and put times are
    pooled (percentiles over all frames); sent_ns rows join in process order, which is the
    sensors' order (each process holds a contiguous block); the worst frame of a tick is the
    worst over the processes; the window is the longest."""
    if not results:
        raise ValueError("no load-generator results to merge")
    out: dict[str, Any] = {key: sum(r[key] for r in results) for key in SUMMED}
    reasons: Counter[str] = Counter()
    for r in results:
        reasons.update(r["refused_by_reason"])
    out["refused_by_reason"] = dict(reasons)
    for key in POOLED:
        if key in results[0]:
            out[key] = [v for r in results for v in r[key]]
    ticks = [r["worst_per_tick_ms"] for r in results]
    out["worst_per_tick_ms"] = [max(column) for column in zip(*ticks, strict=True)]
    out["window_s"] = max(r["window_s"] for r in results)
    out["generators"] = [r["generator"] for r in results]
    return out


def generator_summary(
    per_process: Sequence[dict[str, Any]], lateness_s: npt.ArrayLike, cpus: Sequence[int] = ()
) -> dict[str, Any]:
    """A step's ``generator`` figures: cores busy (summed, and the busiest process, in all its
    threads and in its interpreter's), the put lag pooled over the processes, each process's
    own figures, and the verdict."""
    late = np.asarray(lateness_s, np.float64) * 1e3
    window = max((g["window_s"] for g in per_process), default=0.0)
    limited, pushed = generator_verdict(per_process, cpus)
    return {
        "processes": len(per_process),
        "cpus": list(cpus) or None,  # None: not pinned
        "cores": round(sum(g["cpu_s"] for g in per_process) / max(window, 1e-9), 3),
        "max_process_cores": max((g["cores"] for g in per_process), default=0.0),
        "max_python_cores": max((g["python_cores"] for g in per_process), default=0.0),
        "lag_p99_ms": round(float(np.percentile(late, 99)), 3) if late.size else None,
        "lag_max_ms": round(float(late.max()), 3) if late.size else None,
        "late_puts": sum(g["late_puts"] for g in per_process),
        "max_answer_lag_p99_ms": max(
            (g["answer_lag_p99_ms"] for g in per_process if g.get("answer_lag_p99_ms") is not None),
            default=None,
        ),
        "limited": bool(limited),
        "why": limited,
        "pushed_back": pushed,
        "per_process": list(per_process),
    }


def generator_verdict(
    per_process: Sequence[dict[str, Any]], cpus: Sequence[int] = ()
) -> tuple[list[str], list[str]]:
    """(why the generator limited the step, why the service pushed back), each a list of
    findings, empty when none. The generator limited the step when a process's interpreter
    was busier than BUSY_CORES (its Python threads share one lock: it cannot do more; the
    process as a whole may pass one core, Zenoh's threads running beside it), when the
    processes kept their pinned CPUs over BUSY_CORES busy (the budget is spent), when a
    process fell behind its tick schedule (put lag p99 over LAG_P99_LIMIT_MS) without its
    puts being blocked, or when it heard the answers late (from the service's publication
    to its callback, p99 over LAG_P99_LIMIT_MS: its receiving side was behind, and the
    latency it timed is partly its own). Lag with puts blocked for BLOCKED_SHARE of the
    window is Zenoh's BLOCK congestion control holding the generator back because the
    receivers did not read: the service's limit."""
    limited: list[str] = []
    pushed: list[str] = []
    window = max((g["window_s"] for g in per_process), default=0.0)
    used = sum(g["cpu_s"] for g in per_process) / max(window, 1e-9)
    if cpus and used > BUSY_CORES * len(cpus):
        limited.append(
            f"its {len(cpus)} CPUs {100 * used / len(cpus):.0f} % busy ({used:.2f} cores in "
            f"{len(per_process)} processes)"
        )
    for g in per_process:
        p = g["process"]
        lag = f"lag p99 {g['lag_p99_ms']:.0f} ms, max {g['lag_max_ms']:.0f} ms"
        behind = g["lag_p99_ms"] > LAG_P99_LIMIT_MS
        if g["python_cores"] > BUSY_CORES:
            limited.append(
                f"{g['python_cores']:.2f} cores in the interpreter of process {p} "
                f"({g['cores']:.2f} in all its threads" + (f"; {lag})" if behind else ")")
            )
        elif behind and g["put_share"] >= BLOCKED_SHARE:
            pushed.append(
                f"process {p}: {lag} with put() blocked {100 * g['put_share']:.0f} % of the "
                "window (BLOCK congestion control: the receivers did not keep up)"
            )
        elif behind:
            limited.append(
                f"{lag} in process {p} at {g['cores']:.2f} cores (it waited for a CPU: "
                "other work on its CPUs, or too few of them)"
            )
        back = g.get("answer_lag_p99_ms")
        if back is not None and back > LAG_P99_LIMIT_MS:
            limited.append(
                f"answers heard p99 {back:.0f} ms after the service published them, in process {p}"
            )
    return limited, pushed
