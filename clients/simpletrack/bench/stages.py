"""Time per tracker stage without touching the core: timing shims around the functions that
``Tracker.step`` calls, installed in the benchmark process only and removed on exit.

    with StageTimer() as timer:
        tracker.step(frame)
    timer.seconds["cost_matrix"], timer.calls["assignment"]

Each shim replaces a module or class attribute that the tracker looks up at call time
(``simpletrack.core.tracker.nms``, ``simpletrack.core.geometry.distance_matrix``, ...). Time is
exclusive: a shimmed function called inside another is charged to itself only. A target the
core no longer has is listed in ``missing`` rather than failing, so a refactor of the core
shows up as an empty stage, never as a broken benchmark.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any

# (stage, module, attribute path inside the module). Order = the order a frame goes through.
TARGETS: tuple[tuple[str, str, str], ...] = (
    ("nms", "simpletrack.core.tracker", "nms"),
    ("predict", "simpletrack.core.tracker", "Tracker._predict"),
    ("cost_matrix", "simpletrack.core.geometry", "distance_matrix"),
    ("cost_matrix", "simpletrack.core.geometry", "distance_pairs"),
    ("cost_matrix", "simpletrack.core.tracker", "Tracker._pair_distances"),
    ("assignment", "simpletrack.core.tracker", "assign"),
    ("update", "simpletrack.core.motion", "KalmanFilter.update"),
    ("update", "simpletrack.core.motion", "ConstantVelocity.update"),
    ("lifecycle", "simpletrack.core.tracker", "Tracker._transition"),
    ("lifecycle", "simpletrack.core.tracker", "Tracker._births"),
    ("output", "simpletrack.core.tracker", "Tracker._output"),
)
STAGES: tuple[str, ...] = tuple(dict.fromkeys(stage for stage, _, _ in TARGETS))
OTHER = "other"  # step time outside every shimmed function: glue, copies, masks


@dataclass
class _Patch:
    owner: Any
    name: str
    original: Any


class StageTimer:
    """Context manager that times the tracker's stages while it is active."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        self.calls: dict[str, int] = dict.fromkeys(STAGES, 0)
        self.missing: list[str] = []
        self._patches: list[_Patch] = []
        self._child = [0]  # ns spent in nested shims, per open level

    def reset(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)
        self.calls = dict.fromkeys(STAGES, 0)

    def _shim(self, stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        child = self._child
        clock = time.perf_counter_ns

        def timed(*args: Any, **kwargs: Any) -> Any:
            child.append(0)
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                total = clock() - t0
                inner = child.pop()
                child[-1] += total
                self.seconds[stage] += (total - inner) * 1e-9
                self.calls[stage] += 1

        timed.__wrapped__ = fn  # type: ignore[attr-defined]
        return timed

    def __enter__(self) -> StageTimer:
        for stage, module_name, path in TARGETS:
            owner: Any = importlib.import_module(module_name)
            *parents, name = path.split(".")
            try:
                for part in parents:
                    owner = getattr(owner, part)
                original = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
            except (AttributeError, KeyError):
                self.missing.append(f"{module_name}.{path}")
                continue
            if isinstance(original, staticmethod | classmethod):
                self.missing.append(f"{module_name}.{path} (not a plain function)")
                continue
            setattr(owner, name, self._shim(stage, original))
            self._patches.append(_Patch(owner, name, original))
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for p in reversed(self._patches):
            setattr(p.owner, p.name, p.original)
        self._patches.clear()
