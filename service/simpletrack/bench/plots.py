"""PNG figures of the benchmark results (matplotlib, no display needed).

Every function takes the JSON-able result dict the benchmark wrote, so figures can be redrawn
from a saved ``--json`` file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from simpletrack.bench.stages import OTHER, STAGES

STAGE_COLOURS = {
    "nms": "tab:blue",
    "step": "tab:purple",
    "predict": "tab:cyan",
    "cost_matrix": "tab:red",
    "assignment": "tab:orange",
    "advance": "tab:green",
    OTHER: "tab:gray",
}


def _figure(width: float, height: float) -> Any:
    # The Agg canvas directly: no pyplot state, safe in threads and without a display.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def core_scaling(sweep: dict[str, Any], path: Path) -> Path:
    """Per-frame time against boxes per frame, log-log, with the fitted power law and the time
    per stage (which one grows fastest is what limits the tracker at scale)."""
    pts = sweep["points"]
    boxes = [p["boxes"] for p in pts]
    p50 = [p["latency"]["p50_ms"] for p in pts]
    p99 = [p["latency"]["p99_ms"] for p in pts]
    fig = _figure(9.0, 5.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(boxes, p50, "o-", color="black", lw=2, label="per frame, median")
    ax.plot(boxes, p99, "v:", color="black", lw=1, label="per frame, p99")
    k, c = sweep["exponent"], sweep["coefficient_ms"]
    lo, hi = min(boxes), max(boxes)
    ax.plot(
        [lo, hi],
        [c * lo**k, c * hi**k],
        "--",
        color="black",
        alpha=0.5,
        label=f"fit: time ∝ boxes^{k:.2f}",
    )
    kt, ct = sweep.get("exponent_from_100"), sweep.get("coefficient_from_100_ms")
    if kt is not None and ct is not None:
        tail = [b for b in boxes if b >= 100]
        ax.plot(
            [min(tail), hi],
            [ct * min(tail) ** kt, ct * hi**kt],
            "-.",
            color="red",
            alpha=0.5,
            label=f"fit from 100 boxes: ∝ boxes^{kt:.2f}",
        )
    for stage in (*STAGES, OTHER):
        ms = [p["stages"]["ms_per_frame"].get(stage, 0.0) for p in pts]
        if max(ms) > 0:
            ax.plot(
                boxes,
                [max(v, 1e-4) for v in ms],
                ".-",
                lw=1,
                color=STAGE_COLOURS.get(stage),
                label=stage,
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("boxes per frame (= live tracks), one class")
    ax.set_ylabel("ms per frame")
    extra = f", from 100 boxes: {kt:.2f}" if kt is not None else ""
    ax.set_title(f"Tracker step vs load: growth exponent {k:.2f}{extra}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path)
    return path


def core_stages(loads: dict[str, Any], path: Path) -> Path:
    """Milliseconds per frame in each stage, one bar per load."""
    names = list(loads)
    fig = _figure(7.5, 1.8 + 0.7 * max(len(names), 1))
    ax = fig.add_subplot(1, 1, 1)
    left = [0.0] * len(names)
    for stage in (*STAGES, OTHER):
        ms = [loads[n]["stages"]["ms_per_frame"].get(stage, 0.0) for n in names]
        ax.barh(names, ms, left=left, color=STAGE_COLOURS.get(stage), label=stage)
        left = [a + b for a, b in zip(left, ms, strict=True)]
    ax.set_xlabel("ms per frame (shimmed pass)")
    ax.set_title("Where a tracker step goes")
    ax.legend(fontsize=7, ncol=8, loc="upper center", bbox_to_anchor=(0.5, -0.3))
    fig.tight_layout()
    fig.savefig(path)
    return path


def service_cdf(steps: list[dict[str, Any]], path: Path) -> Path:
    """Latency CDF per sensor count: tracker solid, Zenoh echo floor dashed."""
    fig = _figure(7.5, 5.0)
    ax = fig.add_subplot(1, 1, 1)
    colours = [
        "tab:blue",
        "tab:orange",
        "tab:green",
        "tab:red",
        "tab:purple",
        "tab:brown",
        "tab:pink",
        "tab:gray",
    ]
    sensors = sorted({s["sensors"] for s in steps})
    for i, n in enumerate(sensors):
        colour = colours[i % len(colours)]
        for s in steps:
            if s["sensors"] != n or not s["cdf"]["ms"]:
                continue
            style = "-" if s["kind"] == "tracker" else "--"
            label = f"{n} sensors, {'service' if s['kind'] == 'tracker' else 'echo'}"
            ax.plot(s["cdf"]["ms"], s["cdf"]["fraction"], style, color=colour, label=label)
    ax.axvline(50.0, color="black", lw=0.8, alpha=0.5)
    ax.set_xscale("log")
    ax.set_xlabel("end-to-end latency, put → tracks received (ms)")
    ax.set_ylabel("fraction of frames")
    ax.set_title("Latency CDF at 10 Hz per sensor (dashed: Zenoh echo floor)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    return path


def service_capacity(steps: list[dict[str, Any]], path: Path) -> Path:
    """Frames delivered per second and p99 latency against sensor count."""
    fig = _figure(10.0, 4.2)
    ax1 = fig.add_subplot(1, 2, 1)
    ax2 = fig.add_subplot(1, 2, 2)
    for kind, style in (("tracker", "o-"), ("echo", "s--")):
        sel = sorted((s for s in steps if s["kind"] == kind), key=lambda s: s["sensors"])
        if not sel:
            continue
        label = "service" if kind == "tracker" else "Zenoh echo"
        x = [s["sensors"] for s in sel]
        ax1.plot(x, [s["delivered_per_s"] for s in sel], style, label=label)
        ax2.plot(x, [s["latency"]["p99_ms"] or float("nan") for s in sel], style, label=label)
    top = max((s["sensors"] for s in steps), default=1)
    ax1.plot([1, top], [10, 10 * top], ":", color="gray", label="offered (10 Hz x sensors)")
    for ax in (ax1, ax2):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("sensors at 10 Hz")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    ax1.set_ylabel("track frames received per second")
    ax2.set_ylabel("p99 latency (ms)")
    ax2.axhline(50.0, color="red", lw=0.8, alpha=0.6)
    ax1.set_title("Throughput")
    ax2.set_title("p99 latency (red: 50 ms)")
    fig.tight_layout()
    fig.savefig(path)
    return path


def scale_capacity(rows: list[dict[str, Any]], path: Path) -> Path:
    """Capacity (sensors within the p99 limit) against group members, with the linear ideal
    from one member, and the failover/hand-off times beside it."""
    fig = _figure(10.0, 4.2)
    ax1 = fig.add_subplot(1, 2, 1)
    ax2 = fig.add_subplot(1, 2, 2)
    members = [r["members"] for r in rows]
    cap = [r["capacity"]["max_sensors_passing"] for r in rows]
    ax1.plot(members, [c if c is not None else 0 for c in cap], "o-", label="measured")
    one = next((c for m, c in zip(members, cap, strict=True) if m == 1), None)
    if one:
        ax1.plot(members, [one * m for m in members], ":", color="gray", label="linear from 1")
    for m, c in zip(members, cap, strict=True):
        ax1.annotate(
            "none" if c is None else str(c),
            (m, c or 0),
            textcoords="offset points",
            xytext=(0, 6),
            ha="center",
            fontsize=8,
        )
    ax1.set_xlabel("group members (processes)")
    ax1.set_ylabel("sensors at 10 Hz with p99 under the limit")
    ax1.set_xticks(members)
    ax1.set_ylim(bottom=0)
    ax1.set_title("Capacity against members")
    for fault, style in (("failover", "o-"), ("handoff", "s--")):
        sel = [r for r in rows if r.get(fault) and r[fault]["max_ms"] is not None]
        if sel:
            x = [r["members"] for r in sel]
            ax2.plot(x, [r[fault]["max_ms"] for r in sel], style, label=f"{fault}, max")
            ax2.plot(
                x, [r[fault]["median_ms"] for r in sel], style, alpha=0.5, label=f"{fault}, median"
            )
    ax2.set_xlabel("group members (processes)")
    ax2.set_ylabel("fault → another member's tracks (ms)")
    ax2.set_xticks(members)
    ax2.set_ylim(bottom=0)
    ax2.set_title("What losing a member costs its sensors")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    return path
