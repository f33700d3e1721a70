"""Time per tracker stage without touching the core: timing shims around the functions that
``Tracker.step`` calls, installed in the benchmark process only and removed on exit.

    with StageTimer() as timer:
        tracker.step(frame)
    timer.seconds["cost_matrix"], timer.calls["assignment"]

Each shim replaces a module or class attribute that the tracker looks up at call time
(``simpletrack.core.tracker.nms``, ``simpletrack.core.geometry.distance_pairs``, ...). Time is
exclusive: a shimmed function called inside another is charged to itself only. Every target is
resolved to the function it names when a ``StageTimer`` is made; one the core no longer has
(renamed, removed, made a staticmethod) is a ``MissingStageTarget`` naming the stage and the
target, so a refactor of the core fails the benchmark instead of moving its cost to "other".
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import FunctionType, TracebackType
from typing import Any

# (stage, module, attribute path inside the module). Order = the order a frame goes through.
TARGETS: tuple[tuple[str, str, str], ...] = (
    ("nms", "simpletrack.core.tracker", "nms"),
    # An ordinary frame whole, from its boxes to its tracks: one compiled call
    # (core/step_kernels.py). The stages below are the staged path's, which takes the frames
    # the fused call does not (gated, after a gap, L2 or Mahalanobis classes).
    ("step", "simpletrack.core.tracker", "Tracker._step_frame"),
    ("predict", "simpletrack.core.tracker", "Tracker._predict"),
    ("cost_matrix", "simpletrack.core.tracker", "Tracker._distance_table"),
    ("cost_matrix", "simpletrack.core.geometry", "distance_pairs"),
    # Stage 1 whole: a dense frame's is one compiled call (core/assignment_kernels.py).
    ("assignment", "simpletrack.core.tracker", "Tracker._stage1"),
    # Filter updates, scores, life cycle, births, deaths and output: one compiled call
    # (core/advance_kernels.py).
    ("advance", "simpletrack.core.tracker", "Tracker._advance"),
)
STAGES: tuple[str, ...] = tuple(dict.fromkeys(stage for stage, _, _ in TARGETS))
OTHER = "other"  # step time outside every shimmed function: glue, copies, masks


class MissingStageTarget(LookupError):
    """A stage names a function the core does not have (any more)."""


@dataclass(frozen=True)
class _Target:
    stage: str
    owner: Any  # the module or class whose attribute is replaced
    name: str
    original: Callable[..., Any]


def resolve_targets(targets: Sequence[tuple[str, str, str]] | None = None) -> tuple[_Target, ...]:
    """The functions ``targets`` (default: TARGETS) name, or MissingStageTarget for the first
    that is not one."""
    out = []
    for stage, module_name, path in TARGETS if targets is None else targets:
        where = f"{module_name}.{path}"
        try:
            owner: Any = importlib.import_module(module_name)
        except ImportError:
            raise MissingStageTarget(
                f"stage {stage!r}: no module {module_name} (update {__name__} TARGETS)"
            ) from None
        *parents, name = path.split(".")
        try:
            for part in parents:
                owner = getattr(owner, part)
            original = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        except (AttributeError, KeyError):
            raise MissingStageTarget(
                f"stage {stage!r}: {where} does not exist (renamed or removed? "
                f"update {__name__} TARGETS)"
            ) from None
        # A shim over a staticmethod or a builtin would change how it is called or time nothing.
        if not isinstance(original, FunctionType):
            raise MissingStageTarget(
                f"stage {stage!r}: {where} is not a plain function "
                f"({type(original).__name__}; update {__name__} TARGETS)"
            )
        out.append(_Target(stage, owner, name, original))
    return tuple(out)


class StageTimer:
    """Context manager that times the tracker's stages while it is active."""

    def __init__(self, targets: Sequence[tuple[str, str, str]] | None = None) -> None:
        self._spec = targets
        # Resolved now so that a missing target fails before anything is timed.
        stages = dict.fromkeys(t.stage for t in resolve_targets(targets))
        self.seconds: dict[str, float] = dict.fromkeys(stages, 0.0)
        self.calls: dict[str, int] = dict.fromkeys(stages, 0)
        self._installed: list[_Target] = []
        self._child = [0]  # ns spent in nested shims, per open level

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
        # Resolved again: what the attributes hold now is what __exit__ must put back.
        for t in resolve_targets(self._spec):
            setattr(t.owner, t.name, self._shim(t.stage, t.original))
            self._installed.append(t)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for t in reversed(self._installed):
            setattr(t.owner, t.name, t.original)
        self._installed.clear()
