"""Which sensors each load-generator process holds, and the key expressions that select them.

The sensors of a step are split into contiguous blocks, one per process, so a process can
subscribe to the answers of its own sensors only: a block of sensor numbers is a handful of
decimal prefixes (``s01$*`` is s0100..s0199), and Zenoh routes each track frame to the one
process that published the frame it answers. Pure functions: no Zenoh here.
"""

from __future__ import annotations

DIGITS = 4  # sensor and vehicle numbers are written with four digits (loadgen.sensor_name)


def split_sensors(sensors: int, processes: int) -> list[range]:
    """Sensors 0..sensors-1 as contiguous blocks, one per process, sizes differing by at most
    one; never more blocks than sensors (a process with nothing to publish would only add a
    session)."""
    if sensors < 1 or processes < 1:
        raise ValueError(f"need at least one sensor and one process, not {sensors} and {processes}")
    n = min(processes, sensors)
    return [range(p * sensors // n, (p + 1) * sensors // n) for p in range(n)]


def digit_prefixes(block: range, width: int = DIGITS) -> list[str]:
    """The fewest decimal prefixes whose ``width``-digit completions are exactly ``block``:
    range(0, 300) -> ["00", "01", "02"]; range(7, 30) -> ["0007", "0008", "0009", "001", "002"]
    ("001": 0010..0019). At most 18 per digit, so a few dozen subscribers at worst."""
    if block.step != 1 or block.start < 0 or block.stop > 10**width or not block:
        raise ValueError(f"{block} is not a non-empty block of {width}-digit numbers")
    out = []
    i = block.start
    while i < block.stop:
        size, digits = 1, width
        # The largest power-of-ten block aligned at i that still fits: one prefix covers it.
        while digits > 0 and i % (size * 10) == 0 and i + size * 10 <= block.stop:
            size, digits = size * 10, digits - 1
        out.append(f"{i:0{width}d}"[:digits])
        i += size
    return out


def chunk_patterns(head: str, block: range, width: int = DIGITS) -> list[str]:
    """Key-expression chunks matching the names ``head`` + a number of ``block`` written with
    ``width`` digits: a full number as it is, a shorter prefix followed by Zenoh's ``$*``."""
    return [head + p + ("" if len(p) == width else "$*") for p in digit_prefixes(block, width)]
