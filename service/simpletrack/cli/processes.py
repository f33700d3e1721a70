"""``simpletrack serve --processes N``: a supervisor of N ``simpletrack serve`` children, the
members of one group on one host (one interpreter lock each, so N cores instead of ~1).
``--processes auto``: N = the usable CPUs (affinity mask, cgroup quota: ``host_cpus``) //
``workers``, each member's threads; an N of 1 runs in this process, as ``--processes 1``.

Child i gets instance ``<instance>-<i>``, metrics port ``<metrics_port>+i`` (0 stays 0), state
dir ``<state_dir>/<i>``; in peer mode it listens on the given endpoints with port + i (child 0
keeps them) and connects to every sibling's first listen endpoint, so the members see each
other and a vehicle connected to any one of them learns of the rest (Zenoh gossip). In client
mode every child connects to the same routers. Every other flag is passed on as given; the
environment is inherited.

The supervisor opens no Zenoh session and starts no thread: children are started with
fork+exec (subprocess) from a process that holds no Zenoh runtime. It forwards SIGTERM/SIGINT
to every child and waits for all of them (exit code: the worst child's); a child that dies
without being asked is restarted after a back-off, and one that keeps dying
(``RESTARTS_PER_WINDOW`` restarts within ``CRASH_WINDOW_S``) stops the group, exit code
non-zero. A child whose first start is refused (exit code 2: its own one-line error, such as
a port in use) stops the group at once with code 2: the same arguments would be refused again.
The supervisor does not kill a child that takes long to stop: the deadline is the caller's
(systemd's TimeoutStopSec, Kubernetes' terminationGracePeriodSeconds).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import re
import signal
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import FrameType
from typing import Any, Literal

from simpletrack.cli.errors import USAGE_EXIT, UserError
from simpletrack.cli.host_cpus import HostCpus, host_cpus
from simpletrack.server.logs import EventLogger, get_logger
from simpletrack.server.settings import ServiceSettings
from simpletrack.wire.messages import NAME_PATTERN

MAX_PROCESSES = 64
AUTO: Literal["auto"] = "auto"
RESTARTS_PER_WINDOW = 5
CRASH_WINDOW_S = 60.0
FIRST_BACKOFF_S = 0.5
MAX_BACKOFF_S = 10.0
POLL_S = 0.1
# The flags the supervisor sets per child; the rest are passed on as the user gave them.
PER_CHILD = frozenset(
    {"processes", "instance", "metrics_port", "state_dir", "zenoh_listen", "zenoh_connect"}
)
PR_SET_PDEATHSIG = 1  # linux/prctl.h

log = get_logger("supervisor")


def parse_processes(text: str) -> int | Literal["auto"]:
    """N, or ``"auto"`` (any case): the count is then decided from the settings' ``workers``
    once they are loaded (``auto_processes``)."""
    if text.strip().lower() == AUTO:
        return AUTO
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= MAX_PROCESSES:
        raise UserError(f"--processes {text!r} must be an integer in 1..{MAX_PROCESSES} or auto")
    return n


def auto_processes(cpus: HostCpus, workers: int) -> tuple[int, str]:
    """``--processes auto``: as many members as the usable CPUs hold ``workers`` threads each
    (at least 1, at most ``MAX_PROCESSES``), and the one-line reason to log."""
    n = max(1, cpus.usable // workers)
    capped = min(n, MAX_PROCESSES)
    per = "worker" if workers == 1 else "workers"
    reason = f"{cpus.describe()} / {workers} {per} per member = {_members(n)}"
    if cpus.usable < workers:
        reason += " (at least 1)"
    if capped < n:
        reason += f", capped at {MAX_PROCESSES}"
    return capped, reason


def _members(n: int) -> str:
    return "1 member" if n == 1 else f"{n} members"


def resolve(wanted: int | Literal["auto"], workers: int) -> int:
    """The process count; for ``auto`` logged with its reason (event ``processes_auto``)."""
    if isinstance(wanted, int):
        return wanted
    cpus = host_cpus()
    n, reason = auto_processes(cpus, workers)
    log.info(
        "processes_auto",
        processes=n,
        usable_cpus=cpus.usable,
        affinity_cpus=cpus.affinity,
        quota_cpus=cpus.quota,
        workers=workers,
        reason=reason,
    )
    return n


# ----------------------------------------------------------------------------- child commands
@dataclass(frozen=True, slots=True)
class ChildSpec:
    index: int
    instance: str
    argv: tuple[str, ...]  # the arguments after ``simpletrack serve``


def passed_on(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """The flags of ``args`` the user gave, minus the per-child ones, as command-line words
    (rebuilt from the parsed values, so abbreviations and ``--flag=value`` forms are moot)."""
    out: list[str] = []
    for action in parser._actions:
        if not action.option_strings or action.dest in PER_CHILD or action.dest == "help":
            continue
        value = getattr(args, action.dest, None)
        if value is None or value == action.default:
            continue
        flag = action.option_strings[-1]
        if isinstance(action, argparse._StoreConstAction):  # store_true/false/const
            out.append(flag)
        elif isinstance(value, list):
            for v in value:
                out += [flag, str(v)]
        else:
            out += [flag, str(value)]
    return out


_ENDPOINT = re.compile(r"^(?P<head>[^/]+/.*):(?P<port>\d+)$")


def _split(endpoint: str) -> tuple[str, int, str]:
    """``proto/host:port?meta#config`` -> (``proto/host``, port, ``?meta#config``)."""
    cut = min((i for i in (endpoint.find("?"), endpoint.find("#")) if i >= 0), default=None)
    address, tail = (endpoint, "") if cut is None else (endpoint[:cut], endpoint[cut:])
    m = _ENDPOINT.match(address)
    if m is None:
        raise UserError(f"--processes needs listen endpoints with a port, not {endpoint!r}")
    port = int(m["port"])
    if port == 0:
        raise UserError(f"--processes needs fixed listen ports, not {endpoint!r} (port 0)")
    return m["head"], port, tail


def shifted(endpoint: str, by: int) -> str:
    head, port, tail = _split(endpoint)
    if port + by > 65535:
        raise UserError(f"listen endpoint {endpoint!r} + {by} is past port 65535")
    return f"{head}:{port + by}{tail}"


def reachable(endpoint: str) -> str:
    """Where a sibling reaches a listen endpoint: an any-address listener on loopback."""
    head, port, tail = _split(endpoint)
    proto, _, host = head.partition("/")
    host = {"0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(host, host)
    return f"{proto}/{host}:{port}{tail}"


def child_specs(settings: ServiceSettings, common: Sequence[str], n: int) -> list[ChildSpec]:
    """Each child's ``simpletrack serve`` arguments (``UserError`` when N does not fit)."""
    z = settings.zenoh
    peer = not z.options().is_client()
    if peer and not z.listen:
        raise UserError(
            "--processes in peer mode needs --listen (the Zenoh config file's endpoints "
            "cannot be shifted per child)"
        )
    last = n - 1
    if settings.metrics_port and settings.metrics_port + last > 65535:
        raise UserError(f"--metrics-port {settings.metrics_port} + {last} is past port 65535")
    listens = [[shifted(e, i) for e in z.listen] for i in range(n)] if peer else []
    specs = []
    for i in range(n):
        instance = f"{settings.instance}-{i}"
        if not re.fullmatch(NAME_PATTERN, instance):
            raise UserError(f"--instance {settings.instance!r}: {instance!r} is too long")
        argv = [*common, "--instance", instance]
        argv += ["--metrics-port", str(settings.metrics_port + i if settings.metrics_port else 0)]
        if settings.state_dir is not None:
            argv += ["--state-dir", str(settings.state_dir / str(i))]
        siblings = [reachable(listens[j][0]) for j in range(n) if j != i] if peer else []
        for e in listens[i] if peer else []:
            argv += ["--listen", e]
        for e in [*z.connect, *siblings]:
            argv += ["--connect", e]
        specs.append(ChildSpec(i, instance, tuple(argv)))
    return specs


# ----------------------------------------------------------------------------- restarts
@dataclass
class RestartPolicy:
    """Back-off doubling from ``FIRST_BACKOFF_S``; gives up past ``RESTARTS_PER_WINDOW``
    restarts within ``CRASH_WINDOW_S`` (deaths older than the window are forgiven)."""

    deaths: deque[float] = field(default_factory=deque)

    def after_death(self, now: float) -> float | None:
        """Seconds to wait before the restart, or None: a crash loop, give up."""
        self.deaths.append(now)
        while self.deaths and self.deaths[0] < now - CRASH_WINDOW_S:
            self.deaths.popleft()
        if len(self.deaths) > RESTARTS_PER_WINDOW:
            return None
        return float(min(MAX_BACKOFF_S, FIRST_BACKOFF_S * 2.0 ** (len(self.deaths) - 1)))


def refused(code: int, starts: int) -> bool:
    """A first start that ended in a usage error: a configuration that cannot run (a port
    taken, a folder not writable). A restart's refusal is retried (what held the port may be
    gone in a moment)."""
    return code == USAGE_EXIT and starts == 1


def exit_code(returncode: int) -> int:
    """A shell's view: killed by signal S is 128 + S."""
    return 128 - returncode if returncode < 0 else returncode


# ----------------------------------------------------------------------------- the supervisor
def _die_with_parent() -> Callable[[], None] | None:
    """A child that outlives a SIGKILLed supervisor would hold its ports and sensors: Linux
    sends it SIGTERM when the supervisor dies."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None, use_errno=True)
    parent = os.getpid()

    def setup() -> None:
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the supervisor died before prctl
            os.kill(os.getpid(), signal.SIGTERM)

    return setup


@dataclass
class _Child:
    spec: ChildSpec
    proc: subprocess.Popen[bytes] | None = None
    policy: RestartPolicy = field(default_factory=RestartPolicy)
    restart_at: float | None = None
    code: int = 0  # of its last exit
    starts: int = 0


class Supervisor:
    def __init__(self, specs: Sequence[ChildSpec], logger: EventLogger = log) -> None:
        self.children = [_Child(s) for s in specs]
        self.log = logger
        self._signals: list[int] = []
        self._stopping = False
        self._gave_up = False
        self._refused = False
        self._preexec = _die_with_parent()

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self._signals.append(signum)  # forwarded by the loop: no process calls in a handler

    def _start(self, child: _Child) -> None:
        cmd = [sys.executable, "-m", "simpletrack.cli.main", "serve", *child.spec.argv]
        child.proc = subprocess.Popen(cmd, preexec_fn=self._preexec)
        child.restart_at = None
        child.starts += 1
        self.log.info(
            "child_started",
            child=child.spec.index,
            instance=child.spec.instance,
            pid=child.proc.pid,
            restarts=child.starts - 1,
        )

    def _stop_all(self, signum: int) -> None:
        self._stopping = True
        for child in self.children:
            child.restart_at = None
            if child.proc is not None and child.proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    child.proc.send_signal(signum)

    def _reap(self, child: _Child, now: float) -> None:
        proc = child.proc
        if proc is None or proc.poll() is None:
            return
        child.proc, child.code = None, exit_code(proc.returncode)
        fields: dict[str, Any] = {"child": child.spec.index, "instance": child.spec.instance}
        if self._stopping:
            self.log.info("child_exited", **fields, pid=proc.pid, code=child.code)
            return
        if refused(child.code, child.starts):
            self.log.error(
                "child_refused",
                **fields,
                pid=proc.pid,
                code=child.code,
                action="stopping every child (its error is the line above)",
            )
            self._refused = True
            self._stop_all(signal.SIGTERM)
            return
        self.log.warning("child_died", **fields, pid=proc.pid, code=child.code)
        delay = child.policy.after_death(now)
        if delay is None:
            self.log.error(
                "crash_loop",
                **fields,
                restarts=RESTARTS_PER_WINDOW,
                window_s=CRASH_WINDOW_S,
                action="stopping every child",
            )
            self._gave_up = True
            self._stop_all(signal.SIGTERM)
            return
        child.restart_at = now + delay
        self.log.info("child_restarting", **fields, in_s=delay)

    def run(self) -> int:
        previous = {
            sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGTERM, signal.SIGINT)
        }
        try:
            for child in self.children:
                self._start(child)
            while True:
                while self._signals:
                    signum = self._signals.pop(0)
                    self.log.info("supervisor_stopping", signal=signal.Signals(signum).name)
                    self._stop_all(signum)
                now = time.monotonic()
                for child in self.children:
                    self._reap(child, now)
                    if child.restart_at is not None and now >= child.restart_at:
                        self._start(child)
                if self._stopping and all(c.proc is None for c in self.children):
                    break
                time.sleep(POLL_S)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        worst = max(c.code for c in self.children)
        code = worst
        if self._refused:
            code = USAGE_EXIT
        elif self._gave_up:
            code = max(worst, 1)
        self.log.info("supervisor_stopped", code=code)
        return code


def supervise(
    parser: argparse.ArgumentParser, args: argparse.Namespace, settings: ServiceSettings, n: int
) -> int:
    specs = child_specs(settings, passed_on(parser, args), n)
    log.info(
        "supervisor_started",
        pid=os.getpid(),
        processes=n,
        instances=",".join(s.instance for s in specs),
    )
    return Supervisor(specs).run()


__all__ = [
    "ChildSpec",
    "RestartPolicy",
    "Supervisor",
    "auto_processes",
    "child_specs",
    "parse_processes",
    "refused",
    "resolve",
]
