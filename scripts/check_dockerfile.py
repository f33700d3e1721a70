"""Validate the Dockerfile without a Docker engine.

    .venv/bin/python scripts/check_dockerfile.py            # static checks, then build and run
    .venv/bin/python scripts/check_dockerfile.py --static   # static checks only (~1 s)

Static checks: multi-stage on a slim Python 3.11 base, dependencies installed from
pyproject.toml before the sources are copied, every COPY source present and not excluded by
.dockerignore, a non-root USER, the HEALTHCHECK on /healthz, the metrics port EXPOSEd, the
state directory a VOLUME and the default SIMPLETRACK_STATE_DIR, STOPSIGNAL SIGTERM, and an
ENTRYPOINT + CMD that ``simpletrack``'s own parser accepts.

Build and run: every RUN step is executed with /bin/sh in a throwaway directory on this
machine (the path ARGs point into it; groupadd/useradd/chown are recorded instead of changing
this host's users), then the image's ENTRYPOINT + CMD is started with the image's ENV (bound to
127.0.0.1 and free ports), the HEALTHCHECK command is run until it passes, /readyz must answer
200, and the STOPSIGNAL must stop it with exit code 0.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Paths a RUN step may create: the checker points these ARGs into its throwaway directory.
PATH_ARGS = ("VENV", "STATE_DIR")
# Commands that would change this host's users or file owners: recorded, not run.
RECORDED = ("groupadd", "useradd", "chown")
BASE_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"


@dataclass
class Instruction:
    cmd: str  # upper case: RUN, COPY, ...
    args: str  # the rest, continuation lines joined, flags removed
    flags: dict[str, str]
    line: int

    def exec_form(self) -> list[str] | None:
        if self.args.startswith("["):
            value = json.loads(self.args)
            assert isinstance(value, list)
            return [str(v) for v in value]
        return None


@dataclass
class Stage:
    base: str
    name: str
    instructions: list[Instruction] = field(default_factory=list)

    def all(self, cmd: str) -> list[Instruction]:
        return [i for i in self.instructions if i.cmd == cmd]

    def last(self, cmd: str) -> Instruction | None:
        found = self.all(cmd)
        return found[-1] if found else None


@dataclass
class Dockerfile:
    global_args: dict[str, str]
    stages: list[Stage]

    def stage(self, name: str) -> Stage:
        return next(s for s in self.stages if s.name == name)


_FLAG = re.compile(r"--([a-z-]+)=(\S+)\s+")


def parse(text: str) -> Dockerfile:
    """The instructions of a Dockerfile: comments dropped, continuation lines joined."""
    logical: list[tuple[int, str]] = []
    buf, start = "", 0
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not buf and (not line or line.startswith("#")):
            continue
        if buf and line.startswith("#"):
            continue  # a comment inside a continued instruction
        if not buf:
            start = n
        if line.endswith("\\"):
            buf += line[:-1] + " "
            continue
        logical.append((start, buf + line))
        buf = ""
    if buf:
        raise ValueError(f"line {start}: the file ends inside a continued instruction")
    global_args: dict[str, str] = {}
    stages: list[Stage] = []
    for n, line in logical:
        cmd, _, rest = line.partition(" ")
        cmd, rest = cmd.upper(), rest.strip()
        flags: dict[str, str] = {}
        while m := _FLAG.match(rest):
            flags[m.group(1)] = m.group(2)
            rest = rest[m.end() :]
        if cmd == "FROM":
            base, _, alias = rest.partition(" AS ")
            if not alias:
                base, _, alias = rest.partition(" as ")
            stages.append(Stage(base.strip(), alias.strip() or str(len(stages))))
        elif not stages:
            if cmd != "ARG":
                raise ValueError(f"line {n}: {cmd} before the first FROM")
            name, _, default = rest.partition("=")
            global_args[name] = default
        else:
            stages[-1].instructions.append(Instruction(cmd, rest, flags, n))
    if not stages:
        raise ValueError("no FROM instruction")
    return Dockerfile(global_args, stages)


def expand(text: str, env: dict[str, str]) -> str:
    """Docker's ${VAR}, $VAR and ${VAR:-default} in ENV/COPY/USER/... values."""

    def one(m: re.Match[str]) -> str:
        name = m.group(1) or m.group(3)
        default = m.group(2)
        value = env.get(name, "")
        return value if value or default is None else default

    return re.sub(r"\$\{(\w+)(?::-([^}]*))?\}|\$(\w+)", one, text)


def env_pairs(args: str) -> list[tuple[str, str]]:
    """``ENV a=1 b="x y"`` as pairs (the legacy ``ENV a 1`` form too)."""
    parts = shlex.split(args, posix=True)
    if parts and "=" not in parts[0]:
        return [(parts[0], " ".join(parts[1:]))]
    return [tuple(p.split("=", 1)) for p in parts]  # type: ignore[misc]


def stage_env(df: Dockerfile, stage: Stage, args: dict[str, str] | None = None) -> dict[str, str]:
    """ARGs and ENVs in force at the end of ``stage`` (``args`` override ARG defaults)."""
    base = {"PATH": BASE_PATH}
    scope = {**df.global_args, **(args or {})}
    env: dict[str, str] = dict(base)
    for i in stage.instructions:
        if i.cmd == "ARG":
            name, _, default = i.args.partition("=")
            env[name] = (args or {}).get(name, scope.get(name, default))
        elif i.cmd == "ENV":
            for k, v in env_pairs(i.args):
                env[k] = expand(v, env)
    return env


# ------------------------------------------------------------------------ .dockerignore
def _glob_regex(pattern: str) -> str:
    out, k = "", 0
    while k < len(pattern):
        if pattern.startswith("**/", k):
            out, k = out + "(?:.*/)?", k + 3
        elif pattern.startswith("**", k):
            out, k = out + ".*", k + 2
        elif pattern[k] == "*":
            out, k = out + "[^/]*", k + 1
        elif pattern[k] == "?":
            out, k = out + "[^/]", k + 1
        else:
            out, k = out + re.escape(pattern[k]), k + 1
    return out


def ignored(path: str, patterns: list[str]) -> bool:
    """Docker's rule: the last pattern matching the path or one of its parents wins."""
    parts = path.strip("/").removeprefix("./").split("/")
    candidates = ["/".join(parts[: k + 1]) for k in range(len(parts))]
    result = False
    for pat in patterns:
        negate = pat.startswith("!")
        regex = _glob_regex(pat.removeprefix("!").strip("/"))
        if any(re.fullmatch(regex, c) for c in candidates):
            result = not negate
    return result


def read_dockerignore(root: Path) -> list[str]:
    path = root / ".dockerignore"
    if not path.is_file():
        return []
    lines = (line.strip() for line in path.read_text().splitlines())
    return [line for line in lines if line and not line.startswith("#")]


# ------------------------------------------------------------------------ static checks
def copy_sources(i: Instruction) -> list[str]:
    form = i.exec_form()
    parts = form if form is not None else i.args.split()
    return parts[:-1]


def static_problems(df: Dockerfile, root: Path = ROOT) -> list[str]:
    """Everything wrong with the Dockerfile that can be told without building it."""
    out: list[str] = []
    if len(df.stages) < 2:
        out.append("not multi-stage: build in one stage, copy the result into a clean one")
    base = expand(df.stages[-1].base, df.global_args)
    if not re.fullmatch(r"python:3\.11[\w.-]*-slim[\w.-]*", base):
        out.append(f"final base image {base!r} is not a slim Python 3.11 image")
    patterns = read_dockerignore(root)
    for stage in df.stages:
        for i in stage.all("COPY") + stage.all("ADD"):
            if "from" in i.flags:
                continue
            for src in copy_sources(i):
                if not (root / src).exists():
                    out.append(f"line {i.line}: COPY source {src!r} does not exist")
                elif ignored(src, patterns):
                    out.append(f"line {i.line}: COPY source {src!r} is excluded by .dockerignore")
    out += _layer_order_problems(df)
    final = df.stages[-1]
    env = stage_env(df, final)
    user = final.last("USER")
    if user is None:
        out.append("no USER in the final stage: the service would run as root")
    else:
        name = expand(user.args, env).split(":")[0]
        if name in {"root", "0", ""}:
            out.append(f"USER {user.args} is root")
    health = final.last("HEALTHCHECK")
    if health is None or "/healthz" not in health.args:
        out.append("no HEALTHCHECK on /healthz in the final stage")
    port = env.get("SIMPLETRACK_METRICS_PORT", "9464")
    exposed = {p.split("/")[0] for i in final.all("EXPOSE") for p in expand(i.args, env).split()}
    if port not in exposed:
        out.append(f"the metrics port {port} is not EXPOSEd (EXPOSE {sorted(exposed)})")
    state_dir = env.get("SIMPLETRACK_STATE_DIR")
    volumes = {v for i in final.all("VOLUME") for v in (i.exec_form() or i.args.split())}
    if not state_dir:
        out.append("SIMPLETRACK_STATE_DIR is not set: nothing would survive a restart")
    elif expand(state_dir, env) not in {expand(v, env) for v in volumes}:
        out.append(f"the state directory {state_dir} is not a VOLUME ({sorted(volumes)})")
    stop = final.last("STOPSIGNAL")
    if stop is None or stop.args not in {"SIGTERM", "15"}:
        out.append("STOPSIGNAL is not SIGTERM (the service snapshots on SIGTERM)")
    if command_line(df) is None:
        out.append("no ENTRYPOINT/CMD in exec form in the final stage")
    return out


def _layer_order_problems(df: Dockerfile) -> list[str]:
    """Dependencies must be installed from pyproject.toml before any source is copied."""
    for stage in df.stages:
        seq = stage.instructions
        first_src = next(
            (
                k
                for k, i in enumerate(seq)
                if i.cmd == "COPY"
                and "from" not in i.flags
                and any(
                    s.rstrip("/") in {"service", "schemas", "clients", "."} for s in copy_sources(i)
                )
            ),
            None,
        )
        if first_src is None:
            continue
        before = seq[:first_src]
        has_pyproject = any(i.cmd == "COPY" and "pyproject.toml" in copy_sources(i) for i in before)
        installs = any(i.cmd == "RUN" and "pip" in i.args and "install" in i.args for i in before)
        if not (has_pyproject and installs):
            return [
                f"stage {stage.name}: dependencies are not installed from pyproject.toml "
                "before the sources are copied (every source edit would re-download them)"
            ]
        return []
    return ["no stage copies the sources (service, schemas, clients)"]


def command_line(df: Dockerfile) -> list[str] | None:
    final = df.stages[-1]
    entry, cmd = final.last("ENTRYPOINT"), final.last("CMD")
    e = entry.exec_form() if entry else []
    c = cmd.exec_form() if cmd else []
    if e is None or c is None or not (e or c):
        return None
    return e + c


def healthcheck_argv(df: Dockerfile) -> list[str]:
    """The HEALTHCHECK command as the engine runs it (shell form through /bin/sh -c)."""
    health = df.stages[-1].last("HEALTHCHECK")
    assert health is not None
    m = re.match(r"(?:--\S+\s+)*CMD\s+(.*)", health.args)
    assert m, health.args
    command = m.group(1)
    if command.startswith("["):
        value = json.loads(command)
        assert isinstance(value, list)
        return [str(v) for v in value]
    return ["/bin/sh", "-c", command]


def healthcheck_flags(df: Dockerfile) -> dict[str, float]:
    health = df.stages[-1].last("HEALTHCHECK")
    assert health is not None
    out: dict[str, float] = {"interval": 30, "timeout": 30, "start-period": 0, "retries": 3}
    for k, v in {**health.flags, **dict(re.findall(r"--([a-z-]+)=(\S+)", health.args))}.items():
        out[k] = float(v.rstrip("s")) if k != "retries" else float(v)
    return out


# ------------------------------------------------------------------------ build and run
def _shims(shim_dir: Path, record: Path, python: str) -> None:
    shim_dir.mkdir(parents=True)
    for name in RECORDED:
        p = shim_dir / name
        p.write_text(f'#!/bin/sh\necho "{name} $*" >> "{record}"\n')
        p.chmod(0o755)
    # The base image's `python` is the one on PATH; here it is this interpreter's base.
    for name in ("python", "python3"):
        p = shim_dir / name
        p.write_text(f'#!/bin/sh\nexec "{python}" "$@"\n')
        p.chmod(0o755)


def build(df: Dockerfile, work: Path, log: Path) -> dict[str, str]:
    """Run every stage's COPY/WORKDIR/RUN in ``work``; return the final stage's environment."""
    rootfs = work / "rootfs"
    shim_dir, record = work / "shims", work / "recorded.txt"
    python = getattr(sys, "_base_executable", sys.executable)
    _shims(shim_dir, record, python)
    args = {name: f"{rootfs}{df.global_args[name]}" for name in PATH_ARGS if name in df.global_args}
    host_pip = {k: v for k, v in os.environ.items() if k.startswith("PIP_")}
    env: dict[str, str] = {}
    for stage in df.stages:
        env = {"PATH": BASE_PATH, "HOME": str(work / "home"), "LANG": "C.UTF-8"}
        scope = {**df.global_args, **args}
        cwd = rootfs
        for i in stage.instructions:
            if i.cmd == "ARG":
                name, _, default = i.args.partition("=")
                env[name] = scope.get(name, default)
            elif i.cmd == "ENV":
                for k, v in env_pairs(i.args):
                    env[k] = expand(v, env)
            elif i.cmd == "WORKDIR":
                cwd = rootfs / expand(i.args, env).lstrip("/")
                cwd.mkdir(parents=True, exist_ok=True)
            elif i.cmd == "COPY":
                _copy(i, env, cwd, rootfs)
            elif i.cmd == "RUN":
                run_env = {**host_pip, **env, "PATH": f"{shim_dir}:{env['PATH']}"}
                print(f"  RUN (line {i.line}) {i.args[:90]}{'...' if len(i.args) > 90 else ''}")
                with log.open("ab") as out:
                    rc = subprocess.call(
                        ["/bin/sh", "-c", i.args], cwd=cwd, env=run_env, stdout=out, stderr=out
                    )
                if rc != 0:
                    raise SystemExit(f"RUN at line {i.line} failed with {rc}: see {log}")
    if record.is_file():
        for line in record.read_text().splitlines():
            print(f"  recorded, not run on this host: {line}")
    return env


def _copy(i: Instruction, env: dict[str, str], cwd: Path, rootfs: Path) -> None:
    parts = [expand(p, env) for p in (i.exec_form() or i.args.split())]
    *sources, dest = parts
    target = Path(dest) if dest.startswith(str(rootfs)) else None
    if target is None:
        target = rootfs / dest.lstrip("/") if dest.startswith("/") else cwd / dest
    if "from" in i.flags:
        # One shared directory stands for every stage: copying a stage's path to the same
        # path is already done.
        if all(Path(s) == target for s in sources):
            return
        raise SystemExit(f"line {i.line}: COPY --from between different paths is not simulated")
    for src in sources:
        s = ROOT / src
        if s.is_dir():
            ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
            shutil.copytree(s, target, dirs_exist_ok=True, ignore=ignore)
        elif dest.endswith("/") or target.is_dir():
            target.mkdir(parents=True, exist_ok=True)
            shutil.copy2(s, target / s.name)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(s, target)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def smoke_run(df: Dockerfile, env: dict[str, str], work: Path, grace_s: float = 40.0) -> None:
    """Start the image's command as the container would, check health, readiness and stop."""
    argv = command_line(df)
    assert argv is not None
    exe = shutil.which(argv[0], path=env["PATH"])
    if exe is None:
        raise SystemExit(f"{argv[0]} is not on the image's PATH {env['PATH']}")
    port, zport = free_port(), free_port()
    run_env = {
        **env,
        # Loopback and free ports on a shared host; the image binds 0.0.0.0:9464.
        "SIMPLETRACK_METRICS_HOST": "127.0.0.1",
        "SIMPLETRACK_METRICS_PORT": str(port),
        "SIMPLETRACK_ZENOH__LISTEN": json.dumps([f"tcp/127.0.0.1:{zport}"]),
        "SIMPLETRACK_INSTANCE": "dockerfile-check",
    }
    log = work / "serve.log"
    health = healthcheck_argv(df)
    flags = healthcheck_flags(df)
    print(f"  start: {' '.join(argv)}  (metrics on 127.0.0.1:{port})")
    with log.open("wb") as out:
        proc = subprocess.Popen([exe, *argv[1:]], cwd=work, env=run_env, stdout=out, stderr=out)
    try:
        deadline = time.monotonic() + flags["start-period"] + flags["retries"] * flags["interval"]
        while True:
            exe_health = shutil.which(health[0], path=run_env["PATH"]) or health[0]
            rc = subprocess.call(
                [exe_health, *health[1:]],
                env=run_env,
                timeout=flags["timeout"] + 5,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            if rc == 0:
                break
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"HEALTHCHECK never passed (rc {rc}):\n{log.read_text()}")
            time.sleep(0.5)
        print("  HEALTHCHECK passes")
        deadline = time.monotonic() + 30
        while _status(port, "/readyz") != 200:
            if time.monotonic() > deadline:
                raise SystemExit(f"/readyz never answered 200:\n{log.read_text()}")
            time.sleep(0.2)
        print("  /readyz answers 200")
        stop = df.stages[-1].last("STOPSIGNAL")
        sig = signal.Signals[stop.args] if stop is not None else signal.SIGTERM
        t0 = time.monotonic()
        proc.send_signal(sig)
        rc = proc.wait(grace_s)
        if rc != 0:
            raise SystemExit(f"exit code {rc} after {sig.name}:\n{log.read_text()}")
        print(f"  {sig.name}: exit 0 after {time.monotonic() - t0:.1f} s")
        state = Path(env["SIMPLETRACK_STATE_DIR"])
        if not state.is_dir():
            raise SystemExit(f"the state directory {state} was not created")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _status(port: int, path: str) -> int:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
            return int(r.status)
    except urllib.error.HTTPError as e:
        return int(e.code)
    except OSError:
        return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dockerfile", type=Path, default=ROOT / "Dockerfile")
    parser.add_argument("--static", action="store_true", help="static checks only")
    parser.add_argument("--keep", action="store_true", help="keep the throwaway directory")
    args = parser.parse_args(argv)
    df = parse(args.dockerfile.read_text())
    problems = static_problems(df)
    for p in problems:
        print(f"problem: {p}", file=sys.stderr)
    if problems:
        return 1
    print(f"static checks: ok ({len(df.stages)} stages, command {command_line(df)})")
    if args.static:
        return 0
    work = Path(tempfile.mkdtemp(prefix="dockerfile-check-"))
    try:
        t0 = time.monotonic()
        env = build(df, work, work / "build.log")
        venv = Path(env.get("VENV", ""))
        size = sum(p.stat().st_size for p in venv.rglob("*") if p.is_file()) if venv.name else 0
        print(f"build: ok in {time.monotonic() - t0:.0f} s; {venv.name or '?'} is {size >> 20} MiB")
        smoke_run(df, env, work)
        print("run: ok")
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            with contextlib.suppress(OSError):
                shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
