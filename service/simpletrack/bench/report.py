"""The printed tables of both benchmarks, from their JSON documents."""

from __future__ import annotations

from typing import Any

from simpletrack.bench.stages import OTHER, STAGES
from simpletrack.bench.stats import fmt, table


def _load_line(doc: dict[str, Any]) -> str:
    before = doc["machine_before"]
    after = doc["machine_after"]
    return (
        f"machine: {before['cpus']} CPUs, load average {before['load_average']} before, "
        f"{after['load_average']} after; python {before['python']}, numpy {before['numpy']}"
    )


def core_tables(doc: dict[str, Any]) -> str:
    out = [_load_line(doc), ""]
    loads = doc["loads"]
    if loads:
        rows = []
        for name, r in loads.items():
            lat = r["latency"]
            rows.append(
                [
                    name,
                    str(r["frames"]),
                    fmt(r["boxes_per_frame"]["mean"], 1),
                    fmt(r["frames_per_s"], 1),
                    fmt(lat["p50_ms"], 3),
                    fmt(lat["p99_ms"], 3),
                    fmt(lat["max_ms"], 3),
                ]
            )
        out += [
            "Tracker.step per frame (clean pass)",
            table(
                ["load", "frames", "boxes/frame", "frames/s", "p50 ms", "p99 ms", "max ms"], rows
            ),
            "",
        ]
        cols = (*STAGES, OTHER)
        rows = [
            [name, *(fmt(r["stages"]["ms_per_frame"][c], 3) for c in cols)]
            for name, r in loads.items()
        ]
        out += ["ms per frame by stage (shimmed pass)", table(["load", *cols], rows), ""]
        rows = [
            [name, *(f"{100 * r['stages']['share'][c]:.1f}%" for c in cols)]
            for name, r in loads.items()
        ]
        out += ["share of the step", table(["load", *cols], rows), ""]
    fused = doc.get("fused")
    if fused:
        rows = [
            [name, fmt(fused[key]["p50_ms"], 3), fmt(fused[key]["p99_ms"], 3),
             fmt(fused[key]["max_ms"], 3)]
            for name, key in (
                ("every frame", "latency"),
                ("lidar frames (360 deg)", "lidar_latency"),
                ("camera frames (front)", "camera_latency"),
                ("one-sensor vehicle, lidar frames", "one_sensor_latency"),
            )
        ]  # fmt: skip
        out += [
            f"VehicleTracker.apply per frame: nuScenes scenes as a fused vehicle ({fused['frames']}"
            f" frames, {fused['frames_per_s']} frames/s; camera frames "
            f"{fused['camera_boxes_per_frame']} boxes)",
            table(["frames", "p50 ms", "p99 ms", "max ms"], rows),
            "",
        ]
    ref = doc["reference"]
    rows = []
    for name in ("nuscenes", "nuscenes_parity"):
        if name not in ref:
            continue
        r = ref[name]
        rows.append(
            [
                name,
                "median 350 ms, p99 1600 ms, 2.3 frames/s",
                f"{r['median_speedup']}x",
                f"{r['p99_speedup']}x",
                f"{r['frames_per_s_speedup']}x",
                "yes" if r["meets_goal"] else "NO",
            ]
        )
    if "kitti_car" in ref:
        r = ref["kitti_car"]
        rows.append(
            [
                "kitti_car",
                "median 9.9 ms, p99 88 ms, 58 frames/s",
                f"{r['median_speedup']}x",
                f"{r['p99_speedup']}x",
                f"{r['frames_per_s_speedup']}x",
                "-",
            ]
        )
    if "kitti_all" in ref:
        r = ref["kitti_all"]
        rows.append(
            [
                "kitti_all",
                f"{r['reference']['frames_per_s']} frames/s (sum of classes)",
                "-",
                "-",
                f"{r['frames_per_s_speedup']}x",
                "-",
            ]
        )
    if rows:
        out += [
            f"against the reference ({ref['source']}); goal >= {ref['goal_speedup']:g}x "
            "on the nuScenes median",
            table(["load", "reference", "median", "p99", "frames/s", "goal"], rows),
            "",
        ]
    sw = doc["sweep"]
    if sw:
        rows = []
        for p in sw["points"]:
            share = p["stages"]["share"]
            top = max(share, key=lambda k: share[k])
            rows.append(
                [
                    str(p["boxes"]),
                    str(p["latency"]["count"]),
                    fmt(p["latency"]["p50_ms"], 3),
                    fmt(p["latency"]["p99_ms"], 3),
                    fmt(p["stages"]["ms_per_frame"]["cost_matrix"], 3),
                    f"{top} {100 * share[top]:.0f}%",
                ]
            )
        tail = sw["exponent_from_100"]
        out += [
            f"scaling sweep (one class, as many tracks as boxes): time ∝ boxes^"
            f"{sw['exponent']}" + (f", from 100 boxes up ^{tail}" if tail is not None else ""),
            table(["boxes", "frames", "p50 ms", "p99 ms", "cost matrix ms", "largest stage"], rows),
        ]
    return "\n".join(out)


def _generator_cells(step: dict[str, Any]) -> list[str]:
    """Generator processes, the busiest one's cores (all its threads, and its interpreter's),
    the puts' lag behind schedule at p99."""
    gen = step.get("generator")
    if gen is None:  # a document from before the generator was split
        return ["-", "-", "-", "-"]
    return [
        str(gen["processes"]),
        fmt(gen["max_process_cores"]),
        fmt(gen["max_python_cores"]),
        fmt(gen["lag_p99_ms"]),
    ]


def generator_line(gen: dict[str, Any]) -> str:
    """The verdict on a generator-limited step, in one line."""
    return "generator-limited (not the service): " + "; ".join(gen["why"])


def _verdict(step: dict[str, Any]) -> str:
    if step["saturated"]:
        return "SATURATED"
    if step.get("generator_limited"):
        return "GENERATOR-LIMITED"
    return "passes" if step["passes"] else "p99 > limit"


def service_tables(doc: dict[str, Any]) -> str:
    out = [_load_line(doc), f"latency clock: {doc['clock']}", ""]
    rows = []
    for s in doc["steps"]:
        lat = s["latency"]
        stage = s.get("metrics", {}).get("window_stage_ms", {})
        rows.append(
            [
                s["kind"],
                str(s["sensors"]),
                fmt(s["boxes_per_frame"], 0),
                f"{s['received']}/{s['sent']}",
                str(s["refused"]),
                str(s["lost"]),
                fmt(s["delivered_per_s"], 0),
                fmt(lat["p50_ms"]),
                fmt(lat["p99_ms"]),
                fmt(lat["max_ms"]),
                fmt(s["server_cpu_ms_per_frame"], 3),
                fmt(s["server_cores"]),
                fmt(stage.get("track"), 3),
                fmt(s["loadgen_cores"]),
                *_generator_cells(s),
                _verdict(s),
            ]
        )
    out += [
        table(
            [
                "server",
                "sensors",
                "boxes",
                "answered/sent",
                "refused",
                "lost",
                "frames/s",
                "p50 ms",
                "p99 ms",
                "max ms",
                "CPU ms/frame",
                "cores",
                "track ms",
                "loadgen cores",
                "procs",
                "busiest",
                "interp",
                "lag p99 ms",
                "",
            ],
            rows,
        ),
        "",
    ]
    for s in doc["steps"]:
        if s["why"]:
            out.append(f"{s['kind']} at {s['sensors']} sensors: " + "; ".join(s["why"]))
        if s.get("generator_limited"):
            out.append(f"{s['kind']} at {s['sensors']} sensors: " + generator_line(s["generator"]))
    cap = doc["capacity"]
    unit = "vehicles" if cap.get("vehicles_per_core") is not None else "sensors"
    out += [
        f"stopped: {doc['stopped']} after {doc['elapsed_s']} s",
        f"1 sensor: p99 {fmt(cap['one_sensor_p99_ms'])} ms "
        f"(goal <= {cap['goal_one_sensor_p99_ms']:g} ms)",
        f"largest passing step: {fmt(cap['max_sensors_passing'])} {unit} at "
        f"{doc['steps'][0]['rate_hz'] if doc['steps'] else '-'} Hz "
        f"(p99 < {cap['p99_limit_ms']:g} ms, nothing refused or lost); first failing: "
        f"{fmt(cap['first_failing_sensors'])}; first saturated: "
        f"{fmt(cap['first_saturated_sensors'])}"
        + (
            f"; generator-limited from {cap['first_generator_limited_sensors']} (a capacity "
            "above that is unmeasured, not absent)"
            if cap.get("first_generator_limited_sensors") is not None
            else ""
        ),
        f"streams per core: {fmt(cap['streams_per_core'], 1)} (1 / (server CPU per frame x rate) "
        f"at {fmt(cap['streams_per_core_from_sensors'])} {unit}, the busiest step that kept "
        f"up); goal >= {cap['goal_streams_per_core']:g}",
    ]
    if unit == "vehicles":
        out.append(f"vehicles per core: {fmt(cap['vehicles_per_core'], 1)} (two streams each)")
    for s in doc["steps"]:
        prof = s.get("profile")
        if prof and "gil_ms_per_frame" in prof:
            out.append(
                f"py-spy --gil, {s['sensors']} sensors: the interpreter lock held "
                f"{prof['gil_ms_per_frame']:.3f} ms per frame"
            )
        if prof and "self" in prof:
            top = ", ".join(f"{name} {100 * share:.0f}%" for name, share in prof["self"][:6])
            out.append(f"py-spy, {s['sensors']} sensors, innermost functions: {top}")
            parts = ", ".join(f"{name} {100 * share:.0f}%" for name, share in prof["per_frame"][:5])
            out.append(f"    per frame (under Worker._process): {parts}")
    return "\n".join(out)
