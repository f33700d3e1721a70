"""The simulator's base tick: the one step of simulated time every sensor's period is a whole
number of.

Sensors run at their own rates (a 10 Hz lidar, a 15 Hz camera); the world advances on the
least common multiple of the rates (30 Hz there), and a sensor produces a frame every
``every[name]`` ticks (3 and 2). Rates are floats from a config: each is read as the nearest
fraction with a denominator up to a million, and the tick is accepted only when every sensor's
period is a whole number of ticks to 1e-9 s and the tick is at least 1 ms (a finer one would
be thousands of world steps a second, and is nearly always a typo such as 15.3 for 15 Hz).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from fractions import Fraction

MIN_TICK_S = 1e-3
PERIOD_TOLERANCE_S = 1e-9
_MAX_DENOMINATOR = 1_000_000


@dataclass(frozen=True, slots=True)
class BaseTick:
    """``hz``: ticks per second; ``every``: per sensor name, ticks between its frames."""

    hz: float
    every: dict[str, int]

    @property
    def dt(self) -> float:
        return 1.0 / self.hz


def _lcm(a: Fraction, b: Fraction) -> Fraction:
    # lcm(p/q, r/s) = lcm(p, r) / gcd(q, s) for fractions in lowest terms.
    return Fraction(math.lcm(a.numerator, b.numerator), math.gcd(a.denominator, b.denominator))


def base_tick(rates: Mapping[str, float]) -> BaseTick:
    """The base tick of sensors with these rates (Hz, by sensor name).

    Raises ValueError naming the rates when their common tick is finer than 1 ms or a
    sensor's period is not a whole number of ticks to 1e-9 s."""
    if not rates:
        raise ValueError("no sensor rates to find a common tick for")
    named = ", ".join(f"{name} {rate:.10g} Hz" for name, rate in rates.items())
    exact = {
        name: Fraction(rate).limit_denominator(_MAX_DENOMINATOR) for name, rate in rates.items()
    }
    if any(f <= 0 for f in exact.values()):
        raise ValueError(f"sensor rates must be positive, got {named}")
    lcm = Fraction(0)
    for f in exact.values():
        lcm = f if lcm == 0 else _lcm(lcm, f)
    if lcm > 1.0 / MIN_TICK_S:
        raise ValueError(
            f"sensor rates {named} have no common tick of 1 ms or more: every period must be a "
            f"whole number of ticks, and the least common multiple of these rates is "
            f"{float(lcm):.6g} Hz (a {1e3 / float(lcm):.3g} ms tick)"
        )
    # The exact float of a sensor running at the base rate, so that a fleet at one rate steps
    # by 1.0 / rate_hz, as it did before sensors had rates of their own.
    hz = next((float(rates[n]) for n, f in exact.items() if f == lcm), float(lcm))
    every = {name: int(lcm / f) for name, f in exact.items()}
    for name, rate in rates.items():
        error = abs(1.0 / rate - every[name] / hz)
        if error > PERIOD_TOLERANCE_S:
            raise ValueError(
                f"sensor rates {named}: the period of {name} ({1.0 / rate:.12g} s) is not a "
                f"whole number of {1.0 / hz:.6g} s ticks to {PERIOD_TOLERANCE_S:g} s "
                f"(off by {error:.3g} s)"
            )
    return BaseTick(hz=hz, every=every)
