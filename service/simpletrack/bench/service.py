"""``simpletrack bench service``: the running service's latency, CPU and capacity under load.

One *step* = one sensor count S and one server kind:
- ``tracker``: a fresh ``simpletrack serve`` subprocess (preset nuscenes) on 127.0.0.1;
- ``echo``: ``simpletrack.bench.echo`` in its place (the Zenoh floor).
Spawned load-generator processes (loadgen.py; several with ``generator_processes``, each a
block of the sensors: generators.py) publish S sensors at the rate and time the answers.
This process opens no Zenoh session: it starts them, and reads the server's CPU time from
``/proc/<pid>/stat`` and (tracker only) its ``/metrics`` at the window's edges.

S grows over the given list and stops after the first *saturated* step: the server could
not keep up (a frame refused, dropped or never answered, the median latency over the limit,
or its receivers holding the generator's puts back). A step *passes* when it is not
saturated, the generator kept up, and its p99 is under the limit; on a shared machine a few
scheduler stalls can fail the p99 of an otherwise idle server, which is why a p99 failure
alone does not stop the sweep. A *generator-limited* step (a generator process at its
interpreter's limit or behind its schedule: generators.generator_verdict) measured the
generator, not the service: it is no capacity figure, and S stops growing there too.
"""

from __future__ import annotations

import contextlib
import json
import linecache
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.bench import loadgen
from simpletrack.bench.against import SERVER_PATH_ENV
from simpletrack.bench.generators import BenchError, Generators, generator_summary, merge_results
from simpletrack.bench.report import generator_line
from simpletrack.bench.stats import cdf_ms, summary_ms
from simpletrack.client.publisher import DEFAULT_HEARTBEAT_S
from simpletrack.spawn import free_port, serve_command

ROOT = Path(__file__).resolve().parents[3]
CLK_TCK = os.sysconf("SC_CLK_TCK")
PREFIX = "bench"
VEHICLE = "v0"
P99_LIMIT_MS = 50.0
GOAL_P99_ONE_SENSOR_MS = 5.0
GOAL_STREAMS_PER_CORE = 500.0
STEP_OVERHEAD_S = 6.0  # start-up, connection and drain around each measured window


# The fused vehicles' settings (--fused): the load generator's lidar and front camera.
FUSION_CONFIG = """\
[fusion.sensors.lidar]
[fusion.sensors.camera]
fov_deg = 90.0
max_range_m = 70.0
r = 4.0
verify = false
"""


@dataclass(frozen=True, slots=True)
class ServiceBenchOptions:
    sensors: tuple[int, ...]
    seconds: float
    warmup_s: float
    rate_hz: float
    workers: int
    queue_size: int
    source: str  # nuscenes | synthetic
    data: Path  # the nuScenes centerpoint_val directory
    synthetic_boxes: int
    budget_s: float
    echo: bool
    profile_dir: Path | None
    p99_limit_ms: float = P99_LIMIT_MS
    profile_gil: bool = False  # py-spy --gil: only samples holding the interpreter lock
    drain_s: float = 5.0
    subscribe: str = "owned"  # the members' subscribe setting (the service's default)
    fused: bool = False  # vehicles of a lidar and a camera, fused (loadgen.LoadSpec.fused)
    generator_processes: int = 1  # load-generator processes, each a block of the sensors
    generator_cpus: tuple[int, ...] = ()  # the CPUs they all run on; () = not pinned
    heartbeat_s: float = DEFAULT_HEARTBEAT_S  # the publishers' heartbeat period


# ----------------------------------------------------------------------------- processes
def cpu_seconds(pid: int) -> float:
    """utime + stime of every thread of ``pid`` (fields 14 and 15 of /proc/<pid>/stat)."""
    text = Path(f"/proc/{pid}/stat").read_text()
    fields = text[text.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def scrape(port: int) -> dict[str, float]:
    """Every sample of /metrics as ``name{labels}`` -> value."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        text = r.read().decode()
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            with contextlib.suppress(ValueError):
                out[name] = float(value)
    return out


@dataclass
class Server:
    kind: str
    proc: subprocess.Popen[bytes]
    endpoint: str
    metrics_port: int | None
    log: Path
    instance: str = "bench"

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def tail(self) -> str:
        with contextlib.suppress(OSError):
            return self.log.read_text()[-800:].strip()
        return ""


def _wait_ready(server: Server, ready: Callable[[], bool], timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        if server.proc.poll() is not None:
            raise BenchError(f"{server.kind} exited with {server.proc.returncode}: {server.tail()}")
        if time.monotonic() > deadline:
            server.stop()
            raise BenchError(f"{server.kind} not ready after {timeout:.0f} s: {server.tail()}")
        time.sleep(0.05)


def launch_tracker(
    opts: ServiceBenchOptions,
    tmp: Path,
    *,
    port: int | None = None,
    instance: str = "bench",
    extra: Sequence[str] = (),
) -> Server:
    """A ``simpletrack serve`` starting (``wait_tracker`` waits for it to be ready)."""
    port, metrics_port = port or free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log = tmp / f"serve-{port}.log"
    cmd = serve_command(
        endpoint,
        metrics_port,
        instance,
        "--prefix",
        PREFIX,
        "--preset",
        "nuscenes",
        "--workers",
        str(opts.workers),
        "--log-level",
        "error",
        *extra,
    )
    env = {
        **os.environ,
        "NO_COLOR": "1",
        "SIMPLETRACK_QUEUE_SIZE": str(opts.queue_size),
        "SIMPLETRACK_SUBSCRIBE": opts.subscribe,
        "SIMPLETRACK_IGNORE_CLASSES": json.dumps(loadgen.UNTRACKED),
    }
    server_path = env.pop(SERVER_PATH_ENV, None)  # not a setting: serve refuses it
    if server_path:  # bench --against REF --server-only: REF's service, this generator
        env["PYTHONPATH"] = server_path
    if opts.fused:
        config = tmp / f"fusion-{port}.toml"
        config.write_text(FUSION_CONFIG)
        cmd += ["--config", str(config)]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=out, stderr=out)
    return Server("service", proc, endpoint, metrics_port, log, instance)


def wait_tracker(server: Server) -> None:
    def ready() -> bool:
        try:
            url = f"http://127.0.0.1:{server.metrics_port}/readyz"
            with urllib.request.urlopen(url, timeout=2) as r:
                return int(r.status) == 200
        except OSError:
            return False

    _wait_ready(server, ready)


def start_tracker(opts: ServiceBenchOptions, tmp: Path) -> Server:
    server = launch_tracker(opts, tmp)
    wait_tracker(server)
    return server


def start_echo(tmp: Path) -> Server:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log = tmp / f"echo-{port}.log"
    cmd = [sys.executable, "-m", "simpletrack.bench.echo", "--listen", endpoint, "--prefix", PREFIX]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=out)
    server = Server("echo", proc, endpoint, None, log)
    _wait_ready(server, lambda: "ready" in server.tail())
    return server


@contextlib.contextmanager
def running(kind: str, opts: ServiceBenchOptions, tmp: Path) -> Iterator[Server]:
    server = start_tracker(opts, tmp) if kind == "tracker" else start_echo(tmp)
    try:
        yield server
    finally:
        server.stop()


# ----------------------------------------------------------------------------- profiling
PROFILE_RATE_HZ = 200


def profiled_seconds(seconds: float) -> int:
    """How long py-spy records a window of ``seconds`` (whole seconds, at least one)."""
    return max(1, round(seconds))


def start_profiler(
    pid: int, seconds: float, out: Path, gil: bool = False
) -> subprocess.Popen[bytes] | None:
    """py-spy on the server for the window (all threads, without pausing it); ``gil``: only
    the samples of the thread holding the interpreter lock."""
    exe = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    if not Path(exe).exists():
        return None
    cmd = [
        exe,
        "record",
        "--pid",
        str(pid),
        "--duration",
        str(profiled_seconds(seconds)),
        "--rate",
        str(PROFILE_RATE_HZ),
        "--nonblocking",
        *(["--gil"] if gil else []),
        "--format",
        "raw",
        "--output",
        str(out),
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def gil_ms_per_frame(samples: int, profiled_s: float, window_s: float, frames: int) -> float:
    """The interpreter lock's time per frame from a ``--gil`` profile: the share of the
    profile's samples that found the lock held, over the frames of the measured window. py-spy
    counts a thread that holds the lock while the OS has it descheduled: a loaded machine
    inflates it, so compare only runs alternated on one machine."""
    held = samples / (PROFILE_RATE_HZ * profiled_s)
    return round(1e3 * held * window_s / max(frames, 1), 4)


def summarize_profile(path: Path, top: int = 15) -> dict[str, Any]:
    """From py-spy's collapsed stacks: where the samples are, by innermost function (self), by
    function anywhere on the stack (inclusive), and by the role of the thread."""
    self_time: Counter[str] = Counter()
    inclusive: Counter[str] = Counter()
    roles: Counter[str] = Counter()
    per_frame: Counter[str] = Counter()
    total = 0
    for line in path.read_text().splitlines():
        stack, _, count_s = line.rpartition(" ")
        if not stack or not count_s.isdigit():
            continue
        count = int(count_s)
        raw = stack.split(";")
        for i, f in enumerate(raw):
            if f.startswith(FRAME_FUNCTION):
                per_frame[_callee(raw, i)] += count
                break
        frames = [_frame_name(f) for f in raw]
        code = [f for f in frames if not f.startswith(("process", "thread"))]
        total += count
        roles[_role(code)] += count
        if code:
            self_time[code[-1]] += count
        for f in set(code):
            inclusive[f] += count

    def share(c: Counter[str]) -> list[tuple[str, float]]:
        return [(k, round(v / max(total, 1), 4)) for k, v in c.most_common(top)]

    return {
        "samples": total,
        "roles": share(roles),
        "self": share(self_time),
        "inclusive": share(inclusive),
        # What the worker's per-frame function spends its samples on (its own lines are
        # calls into native code, e.g. Zenoh's put).
        "per_frame": [
            (k, round(v / max(sum(per_frame.values()), 1), 4))
            for k, v in per_frame.most_common(top)
        ],
    }


ROLES = (
    ("Worker.run", "worker threads"),
    ("Intake.__call__", "zenoh callback (intake)"),
    ("serve_forever", "metrics http"),
)


def _role(code: list[str]) -> str:
    for marker, role in ROLES:
        if any(f.startswith(marker) for f in code):
            return role
    if code and code[-1].startswith("Thread.run"):
        return "native code under a Python thread (zenoh)"
    return "other"


FRAME_FUNCTION = "Worker._process "


def _callee(stack: list[str], i: int) -> str:
    """The function called from frame ``i``, or the source line frame ``i`` was on."""
    if i + 1 < len(stack):
        return _frame_name(stack[i + 1])
    where = stack[i].strip().partition(" (")[2].rstrip(")")
    file, _, line = where.rpartition(":")
    text = linecache.getline(str(ROOT / file), int(line)).strip() if line.isdigit() else ""
    return f"own line {line}: {text}" if text else f"own line {line}"


def _frame_name(frame: str) -> str:
    """``func (path/to/file.py:123)`` -> ``func (file.py)``; thread/process labels kept."""
    name, _, where = frame.strip().partition(" (")
    if not where:
        return frame.strip()
    file = where.rstrip(")").rsplit(":", 1)[0]
    return f"{name} ({Path(file).name})"


# ----------------------------------------------------------------------------- one step
def _stage_means(m0: dict[str, float], m1: dict[str, float]) -> dict[str, float | None]:
    out: dict[str, float | None] = {}
    for stage in ("queue", "decode", "track", "publish"):
        s = f'simpletrack_stage_seconds_sum{{stage="{stage}"}}'
        c = f'simpletrack_stage_seconds_count{{stage="{stage}"}}'
        n = m1.get(c, 0.0) - m0.get(c, 0.0)
        out[stage] = round(1e3 * (m1.get(s, 0.0) - m0.get(s, 0.0)) / n, 4) if n > 0 else None
    return out


def _counters(m: dict[str, float], name: str) -> dict[str, float]:
    out = {}
    for key, value in m.items():
        if key.startswith(name + "{") and value:
            out[key[len(name) + 1 : -1]] = value
    return out


def cpu_seconds_all(servers: Sequence[Server]) -> float:
    return sum(cpu_seconds(s.proc.pid) for s in servers)


def scrape_all(servers: Sequence[Server]) -> dict[str, float]:
    """The servers' /metrics samples added up (one server: its own)."""
    out: dict[str, float] = {}
    for server in servers:
        if server.metrics_port:
            for key, value in scrape(server.metrics_port).items():
                out[key] = out.get(key, 0.0) + value
    return out


def load_spec(
    sensors: int, opts: ServiceBenchOptions, servers: Sequence[Server]
) -> loadgen.LoadSpec:
    """The load of one step, connected to every server."""
    return loadgen.LoadSpec(
        endpoint=servers[0].endpoint,
        connect=tuple(s.endpoint for s in servers[1:]),
        prefix=PREFIX,
        vehicle=VEHICLE,
        sensors=sensors,
        rate_hz=opts.rate_hz,
        warmup_s=opts.warmup_s,
        seconds=opts.seconds,
        drain_s=opts.drain_s,
        source=opts.source,
        data=str(opts.data),
        synthetic_boxes=opts.synthetic_boxes,
        advanced=opts.subscribe == "owned",
        heartbeat_s=opts.heartbeat_s,
        fused=opts.fused,
    )


def run_step(kind: str, sensors: int, opts: ServiceBenchOptions, tmp: Path) -> dict[str, Any]:
    with running(kind, opts, tmp) as server:
        return measure_step(kind, sensors, opts, [server])


def measure_step(
    kind: str, sensors: int, opts: ServiceBenchOptions, servers: Sequence[Server]
) -> dict[str, Any]:
    """One step against running servers (several: the members of one group, their CPU and
    counters added up); every load-generator process connects to all of them."""
    spec = load_spec(sensors, opts, servers)
    server = servers[0]
    tracker = kind == "tracker"
    profiler = None
    with Generators(spec, opts.generator_processes, opts.generator_cpus) as gens:
        ready = gens.expect_all("ready", 120.0)[0]
        gens.go()
        gens.expect_all("start", opts.warmup_s + 30.0)
        cpu0, t0 = cpu_seconds_all(servers), time.monotonic()
        m0 = scrape_all(servers) if tracker else {}
        if opts.profile_dir is not None and tracker and len(servers) == 1:
            prof_path = opts.profile_dir / f"service-{sensors}-sensors.txt"
            profiler = start_profiler(server.proc.pid, opts.seconds, prof_path, opts.profile_gil)
        gens.expect_all("end", opts.seconds + 60.0)
        cpu1, t1 = cpu_seconds_all(servers), time.monotonic()
        m1 = scrape_all(servers) if tracker else {}
        result = merge_results(gens.expect_all("result", opts.drain_s + 60.0))
        m2 = scrape_all(servers) if tracker else {}
    profile = None
    if profiler is not None:
        try:
            _, err = profiler.communicate(timeout=opts.seconds + 30)
            if profiler.returncode == 0:
                profile = summarize_profile(prof_path)
                profile["file"] = str(prof_path)
            else:
                profile = {"error": err.decode(errors="replace")[-300:]}
        except subprocess.TimeoutExpired:
            profiler.kill()
            profile = {"error": "py-spy did not finish"}
    window = t1 - t0
    cpu = cpu1 - cpu0
    done = max(result["received_during_window"], 1)
    latency = np.asarray(result["latency_s"], np.float64)
    lateness = np.asarray(result["put_lateness_s"], np.float64)
    generator = generator_summary(result["generators"], lateness, opts.generator_cpus)
    step: dict[str, Any] = {
        "kind": kind,
        "sensors": sensors,
        "rate_hz": opts.rate_hz,
        "boxes_per_frame": round(ready["boxes_mean"], 1),
        "window_s": round(window, 3),
        "sent": result["sent"],
        "received": result["received"],
        "refused": result["refused"],
        "refused_by_reason": result["refused_by_reason"],
        "lost": result["lost"],
        "delivered_per_s": round(result["received_during_window"] / window, 2),
        "latency": summary_ms(latency),
        "cdf": cdf_ms(latency),
        "server_cpu_s": round(cpu, 3),
        "server_cores": round(cpu / window, 3),
        "server_cpu_ms_per_frame": round(1e3 * cpu / done, 4),
        "loadgen_cores": round(result["loadgen_cpu_s"] / max(result["window_s"], 1e-9), 3),
        "put_lateness": summary_ms(lateness),
        "worst_per_tick_ms": result["worst_per_tick_ms"],
        "unexpected": result["unexpected"],
        "generator": generator,
        "generator_limited": generator["limited"],
    }
    if kind == "tracker":
        step["metrics"] = {
            "received": m2.get("simpletrack_frames_received_total", 0.0),
            "tracked": m2.get("simpletrack_frames_tracked_total", 0.0),
            "rejected": _counters(m2, "simpletrack_frames_rejected_total"),
            "dropped": _counters(m2, "simpletrack_frames_dropped_total"),
            "window_stage_ms": _stage_means(m0, m1),
            "fusion_frames": _counters(m2, "simpletrack_fusion_frames_total"),
            # Sensors that changed member since the start: a step whose frames are both
            # refused and tracked, or repeated, reads with these (a takeover tracks again).
            "moved": {
                "handoffs": sum(_counters(m2, "simpletrack_handoffs_total").values()),
                "failovers": m2.get("simpletrack_failovers_total", 0.0),
                "fences": sum(_counters(m2, "simpletrack_fences_total").values()),
                "replayed_frames": m2.get("simpletrack_replayed_frames_total", 0.0),
            },
            "notices_dropped": m2.get("simpletrack_error_notices_dropped_total", 0.0),
        }
    if profile is not None:
        if opts.profile_gil and "samples" in profile:
            profile["gil_ms_per_frame"] = gil_ms_per_frame(
                profile["samples"], profiled_seconds(opts.seconds), window, done
            )
        step["profile"] = profile
    limit = opts.p99_limit_ms
    if opts.fused:  # a lidar frame waits for the camera's, half a period later, by design
        limit += 500.0 / opts.rate_hz
        step["fused"] = True
        step["limit_ms"] = limit
    step["saturated"], step["why"] = saturation(step, limit)
    p99 = step["latency"]["p99_ms"]
    step["passes"] = (
        not step["saturated"] and not step["generator_limited"] and p99 is not None and p99 < limit
    )
    return step


def saturation(step: dict[str, Any], limit_ms: float) -> tuple[bool, list[str]]:
    """Whether the server fell behind the offered load, and the evidence."""
    why = []
    p50 = step["latency"]["p50_ms"]
    if p50 is None or p50 >= limit_ms:
        why.append(f"median {p50} ms >= {limit_ms:g} ms (frames queue up)")
    if step["refused"]:
        why.append(f"{step['refused']} frames refused or dropped")
    if step["lost"]:
        why.append(f"{step['lost']} frames never answered")
    # The generator behind because its puts blocked: the receivers' limit, not its own.
    why += [f"load generator held back: {w}" for w in step["generator"]["pushed_back"]]
    return bool(why), why


# ----------------------------------------------------------------------------- the sweep
def capacity(steps: list[dict[str, Any]]) -> dict[str, Any]:
    """The saturation point and the per-core figure the goals are stated in."""
    tracker = sorted((s for s in steps if s["kind"] == "tracker"), key=lambda s: s["sensors"])
    # A generator-limited step says nothing of the service, unless the service refused or
    # lost frames even at the load it did get (saturated).
    judged = [s for s in tracker if s["saturated"] or not s.get("generator_limited")]
    passing = [s for s in tracker if s["passes"]]
    first_bad = next((s for s in tracker if s["saturated"]), None)
    first_fail = next((s for s in judged if not s["passes"]), None)
    first_gen = next((s for s in tracker if s.get("generator_limited")), None)
    one = next((s for s in tracker if s["sensors"] == 1), None)
    out: dict[str, Any] = {
        "one_sensor_p99_ms": one["latency"]["p99_ms"] if one else None,
        "goal_one_sensor_p99_ms": GOAL_P99_ONE_SENSOR_MS,
        "max_sensors_passing": passing[-1]["sensors"] if passing else None,
        "server_cores_at_max": passing[-1]["server_cores"] if passing else None,
        "first_failing_sensors": first_fail["sensors"] if first_fail else None,
        "first_saturated_sensors": first_bad["sensors"] if first_bad else None,
        "first_generator_limited_sensors": first_gen["sensors"] if first_gen else None,
        "streams_per_core": None,
        "streams_per_core_from_sensors": None,
        "goal_streams_per_core": GOAL_STREAMS_PER_CORE,
    }
    # A core spends server_cpu_ms_per_frame on each frame (fixed costs amortised over the
    # busiest step that kept up): that many 10 Hz streams would fill one core.
    kept_up = [s for s in tracker if not s["saturated"] and not s.get("generator_limited")]
    busiest = kept_up[-1] if kept_up else None
    if busiest is not None and busiest["server_cpu_ms_per_frame"] > 0:
        per_frame_s = busiest["server_cpu_ms_per_frame"] * 1e-3
        out["streams_per_core"] = round(1.0 / (per_frame_s * busiest["rate_hz"]), 1)
        out["streams_per_core_from_sensors"] = busiest["sensors"]
        if busiest.get("fused"):  # a vehicle is two streams (its lidar and its camera)
            out["vehicles_per_core"] = round(out["streams_per_core"] / 2, 1)
    return out


def sweep(
    opts: ServiceBenchOptions,
    kinds: Sequence[str],
    step: Callable[[str, int], dict[str, Any]],
    progress: Callable[[str], None] = print,
) -> dict[str, Any]:
    """The capacity search: ``step(kind, sensors)`` for each sensor count of ``opts``, until
    a tracker step saturates or the time budget runs out."""
    started = time.monotonic()
    steps: list[dict[str, Any]] = []
    stopped = "end of the sensor list"
    for n in opts.sensors:
        for kind in kinds:
            spent = time.monotonic() - started
            if spent + opts.warmup_s + opts.seconds + STEP_OVERHEAD_S > opts.budget_s:
                stopped = f"time budget of {opts.budget_s:g} s"
                break
            unit = "vehicles" if opts.fused else "sensors"
            progress(f"{kind:7s} {n:4d} {unit} at {opts.rate_hz:g} Hz, {opts.seconds:g} s ...")
            result = step(kind, n)
            progress("        " + step_line(result))
            steps.append(result)
        if stopped.startswith("time"):
            break
        here = [s for s in steps if s["kind"] == "tracker" and s["sensors"] == n]
        if any(s["saturated"] for s in here):
            stopped = f"saturated at {n} {'vehicles' if opts.fused else 'sensors'}"
            break
        if any(s.get("generator_limited") for s in here):  # larger steps would measure it too
            stopped = f"generator-limited at {n} {'vehicles' if opts.fused else 'sensors'}"
            break
    return {
        "steps": steps,
        "stopped": stopped,
        "capacity": capacity(steps)
        | {
            "p99_limit_ms": next(
                (s["limit_ms"] for s in steps if "limit_ms" in s), opts.p99_limit_ms
            )
        },
        "elapsed_s": round(time.monotonic() - started, 1),
    }


def run_service_bench(
    opts: ServiceBenchOptions, progress: Callable[[str], None] = print
) -> dict[str, Any]:
    kinds = ("tracker", "echo") if opts.echo else ("tracker",)
    if opts.profile_dir is not None:
        opts.profile_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="simpletrack-bench-") as tmp:
        return sweep(opts, kinds, lambda kind, n: run_step(kind, n, opts, Path(tmp)), progress)


def step_line(step: dict[str, Any]) -> str:
    lat = step["latency"]
    gen = step["generator"]
    flags = []
    if step["saturated"]:
        flags.append("SATURATED: " + "; ".join(step["why"]))
    if step["generator_limited"]:
        flags.append(generator_line(gen))
    if not flags:
        flags.append("passes" if step["passes"] else "p99 over the limit")
    return (
        f"p50 {lat['p50_ms']} ms, p99 {lat['p99_ms']} ms, max {lat['max_ms']} ms; "
        f"{step['received']}/{step['sent']} answered, {step['refused']} refused; "
        f"server {step['server_cpu_ms_per_frame']} ms CPU/frame, {step['server_cores']} cores; "
        f"generator {gen['cores']} cores in {gen['processes']} "
        f"process{'es' if gen['processes'] > 1 else ''} (busiest {gen['max_process_cores']}, "
        f"its interpreter {gen['max_python_cores']}), "
        f"lag p99 {gen['lag_p99_ms']} ms -> {'; '.join(flags)}"
    )
