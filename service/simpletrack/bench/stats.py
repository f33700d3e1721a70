"""Summaries shared by the benchmarks: latency percentiles, CDF samples, power-law fits,
the facts about the machine that a figure must be quoted with, and a process's memory."""

from __future__ import annotations

import importlib.metadata
import os
import platform
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
CDF_POINTS = 200  # quantiles kept per latency distribution in the JSON output


def summary_ms(seconds: npt.ArrayLike) -> dict[str, float | int | None]:
    """count, mean, p50, p90, p99, max of durations given in seconds, in milliseconds."""
    v = np.asarray(seconds, dtype=np.float64).reshape(-1)
    if v.size == 0:
        return {
            "count": 0,
            "mean_ms": None,
            "p50_ms": None,
            "p90_ms": None,
            "p99_ms": None,
            "max_ms": None,
        }
    p50, p90, p99 = np.percentile(v, [50, 90, 99])
    return {
        "count": int(v.size),
        "mean_ms": round(float(v.mean()) * 1e3, 4),
        "p50_ms": round(float(p50) * 1e3, 4),
        "p90_ms": round(float(p90) * 1e3, 4),
        "p99_ms": round(float(p99) * 1e3, 4),
        "max_ms": round(float(v.max()) * 1e3, 4),
    }


def cdf_ms(seconds: npt.ArrayLike, points: int = CDF_POINTS) -> dict[str, list[float]]:
    """An empirical CDF thinned to ``points`` quantiles (enough to redraw it)."""
    v = np.sort(np.asarray(seconds, dtype=np.float64).reshape(-1))
    if v.size == 0:
        return {"ms": [], "fraction": []}
    q = np.linspace(0.0, 1.0, min(points, v.size))
    return {
        "ms": [round(float(x) * 1e3, 4) for x in np.quantile(v, q)],
        "fraction": [round(float(x), 5) for x in q],
    }


def power_law(x: Sequence[float], y: Sequence[float]) -> tuple[float, float]:
    """Least-squares fit of ``y = c * x**k`` in log-log space: returns ``(k, c)``."""
    lx, ly = np.log(np.asarray(x, np.float64)), np.log(np.asarray(y, np.float64))
    if lx.size < 2:
        return float("nan"), float("nan")
    k, logc = np.polyfit(lx, ly, 1)
    return float(k), float(np.exp(logc))


def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def status_mb(pid: int, field: str) -> float | None:
    """A memory field of ``/proc/<pid>/status`` in MB (``VmRSS``: resident now, ``VmHWM``:
    its peak); None once the process is gone or the field is absent."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def machine() -> dict[str, Any]:
    """What a reader needs to weigh the figures: cores, load, versions, when."""
    return {
        "cpus": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": _version("scipy"),
        "eclipse_zenoh": _version("eclipse-zenoh"),
        "unix_time": round(time.time(), 1),
    }


def fmt(value: float | int | None, digits: int = 2) -> str:
    """A table cell: '-' for a missing figure."""
    if value is None:
        return "-"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain aligned text table (pipes and redirects stay readable)."""
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(headers)
    ]
    lines = ["  ".join(h.rjust(w) for h, w in zip(headers, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(lines)
