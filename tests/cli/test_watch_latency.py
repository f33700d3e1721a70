"""``simpletrack watch`` says why a latency cannot be one (a frame stamped after it arrived,
or stamped long before): what a ``--rate max`` replay of a recording shows."""

from __future__ import annotations

import math

import pytest

from simpletrack.cli.watch import format_latency


@pytest.mark.parametrize(
    ("ms", "shown"),
    [
        (None, "-"),
        (math.nan, "-"),
        (0.0, "0.0 ms"),
        (12.34, "12.3 ms"),
        (250.4, "250 ms"),
        (59_999.0, "59999 ms"),
    ],
)
def test_plausible_latencies_are_shown_plain(ms: float | None, shown: str) -> None:
    assert format_latency(ms) == shown


def test_a_negative_latency_says_the_stamp_is_ahead() -> None:
    assert format_latency(-7505.2) == (
        "-7505 ms (stamp ahead of receive time: clock offset or replay)"
    )
    assert format_latency(-0.4) == "-0.4 ms (stamp ahead of receive time: clock offset or replay)"


def test_a_latency_over_a_minute_says_the_stamp_is_on_another_clock() -> None:
    # A KITTI recording's stamps replayed years later.
    years = 9 * 365 * 86400 * 1e3
    assert format_latency(years) == (
        f"{years / 1e3:.0f} s (stamp far behind receive time: clock offset or an old "
        "recording's stamps)"
    )
    assert format_latency(61_000.0).startswith("61000 ms (stamp far behind")
