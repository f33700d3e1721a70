"""``simpletrack serve --processes auto``: the usable CPUs read from fake cgroup v1 and v2 trees
(affinity capped by the smallest quota on the way up; a bad file is no limit, never a crash),
the member count from them and the ``workers`` setting wherever it was set, and a real
process pinned to one CPU running one member."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from simpletrack.cli import processes
from simpletrack.cli.host_cpus import HostCpus, host_cpus
from simpletrack.cli.main import main
from simpletrack.cli.processes import auto_processes, parse_processes
from simpletrack.server import app
from simpletrack.spawn import free_port
from tests.service_helpers import ROOT, ServiceProcess, log_events, wait_for

V2_MOUNT = "41 31 0:38 / /sys/fs/cgroup rw,relatime shared:9 - cgroup2 cgroup2 rw,nsdelegate"
V1_MOUNTS = (
    "32 31 0:29 / /sys/fs/cgroup/cpu,cpuacct rw,relatime shared:10 - cgroup cgroup rw,cpu,cpuacct\n"
    "34 31 0:31 / /sys/fs/cgroup/cpuset rw,relatime shared:11 - cgroup cgroup rw,cpuset\n"
    "41 31 0:38 / /sys/fs/cgroup/unified rw,relatime shared:9 - cgroup2 cgroup2 rw"
)
V1_CGROUP = "5:cpuset:/cpusets/c1\n4:cpu,cpuacct:/pod1/c1\n1:name=systemd:/pod1/c1\n0::/pod1/c1"
V1 = "sys/fs/cgroup/cpu,cpuacct"


def v1(quota: str, period: str = "100000") -> dict[str, str]:
    return {"cpu.cfs_quota_us": quota, "cpu.cfs_period_us": period}


@dataclass(frozen=True)
class Tree:
    """A fake ``/``: /proc/self/cgroup, /proc/self/mountinfo (None: absent) and cgroup files."""

    cgroup: str | None
    mountinfo: str | None
    files: dict[str, dict[str, str]] = field(default_factory=dict)  # directory -> name -> text

    def write(self, root: Path) -> Path:
        (root / "proc/self").mkdir(parents=True)
        if self.cgroup is not None:
            (root / "proc/self/cgroup").write_text(self.cgroup + "\n")
        if self.mountinfo is not None:
            (root / "proc/self/mountinfo").write_text(self.mountinfo + "\n")
        for directory, files in self.files.items():
            (root / directory).mkdir(parents=True, exist_ok=True)
            for name, text in files.items():
                (root / directory / name).write_bytes(text.encode("latin-1") + b"\n")
        return root


LEAF = "sys/fs/cgroup/kubepods/pod1/c1"
POD = "sys/fs/cgroup/kubepods/pod1"
V2 = dict(cgroup="0::/kubepods/pod1/c1", mountinfo=V2_MOUNT)
# (tree, affinity, the quota in CPUs, the usable CPUs)
CASES: dict[str, tuple[Tree, int, float | None, int]] = {
    "v2 no limit": (
        Tree(**V2, files={LEAF: {"cpu.max": "max 100000"}, POD: {"cpu.max": "max 100000"}}),
        16,
        None,
        16,
    ),
    "v2 quota below affinity": (Tree(**V2, files={LEAF: {"cpu.max": "200000 100000"}}), 16, 2, 2),
    "v2 quota above affinity": (Tree(**V2, files={LEAF: {"cpu.max": "3200000 100000"}}), 8, 32, 8),
    "v2 fraction rounds up": (Tree(**V2, files={LEAF: {"cpu.max": "150000 100000"}}), 16, 1.5, 2),
    "v2 half a CPU is one": (Tree(**V2, files={LEAF: {"cpu.max": "50000 100000"}}), 16, 0.5, 1),
    "v2 other period": (Tree(**V2, files={LEAF: {"cpu.max": "150000 50000"}}), 16, 3, 3),
    "v2 nested parent limit binds": (
        Tree(
            **V2,
            files={
                LEAF: {"cpu.max": "800000 100000"},
                POD: {"cpu.max": "400000 100000"},
                "sys/fs/cgroup/kubepods": {"cpu.max": "max 100000"},
            },
        ),
        16,
        4,
        4,
    ),
    "v2 limit above the leaf only": (
        Tree(**V2, files={POD: {"cpu.max": "300000 100000"}}),
        16,
        3,
        3,
    ),
    "v2 malformed leaf, parent counts": (
        Tree(**V2, files={LEAF: {"cpu.max": "lots 100000"}, POD: {"cpu.max": "600000 100000"}}),
        16,
        6,
        6,
    ),
    "v2 malformed is no limit": (
        Tree(**V2, files={LEAF: {"cpu.max": "200000 zero"}}),
        16,
        None,
        16,
    ),
    "v2 zero period is no limit": (Tree(**V2, files={LEAF: {"cpu.max": "200000 0"}}), 16, None, 16),
    "v2 empty file is no limit": (Tree(**V2, files={LEAF: {"cpu.max": ""}}), 16, None, 16),
    "v2 binary file is no limit": (Tree(**V2, files={LEAF: {"cpu.max": "\xff\xfe"}}), 16, None, 16),
    "v2 no cpu.max anywhere": (Tree(**V2, files={LEAF: {}}), 16, None, 16),
    "no /proc/self/cgroup": (
        Tree(None, V2_MOUNT, {LEAF: {"cpu.max": "200000 100000"}}),
        16,
        None,
        16,
    ),
    "garbage /proc/self/cgroup": (
        Tree("no colons here\n::\n7", V2_MOUNT, {LEAF: {"cpu.max": "200000 100000"}}),
        16,
        None,
        16,
    ),
    "garbage mountinfo": (
        Tree("0::/kubepods/pod1/c1", "- -\n1 2 3\n\n", {LEAF: {"cpu.max": "200000 100000"}}),
        16,
        None,
        16,
    ),
    "no mountinfo: the usual mount": (
        Tree("0::/kubepods/pod1/c1", None, {LEAF: {"cpu.max": "200000 100000"}}),
        16,
        2,
        2,
    ),
    # A container without a cgroup namespace sees the host's path; its own cgroup is the mount.
    "v2 host path not in the container": (
        Tree("0::/docker/abc", V2_MOUNT, {"sys/fs/cgroup": {"cpu.max": "200000 100000"}}),
        16,
        2,
        2,
    ),
    # A mount of a sub-tree: the path is relative to the mount's base.
    "v2 mount of a sub-tree": (
        Tree(
            "0::/kubepods/pod1/c1",
            "41 31 0:38 /kubepods/pod1 /sys/fs/cgroup rw - cgroup2 cgroup2 rw",
            {"sys/fs/cgroup/c1": {"cpu.max": "100000 100000"}, LEAF: {"cpu.max": "max 100000"}},
        ),
        16,
        1,
        1,
    ),
    "v1 no limit": (Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": v1("-1")}), 16, None, 16),
    "v1 quota below affinity": (
        Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": v1("200000")}),
        16,
        2,
        2,
    ),
    "v1 quota above affinity": (
        Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": v1("900000")}),
        4,
        9,
        4,
    ),
    "v1 other period, rounds up": (
        Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": v1("125000", "50000")}),
        16,
        2.5,
        3,
    ),
    "v1 nested parent limit binds": (
        Tree(
            V1_CGROUP,
            V1_MOUNTS,
            {f"{V1}/pod1/c1": v1("-1"), f"{V1}/pod1": v1("100000"), V1: v1("-1")},
        ),
        16,
        1,
        1,
    ),
    "v1 malformed is no limit": (
        Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": v1("a lot")}),
        16,
        None,
        16,
    ),
    "v1 missing period: the default": (
        Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": {"cpu.cfs_quota_us": "300000"}}),
        16,
        3,
        3,
    ),
    "v1 missing files": (Tree(V1_CGROUP, V1_MOUNTS, {f"{V1}/pod1/c1": {}}), 16, None, 16),
    # cpuset is not cpu: a quota file under its mount is not read.
    "v1 cpuset is not the cpu controller": (
        Tree(V1_CGROUP, V1_MOUNTS, {"sys/fs/cgroup/cpuset/cpusets/c1": v1("100000")}),
        16,
        None,
        16,
    ),
    "v1 no mountinfo: the usual mount": (
        Tree(V1_CGROUP, None, {"sys/fs/cgroup/cpu/pod1/c1": v1("200000")}),
        16,
        2,
        2,
    ),
    # A hybrid host: v1 and v2 both mounted; the smaller quota binds.
    "hybrid: the smaller of v1 and v2": (
        Tree(
            V1_CGROUP,
            V1_MOUNTS,
            {
                f"{V1}/pod1/c1": v1("300000"),
                "sys/fs/cgroup/unified/pod1/c1": {"cpu.max": "200000 100000"},
            },
        ),
        16,
        2,
        2,
    ),
}


@pytest.mark.parametrize(("tree", "affinity", "quota", "usable"), CASES.values(), ids=CASES.keys())
def test_usable_cpus_are_the_affinity_capped_by_the_smallest_quota(
    tmp_path: Path, tree: Tree, affinity: int, quota: float | None, usable: int
) -> None:
    cpus = host_cpus(tree.write(tmp_path), affinity=affinity)
    assert cpus == HostCpus(affinity, quota)
    assert cpus.usable == usable


def test_an_empty_root_is_the_affinity_alone(tmp_path: Path) -> None:
    assert host_cpus(tmp_path, affinity=3) == HostCpus(3, None)
    assert host_cpus(tmp_path).affinity == len(os.sched_getaffinity(0))


@pytest.mark.parametrize(
    ("cpus", "workers", "n", "reason"),
    [
        (
            HostCpus(16, 16.0),
            2,
            8,
            "16 CPUs (affinity 16, cgroup quota 16) / 2 workers per member = 8 members",
        ),
        (
            HostCpus(16, 4.0),
            2,
            2,
            "4 CPUs (affinity 16, cgroup quota 4) / 2 workers per member = 2 members",
        ),
        (
            HostCpus(8, None),
            3,
            2,
            "8 CPUs (affinity 8, cgroup quota none) / 3 workers per member = 2 members",
        ),
        (
            HostCpus(16, 1.5),
            1,
            2,
            "2 CPUs (affinity 16, cgroup quota 1.5) / 1 worker per member = 2 members",
        ),
        (
            HostCpus(1, None),
            2,
            1,
            "1 CPU (affinity 1, cgroup quota none) / 2 workers per member = 1 member (at least 1)",
        ),
        (
            HostCpus(200, None),
            1,
            64,
            "200 CPUs (affinity 200, cgroup quota none) / 1 worker per member = 200 members, "
            "capped at 64",
        ),
    ],
)
def test_auto_is_usable_cpus_over_workers_at_least_1_at_most_64(
    cpus: HostCpus, workers: int, n: int, reason: str
) -> None:
    assert auto_processes(cpus, workers) == (n, reason)


@pytest.mark.parametrize("text", ["auto", "AUTO", "Auto"])
def test_auto_is_accepted_in_any_case(text: str) -> None:
    assert parse_processes(text) == "auto"
    assert parse_processes("3") == 3


@pytest.mark.parametrize(
    ("where", "workers", "last"),
    [("flag", 1, 7), ("environment", 2, 3), ("file", 4, 1), ("default", None, 3)],
)
def test_auto_divides_by_the_workers_setting_wherever_it_was_set(
    where: str,
    workers: int | None,
    last: int,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # 8 CPUs; the member count N shows in the refusal of metrics ports 65535..65535+N-1,
    # before any child starts. One member would run here: failed at once instead.
    monkeypatch.setattr(processes, "host_cpus", lambda: HostCpus(8, None))
    monkeypatch.setattr(app, "run", lambda _settings: pytest.fail("ran one member"))
    monkeypatch.delenv("SIMPLETRACK_WORKERS", raising=False)
    argv = ["serve", "--processes", "auto", "--metrics-port", "65535"]
    if where == "flag":
        argv += ["--workers", str(workers)]
    elif where == "environment":
        monkeypatch.setenv("SIMPLETRACK_WORKERS", str(workers))
    elif where == "file":
        (tmp_path / "s.toml").write_text(f"workers = {workers}\n")
        argv += ["--config", str(tmp_path / "s.toml")]
    with log_events("simpletrack.supervisor") as events:
        assert main(argv) == 2
    assert f"--metrics-port 65535 + {last} is past port 65535" in capsys.readouterr().err
    [event] = events.named("processes_auto")
    assert event["processes"] == last + 1 and event["workers"] == (workers or 2)
    assert event["reason"].endswith(f"= {last + 1} members")


def _start_pinned(tmp: Path, cpus: set[int], *args: str) -> ServiceProcess:
    """``simpletrack serve --processes auto`` on ``cpus`` only (``taskset -c``)."""
    port, metrics_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log_path = tmp / f"auto-{port}.log"
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "serve", "--processes", "auto"]
    cmd += ["--listen", endpoint, "--instance", "auto", "--workers", "1", *args]
    if "--metrics-port" not in args:
        cmd += ["--metrics-port", str(metrics_port)]
    env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "NO_COLOR": "1"}
    env.pop("SIMPLETRACK_WORKERS", None)
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            cmd,
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=log,
            preexec_fn=lambda: os.sched_setaffinity(0, cpus),
        )
    return ServiceProcess(proc, endpoint, metrics_port, log_path, "auto")


def _two_cpus() -> list[int]:
    """Two CPUs of this process's, or a skip: with one, a count that ignored the affinity
    would give the same answer and the real-process tests could not fail."""
    mine = sorted(os.sched_getaffinity(0))
    if len(mine) < 2 or host_cpus().usable < 2:
        pytest.skip("needs 2 usable CPUs")
    return mine[:2]


@pytest.mark.zenoh
def test_pinned_to_one_cpu_with_one_worker_auto_runs_one_member_in_this_process(
    tmp_path: Path,
) -> None:
    svc = _start_pinned(tmp_path, {_two_cpus()[0]})
    try:

        def ready() -> bool:
            if svc.proc.poll() is not None:
                raise AssertionError(f"exited:\n{svc.log_path.read_text()}")
            try:
                return svc.http("/readyz")[0] == 200
            except OSError:
                return False

        wait_for(ready, 60, "/readyz")
        events = svc.logs()
        [auto] = [e for e in events if e.get("event") == "processes_auto"]
        assert (auto["processes"], auto["affinity_cpus"], auto["workers"]) == (1, 1, 1)
        # One member, and it is this process: no supervisor, no child.
        names = {e.get("event") for e in events}
        assert "supervisor_started" not in names and "child_started" not in names
        [started] = [e for e in events if e.get("event") == "service_started"]
        assert started["instance"] == "auto"  # not auto-0, a supervisor's child
    finally:
        assert svc.stop(signal.SIGTERM, timeout=60) == 0


def test_pinned_to_two_cpus_with_one_worker_auto_asks_for_two_members(tmp_path: Path) -> None:
    # Metrics port 65535: two members would need 65536, refused before anything starts.
    svc = _start_pinned(tmp_path, set(_two_cpus()), "--metrics-port", "65535")
    assert svc.proc.wait(60) == 2
    text = svc.log_path.read_text()
    assert "--metrics-port 65535 + 1 is past port 65535" in text
    [auto] = [e for e in svc.logs() if e.get("event") == "processes_auto"]
    assert (auto["processes"], auto["affinity_cpus"]) == (2, 2)
