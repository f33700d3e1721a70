"""The CPUs this process may use: its affinity mask, capped by its cgroup's CPU quota (what a
container's ``cpus:`` or a pod's ``limits.cpu`` sets). ``os.cpu_count()`` sees neither.

Both cgroup versions are read, v2 ``cpu.max`` and v1 ``cpu.cfs_quota_us``/``cpu.cfs_period_us``
(a hybrid host has both hierarchies mounted), from the process's own cgroup up to the
hierarchy's root: a parent's quota binds its children too, so the smallest one counts. A file
that is missing, unreadable or malformed is no limit: the worst case is the affinity count, as
if there were no cgroup at all, never a failed start.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

# Where the hierarchies are when /proc/self/mountinfo cannot be read.
DEFAULT_V2_MOUNT = "/sys/fs/cgroup"
DEFAULT_V1_MOUNT = "/sys/fs/cgroup/cpu"
V1_DEFAULT_PERIOD_US = 100_000


@dataclass(frozen=True, slots=True)
class HostCpus:
    affinity: int  # CPUs in this process's affinity mask (taskset, cpuset, a pod's CPU manager)
    quota: float | None  # CPUs' worth of time the cgroup quota allows per period; None: no quota

    @property
    def usable(self) -> int:
        """The affinity count capped by the quota rounded up. Up, not down: the quota is CPU
        time per period, not a number of CPUs, and a 1.5-CPU quota lets 2 threads run (each
        part of the time), where rounding down would leave the 0.5 paid for unused (the JVM
        and .NET round up too). The price: under full load a group with more threads than
        quota spends it early in each 100 ms period and waits out the rest (CFS throttling);
        a whole-CPU limit, as docs/DEPLOY.md recommends, has no fraction to round."""
        if self.quota is None:
            return self.affinity
        return max(1, min(self.affinity, math.ceil(self.quota)))

    def describe(self) -> str:
        quota = "none" if self.quota is None else f"{self.quota:g}"
        return f"{_cpus(self.usable)} (affinity {self.affinity}, cgroup quota {quota})"


def _cpus(n: int) -> str:
    return f"{n} CPU" if n == 1 else f"{n} CPUs"


def affinity_count() -> int:
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1  # no affinity masks (macOS)


def host_cpus(root: Path = Path("/"), affinity: int | None = None) -> HostCpus:
    """This process's CPUs; ``root`` is where ``/proc`` and ``/sys`` are (a test's fake tree),
    ``affinity`` the mask's size when not this process's own."""
    return HostCpus(affinity_count() if affinity is None else affinity, cgroup_quota(root))


def cgroup_quota(root: Path) -> float | None:
    """The smallest CPU quota on the way from this process's cgroups to their roots, in CPUs."""
    quotas = [q for d in _v2_dirs(root) if (q := _v2_quota(d)) is not None]
    quotas += [q for d in _v1_dirs(root) if (q := _v1_quota(d)) is not None]
    return min(quotas, default=None)


# ----------------------------------------------------------------------------- the files
def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None


def _v2_quota(directory: Path) -> float | None:
    """``cpu.max``: ``$MAX $PERIOD``, MAX ``max`` for no limit ("200000 100000": 2 CPUs)."""
    text = _read(directory / "cpu.max")
    if text is None:
        return None
    words = text.split()
    if not words or words[0] == "max":
        return None
    return _ratio(words[0], words[1] if len(words) > 1 else str(V1_DEFAULT_PERIOD_US))


def _v1_quota(directory: Path) -> float | None:
    """``cpu.cfs_quota_us`` over ``cpu.cfs_period_us``; a quota of -1 is none."""
    quota = _read(directory / "cpu.cfs_quota_us")
    if quota is None or quota == "-1":
        return None
    return _ratio(quota, _read(directory / "cpu.cfs_period_us") or str(V1_DEFAULT_PERIOD_US))


def _ratio(quota: str, period: str) -> float | None:
    try:
        q, p = int(quota), int(period)
    except ValueError:
        return None
    return q / p if q > 0 and p > 0 else None


# ----------------------------------------------------------------------------- the directories
def _cgroups(root: Path) -> dict[str, str]:
    """``/proc/self/cgroup``: hierarchy -> path; ``""`` is v2 (``0::/path``), v1 lines are keyed
    by their controllers (``4:cpu,cpuacct:/docker/abc``)."""
    out: dict[str, str] = {}
    for line in (_read(root / "proc/self/cgroup") or "").splitlines():
        parts = line.split(":", 2)
        if len(parts) == 3 and parts[2].startswith("/"):
            out[parts[1]] = parts[2]
    return out


@dataclass(frozen=True, slots=True)
class _Mount:
    point: str  # where it is mounted
    base: str  # the cgroup shown at that point ("/" but in a container without a namespace)
    fstype: str
    options: frozenset[str]


def _mounts(root: Path) -> list[_Mount] | None:
    """The cgroup mounts of ``/proc/self/mountinfo`` (None: no such file)."""
    text = _read(root / "proc/self/mountinfo")
    if text is None:
        return None
    out = []
    for line in text.splitlines():
        fields = line.split()
        if "-" not in fields[6:]:  # optional fields from the 7th, then "-"
            continue
        tail = fields[fields.index("-", 6) + 1 :]
        if len(tail) >= 3 and tail[0] in ("cgroup", "cgroup2"):
            out.append(_Mount(fields[4], fields[3], tail[0], frozenset(tail[2].split(","))))
    return out


def _walk(root: Path, mount: str, base: str, path: str) -> Iterator[Path]:
    """The directories from the cgroup ``path`` up to the mount point. The path is the one the
    kernel shows, relative to the hierarchy's root; under a mount of a sub-tree (``base``) it
    is made relative to that. A directory that is not there (a container without a cgroup
    namespace sees the host's path but has its own cgroup mounted) yields missing files, and
    the walk up still reaches the mount point, that container's own cgroup."""
    rel = PurePosixPath(path)
    if base != "/" and rel.is_relative_to(base):
        rel = rel.relative_to(base)
    top = root / mount.lstrip("/")
    parts = [p for p in rel.parts if p != "/"]
    for i in range(len(parts), -1, -1):
        yield top.joinpath(*parts[:i])


def _v2_dirs(root: Path) -> Iterator[Path]:
    path = _cgroups(root).get("")
    if path is None:
        return
    mounts = _mounts(root)
    found = [(m.point, m.base) for m in mounts or [] if m.fstype == "cgroup2"]
    for point, base in found if mounts is not None else [(DEFAULT_V2_MOUNT, "/")]:
        yield from _walk(root, point, base, path)


def _v1_dirs(root: Path) -> Iterator[Path]:
    path = next((p for c, p in _cgroups(root).items() if "cpu" in c.split(",")), None)
    if path is None:
        return
    mounts = _mounts(root)
    found = [(m.point, m.base) for m in mounts or [] if m.fstype == "cgroup" and "cpu" in m.options]
    for point, base in found if mounts is not None else [(DEFAULT_V1_MOUNT, "/")]:
        yield from _walk(root, point, base, path)


__all__ = ["HostCpus", "affinity_count", "cgroup_quota", "host_cpus"]
