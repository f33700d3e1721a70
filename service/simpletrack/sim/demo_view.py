"""What the demo shows: a live rich table while it runs, and a plain summary at the end."""

from __future__ import annotations

import math
import time
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text

from simpletrack.eval.clear_mot import MotCounts
from simpletrack.sim.demo import DemoOptions, DemoResult, ServiceMode
from simpletrack.sim.demo_stats import FleetStats, StreamStats, recent_quantile
from simpletrack.sim.vehicle_score import DETECTIONS, FUSED, TOGETHER

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
        mot = _stream_counts(stats, st)
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
    mot = stats.scores.counts(FUSED)
    table.add_section()
    table.add_row(
        "fleet",
        "fused",
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
        "latency: sensor stamp -> planner; MOTA/IDS: each stream against its vehicle's truth "
        "(every object in view of any of its sensors; same class, centre within 2 m, "
        "Hungarian per frame; at the stamps where every sensor has a frame)",
        style="dim",
    )
    if result.view_url:
        view = Text.assemble("browser view: ", (result.view_url, "underline cyan"))
        return Group(header, view, table, note)
    return Group(header, table, note)


def _count(value: float, digits: int = 2) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def _stream_counts(stats: FleetStats, st: StreamStats) -> MotCounts:
    """A stream's row of its vehicle (fused, or that sensor's own tracks)."""
    vehicle = stats.scores.vehicles.get(st.vehicle)
    if vehicle is None:
        return MotCounts()
    return vehicle.counts(FUSED if st.fused else st.sensor)


ROW_NAMES = {
    FUSED: "fused tracks",
    TOGETHER: "per-sensor together",
    DETECTIONS: "detections alone",
}


def comparison_lines(stats: FleetStats) -> list[str]:
    """Every row against the vehicles' truth, on the same frames (sim/vehicle_score.py)."""
    scores = stats.scores
    lines = [
        f"  scoring   {'':22}{'MOTA':>7}{'MOTP m':>8}{'FP':>7}{'FN':>7}{'IDS':>7}"
        f"{'ids/object':>12}{'doubled':>9}"
    ]
    for row in scores.rows:
        m = scores.counts(row)
        has_ids = row != DETECTIONS
        name = ROW_NAMES.get(row, f"{row} alone")
        lines.append(
            f"            {name:22}{_mota(m.mota):>7}{_mota(m.motp):>8}{m.fp:>7}{m.fn:>7}"
            f"{m.ids if has_ids else '-':>7}{_count(m.ids_per_object) if has_ids else '-':>12}"
            f"{_pct(m.doubled_share) if has_ids else '-':>9}"
        )
    lines.append(
        "            truth: every object in view of any of the vehicle's sensors; per-sensor "
        "together: each sensor's tracks, ids kept apart by sensor; detections alone: boxes "
        ">= the preset's score_high after NMS, no ids; doubled: matched truth boxes with a "
        "second track of theirs within 2 m"
    )
    calibration = scores.calibration()
    if calibration:
        cells = ", ".join(f"{lo:.1f}+: {share:.2f} ({n})" for lo, n, share in calibration)
        lines.append(
            f"  existence share of fused tracks that are real, by reported existence: {cells}"
        )
    return lines


def _pct(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.1%}"


def final_line(result: DemoResult) -> str:
    """The one line to read: frames, latency, the fused tracks against the per-sensor ones."""
    stats = result.stats
    scores = stats.scores
    fused, together = scores.counts(FUSED), scores.counts(TOGETHER)
    singles = " ".join(f"{s} {_count(scores.counts(s).mota)}" for s in scores.sensors)
    return (
        f"tracked {stats.tracked}/{stats.sent} frames · fused p50 "
        f"{_ms(stats.fused_latency.quantile(0.5))} ms p99 {_ms(stats.fused_latency.quantile(0.99))} ms "
        f"· MOTA fused {_count(fused.mota)} (per-sensor together {_count(together.mota)}, "
        f"{singles}, detections {_count(scores.counts(DETECTIONS).mota)}) · "
        f"{_count(fused.ids_per_object)} ids per object (together "
        f"{_count(together.ids_per_object)})"
    )


def summary_lines(result: DemoResult, options: DemoOptions) -> list[str]:
    stats: FleetStats = result.stats
    mot = stats.scores.counts(FUSED)
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
        f"  latency   fused p50 {_ms(stats.fused_latency.quantile(0.5))} ms, "
        f"p99 {_ms(stats.fused_latency.quantile(0.99))} ms ({stats.fused_latency.n} messages); "
        f"per sensor p50 {_ms(stats.latency.quantile(0.5))} ms, "
        f"p99 {_ms(stats.latency.quantile(0.99))} ms ({stats.latency.n} frames; sensor stamp "
        f"-> planner)",
        f"  tracks    {stats.tracks_now} fused tracks active at the end, {stats.ids_seen} fused "
        f"track ids seen, {stats.fused_messages} fused messages",
        f"  MOTA      fused {_mota(mot.mota)}  IDS {mot.ids}, FP {mot.fp}, FN {mot.fn}, "
        f"TP {mot.tp} of {mot.gt} truth boxes (recall {_mota(mot.recall)}, "
        f"precision {_mota(mot.precision)}), {mot.frames // max(len(stats.scores.vehicles), 1)} "
        f"scoring stamps per vehicle",
        *comparison_lines(stats),
        final_line(result),
    ]
    return lines


def summary_json(result: DemoResult, options: DemoOptions) -> dict[str, Any]:
    stats = result.stats
    scores = stats.scores

    def num(v: float) -> float | None:
        return None if math.isnan(v) else round(v, 6)

    def row(m: MotCounts) -> dict[str, Any]:
        return {
            "mota": num(m.mota),
            "motp_m": num(m.motp),
            "ids": m.ids,
            "fp": m.fp,
            "fn": m.fn,
            "tp": m.tp,
            "gt": m.gt,
            "recall": num(m.recall),
            "precision": num(m.precision),
            "ids_per_object": num(m.ids_per_object),
            "doubled_share": num(m.doubled_share),
            "frames": m.frames,
        }

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
            "fused_messages": stats.fused_messages,
            "rejected": dict(stats.rejected),
            "unanswered": result.unanswered,
        },
        "latency_ms": {
            "p50": num(stats.latency.quantile(0.5) * 1e3),
            "p99": num(stats.latency.quantile(0.99) * 1e3),
            "fused_p50": num(stats.fused_latency.quantile(0.5) * 1e3),
            "fused_p99": num(stats.fused_latency.quantile(0.99) * 1e3),
        },
        "tracks": {"active": stats.tracks_now, "ids_seen": stats.ids_seen},
        "rows": {name: row(scores.counts(name)) for name in scores.rows},
        "existence_calibration": [
            {"from": lo, "tracks": n, "real": round(share, 4)}
            for lo, n, share in scores.calibration()
        ],
        "summary": final_line(result),
        "streams": {
            f"{v}/{s}": {
                "published": st.sent,
                "tracked": st.tracked,
                "rejected": sum(st.rejected.values()),
                "mota": num(_stream_counts(stats, st).mota),
                "ids": _stream_counts(stats, st).ids,
            }
            for (v, s), st in stats.streams.items()
            if not st.fused
        },
        "fused_streams": {
            f"{v}/@vehicle": {
                "messages": st.tracked,
                "mota": num(_stream_counts(stats, st).mota),
                "ids": _stream_counts(stats, st).ids,
            }
            for (v, _), st in stats.streams.items()
            if st.fused
        },
    }
