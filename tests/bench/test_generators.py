"""The load generator spread over several processes (bench/generators.py, bench/shares.py):
the CPU list, the sensor split and the key expressions that keep each process's answers its
own, the schedule's phases, the merge of the processes' results, the verdict that the
generator (not the service) limited a step and how capacity treats such a step; and one
short real `bench service` step with two pinned generator processes (~8 s)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from simpletrack.bench import loadgen
from simpletrack.bench.generators import (
    generator_summary,
    generator_verdict,
    merge_results,
    parse_cpu_list,
)
from simpletrack.bench.service import ServiceBenchOptions, capacity, sweep
from simpletrack.bench.shares import chunk_patterns, digit_prefixes, split_sensors
from simpletrack.cli.main import main


# ----------------------------------------------------------------------------- the CPU list
@pytest.mark.parametrize(
    ("text", "cpus"),
    [
        ("0-3", (0, 1, 2, 3)),
        ("0,1,2,3", (0, 1, 2, 3)),
        ("3,0-1", (0, 1, 3)),
        ("2", (2,)),
        (" 1 , 2-2 ", (1, 2)),
        ("1,1,0-1", (0, 1)),
    ],
)
def test_a_cpu_list_reads_as_sorted_cpus(text: str, cpus: tuple[int, ...]) -> None:
    assert parse_cpu_list(text, range(8)) == cpus


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("0-9", "CPU 8-9 is not one this machine lets the generator use (usable: 0-7)"),
        ("0,8,10-12", "CPU 8,10-12 is not one"),
        ("x", "'x' is not a CPU number"),
        ("0,,1", "'' is not a CPU number"),
        ("3-1", "'3-1' is not a range from a low CPU"),
        ("-1", "'-1' is not a CPU number"),
        ("0-", "'0-' is not a CPU number"),
        ("1.5", "'1.5' is not a CPU number"),
    ],
)
def test_a_bad_cpu_list_names_the_bad_item(text: str, needle: str) -> None:
    with pytest.raises(ValueError) as info:
        parse_cpu_list(text, range(8))
    assert needle in str(info.value)


@pytest.mark.skipif(
    len(os.sched_getaffinity(0)) < 2 or shutil.which("taskset") is None,
    reason="needs two CPUs and taskset",
)
def test_a_bench_under_taskset_may_still_give_the_generator_the_other_cpus() -> None:
    """The documented layout: the bench (and so the service) under taskset on some CPUs,
    the generator on others."""
    first, *rest = sorted(os.sched_getaffinity(0))
    code = "from simpletrack.bench.generators import usable_cpus; print(sorted(usable_cpus()))"
    out = subprocess.run(
        ["taskset", "-c", str(first), sys.executable, "-c", code],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert json.loads(out) == [first, *rest]


# ----------------------------------------------------------------------------- the split
@pytest.mark.parametrize(
    ("sensors", "processes", "blocks"),
    [
        (1, 1, [range(0, 1)]),
        (10, 1, [range(0, 10)]),
        (10, 2, [range(0, 5), range(5, 10)]),
        (10, 3, [range(0, 3), range(3, 6), range(6, 10)]),
        (3, 5, [range(0, 1), range(1, 2), range(2, 3)]),  # no process without a sensor
        (1200, 4, [range(0, 300), range(300, 600), range(600, 900), range(900, 1200)]),
    ],
)
def test_each_sensor_is_in_exactly_one_contiguous_block(
    sensors: int, processes: int, blocks: list[range]
) -> None:
    got = split_sensors(sensors, processes)
    assert got == blocks
    assert [i for b in got for i in b] == list(range(sensors))
    assert max(map(len, got)) - min(map(len, got)) <= 1


@pytest.mark.parametrize(
    ("block", "prefixes"),
    [
        (range(0, 300), ["00", "01", "02"]),
        (range(7, 30), ["0007", "0008", "0009", "001", "002"]),
        (range(5, 6), ["0005"]),
        (range(0, 10_000), [""]),
        (range(990, 1010), ["099", "100"]),
    ],
)
def test_a_block_is_the_fewest_decimal_prefixes(block: range, prefixes: list[str]) -> None:
    assert digit_prefixes(block) == prefixes


@pytest.mark.parametrize("block", [range(0, 333), range(333, 667), range(34, 998), range(1, 2)])
def test_the_prefixes_select_exactly_the_block(block: range) -> None:
    covered = [
        i for i in range(10_000) if any(f"{i:04d}".startswith(p) for p in digit_prefixes(block))
    ]
    assert covered == list(block)


@pytest.mark.parametrize("fused", [False, True])
def test_each_process_hears_its_own_sensors_answers_and_no_other(fused: bool) -> None:
    """What Zenoh will route: every answer key of the load against each process's
    subscriptions, matched by Zenoh's own key-expression intersection."""
    base = loadgen.LoadSpec(
        endpoint="tcp/127.0.0.1:7447", prefix="bench", vehicle="v0", sensors=37, rate_hz=10.0,
        warmup_s=0.0, seconds=1.0, drain_s=1.0, source="synthetic", data="", synthetic_boxes=4,
        fused=fused,
    )  # fmt: skip
    leaf = "@vehicle/tracks" if fused else "tracks"
    owner = {}
    for part, block in enumerate(split_sensors(37, 3)):
        spec = replace(base, part=part, parts=3)
        subs = [zenoh.KeyExpr(k) for k in loadgen.answer_keys(spec, "tracks")]
        errs = [zenoh.KeyExpr(k) for k in loadgen.answer_keys(spec, "errors")]
        for i in range(37):
            name = loadgen.vehicle_name("v0", i) if fused else loadgen.sensor_name(i)
            tracks = zenoh.KeyExpr(f"bench/{name}/{leaf}" if fused else f"bench/v0/{name}/{leaf}")
            error = zenoh.KeyExpr(
                f"bench/{name}/camera/errors" if fused else f"bench/v0/{name}/errors"
            )
            heard = any(s.intersects(tracks) for s in subs)
            assert heard == (i in block), (part, i)
            assert any(s.intersects(error) for s in errs) == (i in block), (part, i)
            if heard:
                owner[i] = part
    assert sorted(owner) == list(range(37))
    # One process holds the whole load: the wildcard it always had.
    assert loadgen.answer_keys(base, "tracks") == [
        "bench/*/@vehicle/tracks" if fused else "bench/v0/*/tracks"
    ]


def test_chunk_patterns_write_whole_numbers_without_a_wildcard() -> None:
    assert chunk_patterns("s", range(0, 300)) == ["s00$*", "s01$*", "s02$*"]
    assert chunk_patterns("v0", range(600, 601)) == ["v00600"]


# ----------------------------------------------------------------------------- the schedule
@pytest.mark.parametrize("fused", [False, True])
def test_one_process_keeps_the_old_phases(fused: bool) -> None:
    spec = _spec(sensors=7, fused=fused)
    period = 100_000_000
    n = spec.streams
    if fused:
        half = period // 2
        old = [(i // 2) * half // spec.sensors + (i % 2) * half for i in range(n)]
    else:
        old = [i * period // n for i in range(n)]
    assert loadgen.phases(spec, period) == old


def test_several_processes_spread_over_the_whole_period_and_interleave() -> None:
    period = 100_000_000
    offsets = [loadgen.phases(_spec(sensors=8, part=p, parts=2), period) for p in range(2)]
    assert offsets[0] == [0, 25_000_000, 50_000_000, 75_000_000]
    assert offsets[1] == [12_500_000, 37_500_000, 62_500_000, 87_500_000]


@pytest.mark.parametrize(("fused", "order"), [(False, [0, 1, 2]), (True, [0, 2, 4, 1, 3, 5])])
def test_each_tick_puts_in_time_order(fused: bool, order: list[int]) -> None:
    """A fused vehicle's camera is due after the other vehicles' lidars: put in row order,
    it ran late by design and counted as the generator's lag."""
    spec = replace(_spec(sensors=3, fused=fused), rate_hz=100.0, seconds=0.02)
    columns = loadgen.box_columns(loadgen.synthetic_box_arrays(2, 0)[0])
    frame = {"lidar": columns, "camera": columns} if fused else columns
    puts: list[int] = []

    class Pub:
        def __init__(self, row: int) -> None:
            self.row = row

        def put(self, payload: bytes) -> None:
            puts.append(self.row)

    class Conn:
        def send(self, message: object) -> None:
            pass

    sched = loadgen._publish(
        spec,
        [Pub(r) for r in spec.rows],
        [[frame]],
        loadgen.Receiver(spec),
        Conn(),  # type: ignore[arg-type]
    )
    assert spec.ticks == 2 and puts == order * 2
    assert sched.sent_ns.shape == (len(order), 2) and (sched.put_ns >= 0).all()


def _spec(sensors: int, part: int = 0, parts: int = 1, fused: bool = False) -> loadgen.LoadSpec:
    return loadgen.LoadSpec(
        endpoint="tcp/127.0.0.1:7447", prefix="bench", vehicle="v0", sensors=sensors,
        rate_hz=10.0, warmup_s=0.0, seconds=1.0, drain_s=1.0, source="synthetic", data="",
        synthetic_boxes=4, fused=fused, part=part, parts=parts,
    )  # fmt: skip


def test_thread_cpu_sees_this_thread_s_work_and_not_another_s() -> None:
    me = threading.get_native_id()
    idle = threading.Thread(target=time.sleep, args=(0.3,))
    idle.start()
    before = loadgen.thread_cpu()
    end = time.thread_time() + 0.2
    while time.thread_time() < end:
        pass
    after = loadgen.thread_cpu()
    idle.join()
    assert after[me] - before[me] >= 0.15
    assert idle.native_id is not None
    assert after.get(idle.native_id, 0.0) - before.get(idle.native_id, 0.0) <= 0.02


# ----------------------------------------------------------------------------- the merge
def _result(p: int, sent: int, received: int, latency: list[float], ticks: list[float],
            reasons: dict[str, int], cpu: float, window: float, rows: list[list[int]]) -> dict[str, Any]:  # fmt: skip
    return {
        "sent": sent, "received": received, "refused": sum(reasons.values()),
        "refused_by_reason": reasons, "lost": sent - received - sum(reasons.values()),
        "unexpected": 0, "window_sent": sent, "window_received": received,
        "window_refused": 0, "received_during_window": received, "latency_s": latency,
        "worst_per_tick_ms": ticks, "put_lateness_s": [0.001 * p], "loadgen_cpu_s": cpu,
        "window_s": window, "answers": [(r[0], 0, "m0", 1) for r in rows], "sent_ns": rows,
        "generator": {"process": p},
    }  # fmt: skip


def test_one_process_s_result_merges_to_itself() -> None:
    one = _result(0, 10, 9, [0.1, 0.2], [1.0, 2.0], {"dropped": 1}, 0.5, 2.0, [[0], [1]])
    merged = merge_results([one])
    assert {k: v for k, v in merged.items() if k != "generators"} == {
        k: v for k, v in one.items() if k != "generator"
    }
    assert merged["generators"] == [{"process": 0}]


def test_several_results_add_up_pool_and_keep_the_sensors_order() -> None:
    a = _result(0, 10, 8, [0.1], [1.0, 5.0], {"dropped": 1}, 0.5, 2.0, [[0], [1]])
    b = _result(1, 20, 18, [0.3, 0.2], [3.0, 2.0], {"dropped": 1, "late": 1}, 0.25, 2.5, [[2]])
    m = merge_results([a, b])
    assert (m["sent"], m["received"], m["refused"], m["lost"]) == (30, 26, 3, 1)
    assert m["refused_by_reason"] == {"dropped": 2, "late": 1}
    assert m["latency_s"] == [0.1, 0.3, 0.2]
    assert m["worst_per_tick_ms"] == [3.0, 5.0]
    assert m["sent_ns"] == [[0], [1], [2]] and [r[0] for r in m["answers"]] == [0, 1, 2]
    assert m["loadgen_cpu_s"] == 0.75 and m["window_s"] == 2.5
    assert m["generators"] == [{"process": 0}, {"process": 1}]


# ----------------------------------------------------------------------------- the verdict
def _gen(
    p: int, python: float, lag_p99: float, put_share: float = 0.0, cores: float | None = None
) -> dict[str, Any]:
    cores = python * 2 if cores is None else cores  # Zenoh's threads as busy as Python's
    return {
        "process": p, "cores": cores, "python_cores": python, "cpu_s": cores * 2.0,
        "window_s": 2.0, "lag_p99_ms": lag_p99, "lag_max_ms": lag_p99 * 2, "late_puts": 0,
        "put_share": put_share, "answer_lag_p99_ms": 0.5,
    }  # fmt: skip


@pytest.mark.parametrize(
    ("processes", "cpus", "limited", "pushed"),
    [
        ([_gen(0, 0.3, 0.5), _gen(1, 0.4, 2.0)], (), [], []),
        # The process past one core, its interpreter not: Zenoh's threads run beside it.
        ([_gen(0, 0.6, 0.5, cores=1.3)], (), [], []),
        (
            [_gen(0, 0.3, 0.5), _gen(1, 0.98, 2.0)],
            (),
            ["0.98 cores in the interpreter of process 1 (1.96 in all its threads)"],
            [],
        ),
        (
            [_gen(0, 0.95, 34.0)],
            (),
            ["0.95 cores in the interpreter of process 0 (1.90 in all its threads; lag p99 34"],
            [],
        ),
        ([_gen(0, 0.2, 10.0)], (), [], []),  # at the limit, not over
        (
            [_gen(0, 0.3, 0.5), _gen(1, 0.3, 34.0)],
            (),
            ["lag p99 34 ms, max 68 ms in process 1 at 0.60 cores (it waited for a CPU"],
            [],
        ),
        ([_gen(0, 0.3, 34.0, put_share=0.8)], (), [], ["process 0: lag p99 34 ms, max 68 ms"]),
        ([_gen(0, 0.3, 34.0, put_share=0.2)], (), ["lag p99 34 ms"], []),
        # The pinned budget spent: 3.7 cores of 4 CPUs, no process at its own limit.
        (
            [_gen(p, 0.45, 1.0, cores=0.925) for p in range(4)],
            (0, 1, 2, 3),
            ["its 4 CPUs 92 % busy (3.70 cores in 4 processes)"],
            [],
        ),
        ([_gen(p, 0.45, 1.0, cores=0.85) for p in range(4)], (0, 1, 2, 3), [], []),
        # Answers heard late: this process's receiving side, not the service's work.
        (
            [_gen(0, 0.3, 0.5) | {"answer_lag_p99_ms": 25.0}],
            (),
            ["answers heard p99 25 ms after the service published them, in process 0"],
            [],
        ),
        ([_gen(0, 0.3, 0.5) | {"answer_lag_p99_ms": 2.0}], (), [], []),
        ([_gen(0, 0.3, 0.5) | {"answer_lag_p99_ms": None}], (), [], []),  # the echo's
    ],
)
def test_the_generator_limited_verdict(
    processes: list[dict[str, Any]], cpus: tuple[int, ...], limited: list[str], pushed: list[str]
) -> None:
    got_limited, got_pushed = generator_verdict(processes, cpus)
    assert len(got_limited) == len(limited) and len(got_pushed) == len(pushed)
    for got, want in zip(got_limited + got_pushed, limited + pushed, strict=True):
        assert got.startswith(want), (got, want)


def test_the_summary_adds_cores_and_finds_the_busiest_process() -> None:
    per_process = [_gen(0, 0.25, 1.0, cores=0.5), _gen(1, 0.4, 1.0, cores=0.98)]
    s = generator_summary(per_process, [0.001] * 99 + [0.05], (0, 1, 2))
    assert s["processes"] == 2 and s["cpus"] == [0, 1, 2]
    assert s["cores"] == pytest.approx(1.48) and s["max_process_cores"] == 0.98
    assert s["max_python_cores"] == 0.4
    assert not s["limited"] and s["why"] == [] and s["pushed_back"] == []
    assert s["lag_max_ms"] == 50.0
    busy = generator_summary([*per_process, _gen(2, 0.97, 1.0, cores=0.97)], [0.001], (0, 1, 2))
    assert busy["limited"] and busy["why"][0].startswith("0.97 cores in the interpreter")


# ----------------------------------------------------------------------------- capacity
def _step(sensors: int, *, saturated: bool = False, limited: bool = False) -> dict[str, Any]:
    return {
        "kind": "tracker", "sensors": sensors, "rate_hz": 10.0, "saturated": saturated,
        "why": ["2 frames refused or dropped"] if saturated else [], "generator_limited": limited,
        "passes": not saturated and not limited, "server_cores": 0.1 * sensors,
        "server_cpu_ms_per_frame": 1.0 + sensors, "received": 1, "sent": 1, "refused": 0,
        "latency": {"p50_ms": 1.0, "p99_ms": 2.0, "max_ms": 3.0},
        "generator": {"cores": 0.5, "processes": 2, "max_process_cores": 1.5,
                      "max_python_cores": 0.95, "lag_p99_ms": 40.0,
                      "why": ["0.95 cores in the interpreter of process 1"]},
    }  # fmt: skip


def test_a_generator_limited_step_is_no_capacity_figure() -> None:
    cap = capacity([_step(10), _step(20), _step(30, limited=True)])
    assert cap["max_sensors_passing"] == 20
    assert cap["first_failing_sensors"] is None  # the service did not fail: it was not measured
    assert cap["first_saturated_sensors"] is None
    assert cap["first_generator_limited_sensors"] == 30
    assert cap["streams_per_core_from_sensors"] == 20


def test_refusals_count_against_the_service_even_when_the_generator_lagged() -> None:
    cap = capacity([_step(10), _step(20, saturated=True, limited=True)])
    assert cap["first_failing_sensors"] == cap["first_saturated_sensors"] == 20


def test_the_sweep_stops_at_a_generator_limited_step() -> None:
    opts = ServiceBenchOptions(
        sensors=(10, 20, 30, 40), seconds=1.0, warmup_s=0.0, rate_hz=10.0, workers=2,
        queue_size=64, source="synthetic", data=Path(), synthetic_boxes=4, budget_s=1e6,
        echo=False, profile_dir=None,
    )  # fmt: skip
    done: list[int] = []

    def step(kind: str, n: int) -> dict[str, Any]:
        done.append(n)
        return _step(n, limited=n >= 20)

    lines: list[str] = []
    out = sweep(opts, ("tracker",), step, lines.append)
    assert done == [10, 20]
    assert out["stopped"] == "generator-limited at 20 sensors"
    assert any(
        "generator-limited (not the service): 0.95 cores in the interpreter" in ln for ln in lines
    )


# ----------------------------------------------------------------------------- the CLI
@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--generator-cpus", "0-4096"], "--generator-cpus '0-4096': CPU "),
        (["--generator-cpus", "4096"], "--generator-cpus '4096': CPU 4096 is not one"),
        (["--generator-cpus", "a-b"], "--generator-cpus 'a-b': 'a-b' is not a CPU number"),
        (["--generator-processes", "0"], "--generator-processes 0 must be in 1..64"),
        (["--heartbeat", "0"], "--heartbeat 0 must be in 0.01..3600 seconds"),
    ],
)
@pytest.mark.parametrize("bench", ["service", "scale"])
def test_bad_generator_flags_are_one_line_errors(
    bench: str, args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", bench, "--source", "synthetic", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("simpletrack bench: error:") and "\n" not in err, err
    assert needle in err, err


def test_the_heartbeat_reaches_the_publishers_and_ref_only_when_given() -> None:
    import argparse

    from simpletrack.bench.service import Server, load_spec
    from simpletrack.cli.bench import _generator_option

    def flags(heartbeat: float | None) -> list[str]:
        ns = argparse.Namespace(generator_processes=1, generator_cpus=None, heartbeat=heartbeat)
        return _generator_option(ns)

    assert flags(2.0) == ["--heartbeat", "2.0"]
    assert flags(None) == []  # an older REF does not know the flag
    opts = ServiceBenchOptions(
        sensors=(3,), seconds=1.0, warmup_s=0.0, rate_hz=10.0, workers=2, queue_size=64,
        source="synthetic", data=Path(), synthetic_boxes=4, budget_s=1e6, echo=False,
        profile_dir=None,
    )  # fmt: skip
    server = Server("tracker", None, "tcp/127.0.0.1:1", None, Path())  # type: ignore[arg-type]
    assert load_spec(3, opts, [server]).heartbeat_s == 0.5  # DetectionPublisher's default
    assert load_spec(3, replace(opts, heartbeat_s=2.0), [server]).heartbeat_s == 2.0


# ----------------------------------------------------------------------------- a real step
@pytest.mark.zenoh
def test_two_pinned_generator_processes_each_time_their_own_sensors(tmp_path: Path) -> None:
    cpu = max(os.sched_getaffinity(0))
    out = tmp_path / "service.json"
    rc = main(
        [
            *("bench", "service", "--sensors", "5", "--seconds", "1.5", "--warmup", "0.5"),
            *("--source", "synthetic", "--synthetic-boxes", "20", "--no-echo"),
            *("--generator-processes", "2", "--generator-cpus", str(cpu), "--json", str(out)),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    (step,) = doc["steps"]
    ticks = 20  # (0.5 + 1.5) s at 10 Hz
    assert step["sent"] == step["received"] == 5 * ticks  # every frame answered
    assert step["unexpected"] == 0
    gen = step["generator"]
    assert gen["processes"] == 2 and gen["cpus"] == [cpu]
    assert gen["cores"] > 0 and gen["max_process_cores"] > 0 and gen["lag_p99_ms"] is not None
    procs = gen["per_process"]
    assert [p["sensors"] for p in procs] == [[0, 2], [2, 5]]
    for p in procs:
        # Every thread of the process (Zenoh's included) ran on the CPU it was given.
        assert p["cpus"] == [cpu]
        assert p["cpu_s"] > 0 and p["cores"] > 0 and p["lag_max_ms"] >= p["lag_p99_ms"] >= 0
        assert p["answer_lag_p99_ms"] is not None and p["answer_lag_p99_ms"] > -1.0
        # Whole /proc ticks (10 ms) per thread against process_time's nanoseconds.
        assert 0 <= p["python_cores"] <= p["cores"] + 0.05
        # Each process heard the answers to its own frames, all of them, and none other.
        own = p["sensors"][1] - p["sensors"][0]
        assert p["sent"] == p["received"] == own * ticks
        assert p["unexpected"] == 0
    # The N=1 keys are all still there.
    for key in ("loadgen_cores", "put_lateness", "latency", "worst_per_tick_ms", "saturated"):
        assert key in step
    assert len(step["worst_per_tick_ms"]) == 15  # the measured ticks


def test_a_frame_answered_and_named_in_a_notice_counts_once_toward_the_wait() -> None:
    # A failover's notice naming a frame that was tracked too made the count of answers reach
    # the frames sent while the run's last frame was still on its way back: it was counted
    # unanswered (bench scale, 1 frame of 3,200 once in a few runs).
    r = loadgen.Receiver(_spec(2))
    r.recv_ns[0, 0] = r.recv_ns[1, 0] = 1
    r.refused[0, 0] = True  # tracked and refused: one answered frame
    r.received, r.errors = 2, 1
    assert r.answered() == 2  # of 2 x 10 sent: the wait goes on
    r.refused[1, 1] = True  # a frame refused alone is answered
    assert r.answered() == 3


class _Sample:
    """What the receiver reads of a Zenoh sample: its key and its payload's bytes."""

    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr = key
        self.payload = zenoh.ZBytes(payload)


def test_a_notice_of_frames_shed_together_answers_every_frame_it_names() -> None:
    # A member that sheds two frames of one sensor before its worker announces them names both
    # in one notice (seqs): the receiver marked only the first, and a saturated step reported
    # the others "never answered" (bench scale, 8 members on 2 cores: 5 shed, 2 "lost").
    from simpletrack.server.outbox import drop_notice, frame_error
    from simpletrack.wire.codec import encode
    from simpletrack.wire.reasons import ErrorReason

    r = loadgen.Receiver(_spec(2))
    shed = [3, 4, 6]
    notice = frame_error(
        "v0", "s0001", drop_notice(ErrorReason.DROPPED_QUEUE_FULL, list(shed), 1), "a", 1, list(shed)
    )  # fmt: skip
    r.on_errors(_Sample("bench/v0/s0001/errors", encode(notice)))  # type: ignore[arg-type]
    assert r.refused[1].nonzero()[0].tolist() == shed
    assert r.errors == 3 and r.reasons["dropped_queue_full"] == 3
    assert r.answered() == 3
    one = frame_error("v0", "s0000", drop_notice(ErrorReason.DROPPED_QUEUE_FULL, [2], 1), "a", 1)
    r.on_errors(_Sample("bench/v0/s0000/errors", encode(one)))  # type: ignore[arg-type]
    assert r.refused[0].nonzero()[0].tolist() == [2] and r.errors == 4
    # Every other frame tracked but one: that one alone is lost, whatever the count of notices.
    r.recv_ns[~r.refused] = 1
    r.recv_ns[0, 5] = 0
    ones = np.ones_like(r.recv_ns)
    sched = loadgen.Schedule(ones, ones * 0, ones * 0, 0.1, 0.1, 1.0)
    assert loadgen._result(r.spec, sched, r)["lost"] == 1
