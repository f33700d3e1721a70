"""scipy's assignment solvers, imported on first use: ``scipy.optimize`` alone costs ~0.25 s
of start-up, which every ``simpletrack`` command paid though greedy matching (the nuscenes
preset) never calls it. ``preload()`` pays it up front, for a service whose first frame
must not."""

from __future__ import annotations

from typing import Any


def linear_sum_assignment(cost: Any, maximize: bool = False) -> Any:
    from scipy.optimize import linear_sum_assignment as solve

    return solve(cost, maximize=maximize)


def min_weight_full_bipartite_matching(graph: Any) -> Any:
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching as solve

    return solve(graph)


def preload() -> None:
    """Import both solvers now."""
    import scipy.optimize
    import scipy.sparse.csgraph  # noqa: F401
