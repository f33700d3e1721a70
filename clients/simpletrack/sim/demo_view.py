"""What the demo shows: a live rich table while it runs, and a plain summary at the end."""

from __future__ import annotations

import math
import time
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from simpletrack.sim.demo import DemoOptions, DemoResult, ServiceMode
from simpletrack.sim.demo_stats import FleetStats, recent_quantile

SERVICE_WORDS = {
    ServiceMode.INPROCESS: "in-process",
    ServiceMode.SUBPROCESS: "subprocess",
    ServiceMode.EXTERNAL: "external",
}


def _ms(seconds: float) -> str:
    return "-" if math.isnan(seconds) else f"{seconds * 1e3:.1f}"


def _mota(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.3f}"


def live_view(result: DemoResult, options: DemoOptions) -> Group:
    stats = result.stats
    now = time.monotonic()
    sim = options.sim
    length = f" / {options.duration:g} s" if options.duration else " (Ctrl-C to stop)"
    header = Text.assemble(
        ("simpletrack demo", "bold"),
        f"  {sim.vehicles} vehicles x {len(sim.sensors)} sensors, seed {sim.seed}, "
        f"service {SERVICE_WORDS[result.service]} on {result.endpoint}  ",
        (f"{result.elapsed:.1f} s{length}", "cyan"),
    )
    table = Table(expand=False, header_style="bold")
    for name, justify in (
        ("vehicle", "left"),
        ("sensor", "left"),
        ("tracked/sent", "right"),
        ("Hz", "right"),
        ("p50 ms", "right"),
        ("p99 ms", "right"),
        ("tracks", "right"),
        ("rejected", "right"),
        ("MOTA", "right"),
        ("IDS", "right"),
    ):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    rate_total = 0.0
    for st in stats.streams.values():
        rate = st.rate(now)
        rate_total += rate
        mot = st.scorer.counts
        table.add_row(
            st.vehicle,
            st.sensor,
            f"{st.tracked}/{st.sent}",
            f"{rate:.1f}",
            _ms(recent_quantile(st.recent_latency, 0.5)),
            _ms(recent_quantile(st.recent_latency, 0.99)),
            f"{st.tracks_now}",
            f"{sum(st.rejected.values())}",
            _mota(mot.mota),
            f"{mot.ids}",
        )
    mot = stats.mot
    table.add_section()
    table.add_row(
        "fleet",
        f"{len(stats.streams)} streams",
        f"{stats.tracked}/{stats.sent}",
        f"{rate_total:.1f}",
        _ms(stats.latency.quantile(0.5)),
        _ms(stats.latency.quantile(0.99)),
        f"{stats.tracks_now}",
        f"{sum(stats.rejected.values())}",
        _mota(mot.mota),
        f"{mot.ids}",
        style="bold",
    )
    note = Text(
        "latency: sensor stamp -> planner; MOTA/IDS: tracks vs the simulator's truth "
        "(same class, centre within 2 m, Hungarian per frame)",
        style="dim",
    )
    if result.view_url:
        view = Text.assemble("browser view: ", (result.view_url, "underline cyan"))
        return Group(header, view, table, note)
    return Group(header, table, note)


def _count(value: float, digits: int = 2) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def comparison_lines(stats: FleetStats) -> list[str]:
    """The tracks next to the raw detections of the same frames (what tracking adds)."""
    rows = (("tracks", stats.mot, True), ("detections alone", stats.baseline_mot, False))
    lines = [
        f"  scoring   {'':18}{'MOTA':>7}{'MOTP m':>8}{'FP':>7}{'FN':>7}{'IDS':>7}{'ids/object':>12}"
    ]
    for name, m, has_ids in rows:
        lines.append(
            f"            {name:18}{_mota(m.mota):>7}{_mota(m.motp):>8}{m.fp:>7}{m.fn:>7}"
            f"{m.ids if has_ids else '-':>7}{_count(m.ids_per_object) if has_ids else '-':>12}"
        )
    lines.append(
        "            detections alone: boxes scoring >= the preset's score_high after NMS, "
        "no ids (a new one every frame), so IDS is not counted"
    )
    return lines


def final_line(result: DemoResult) -> str:
    """The one line to read: frames, latency, MOTA against the baseline, identity."""
    stats = result.stats
    mot, alone = stats.mot, stats.baseline_mot
    return (
        f"tracked {stats.tracked}/{stats.sent} frames · p50 {_ms(stats.latency.quantile(0.5))} ms "
        f"p99 {_ms(stats.latency.quantile(0.99))} ms · MOTA {_count(mot.mota)} (detections alone "
        f"{_count(alone.mota)}) · IDS {mot.ids} · {_count(mot.ids_per_object, 1)} ids per object"
    )


def summary_lines(result: DemoResult, options: DemoOptions) -> list[str]:
    stats: FleetStats = result.stats
    mot = stats.mot
    sim = options.sim
    rejected = stats.rejected
    per_sensor = stats.tracked / max(len(stats.streams), 1) / max(result.elapsed, 1e-9)
    reasons = ", ".join(f"{n} {r}" for r, n in sorted(rejected.items()))
    lines = [
        f"simpletrack demo: {result.stopped_by}: ran {result.elapsed:.1f} s, {sim.vehicles} vehicles "
        f"x {len(sim.sensors)} sensors ({', '.join(s.name for s in sim.sensors)}), seed {sim.seed}, "
        f"service {SERVICE_WORDS[result.service]} on {result.endpoint}",
        f"  frames    {stats.sent} published, {stats.tracked} tracked, "
        f"{sum(rejected.values())} rejected{f' ({reasons})' if reasons else ''}, "
        f"{result.unanswered} unanswered",
        f"  rate      {stats.tracked / max(result.elapsed, 1e-9):.1f} track frames/s "
        f"({per_sensor:.1f} per sensor)",
        f"  latency   p50 {_ms(stats.latency.quantile(0.5))} ms, "
        f"p99 {_ms(stats.latency.quantile(0.99))} ms (sensor stamp -> planner, {stats.latency.n} frames)",
        f"  tracks    {stats.tracks_now} active at the end, {stats.ids_seen} track ids seen",
        f"  MOTA      {_mota(mot.mota)}  IDS {mot.ids}, FP {mot.fp}, FN {mot.fn}, "
        f"TP {mot.tp} of {mot.gt} truth boxes (recall {_mota(mot.recall)}, "
        f"precision {_mota(mot.precision)})",
        *comparison_lines(stats),
        final_line(result),
    ]
    return lines


def summary_json(result: DemoResult, options: DemoOptions) -> dict[str, Any]:
    stats = result.stats
    mot = stats.mot
    alone = stats.baseline_mot

    def num(v: float) -> float | None:
        return None if math.isnan(v) else round(v, 6)

    return {
        "stopped_by": result.stopped_by,
        "elapsed_s": round(result.elapsed, 3),
        "vehicles": options.sim.vehicles,
        "sensors": [s.name for s in options.sim.sensors],
        "seed": options.sim.seed,
        "service": result.service.value,
        "frames": {
            "published": stats.sent,
            "tracked": stats.tracked,
            "rejected": dict(stats.rejected),
            "unanswered": result.unanswered,
        },
        "latency_ms": {
            "p50": num(stats.latency.quantile(0.5) * 1e3),
            "p99": num(stats.latency.quantile(0.99) * 1e3),
        },
        "tracks": {"active": stats.tracks_now, "ids_seen": stats.ids_seen},
        "mot": {
            "mota": num(mot.mota),
            "ids": mot.ids,
            "fp": mot.fp,
            "fn": mot.fn,
            "tp": mot.tp,
            "gt": mot.gt,
            "recall": num(mot.recall),
            "precision": num(mot.precision),
            "motp_m": num(mot.motp),
            "ids_per_object": num(mot.ids_per_object),
        },
        "detections_alone": {
            "mota": num(alone.mota),
            "mota_fresh_ids": num(stats.baseline_fresh_ids.mota),
            "motp_m": num(alone.motp),
            "fp": alone.fp,
            "fn": alone.fn,
            "tp": alone.tp,
            "gt": alone.gt,
        },
        "summary": final_line(result),
        "streams": {
            f"{v}/{s}": {
                "published": st.sent,
                "tracked": st.tracked,
                "rejected": sum(st.rejected.values()),
                "mota": num(st.scorer.counts.mota),
                "ids": st.scorer.counts.ids,
            }
            for (v, s), st in stats.streams.items()
        },
    }
