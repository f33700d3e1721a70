"""The Zenoh router configs (deploy/zenoh/, deploy/k8s/): explicit endpoints only; the
vehicle-facing mTLS + access-control example enforced by a real router (this process,
``mode: router``, with the file's settings; only its addresses and certificate paths are
replaced); and the compose router, service and demo fleet wired together."""

from __future__ import annotations

import ipaddress
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
import zenoh

from simpletrack.client import DetectionPublisher
from simpletrack.session import open_session
from tests.faults.router_process import start_client_service
from tests.service_helpers import Client, free_port, metric, moving_cars, stamp, wait_for

ROOT = Path(__file__).resolve().parents[2]
ZENOH_DIR = ROOT / "deploy" / "zenoh"
ROUTER_CONFIGS = [
    *sorted(ZENOH_DIR.glob("router*.json5")),
    ROOT / "deploy" / "k8s" / "zenoh-router.json5",
]
MTLS = ZENOH_DIR / "router-vehicles-mtls.json5"
VEHICLE = ZENOH_DIR / "vehicle-client-mtls.json5"
WILDCARD_HOSTS = {"0.0.0.0", "::", "[::]", "", "*"}


def load(path: Path) -> zenoh.Config:
    return zenoh.Config.from_json5(path.read_text())  # rejects unknown keys, like zenohd


def get(config: zenoh.Config, key: str) -> Any:
    return json.loads(config.get_json(key))


def host_port(endpoint: str) -> tuple[str, str]:
    _, _, address = endpoint.partition("/")
    address = address.split("#")[0].split("?")[0]
    host, _, port = address.rpartition(":")
    return host, port


def test_there_are_router_configs() -> None:
    assert {p.name for p in ROUTER_CONFIGS} >= {"router.json5", MTLS.name}


def exposure_problems(config: zenoh.Config) -> list[str]:
    """Ways a router config opens more than it names: wildcard or missing listen addresses,
    multicast scouting, a REST plugin on every interface or a writable admin space."""
    out = []
    listen = get(config, "listen/endpoints")
    if not listen:
        out.append("no listen endpoints: zenohd then listens on tcp/[::]:7447")
    for endpoint in listen or []:
        host, port = host_port(endpoint)
        if host in WILDCARD_HOSTS:
            out.append(f"{endpoint} listens on every interface")
        else:
            try:
                ipaddress.ip_address(host.strip("[]"))
            except ValueError:
                out.append(f"{endpoint}: a name may resolve to more than one address")
        if not (port.isdigit() and int(port) > 0):
            out.append(f"{endpoint} has no fixed port")
    if get(config, "scouting/multicast/enabled") is not False:
        out.append("multicast scouting is on")
    rest = get(config, "plugins").get("rest")
    if rest is not None:
        bind = str(rest["http_port"])
        if bind.rpartition(":")[0] in WILDCARD_HOSTS:
            out.append(f"the REST plugin binds {bind!r}: every interface")
        if get(config, "adminspace/permissions/write") is not False:
            out.append("the admin space is writable through REST")
    return out


@pytest.mark.parametrize("path", ROUTER_CONFIGS, ids=lambda p: p.name)
def test_router_listens_only_on_explicit_addresses(path: Path) -> None:
    config = load(path)
    assert get(config, "mode") == "router"
    assert exposure_problems(config) == []


@pytest.mark.parametrize(
    ("key", "value", "problem"),
    [
        ("listen/endpoints", '["tcp/0.0.0.0:7447"]', "every interface"),
        ("listen/endpoints", '["tcp/[::]:7447"]', "every interface"),
        ("listen/endpoints", '["tcp/router.local:7447"]', "a name"),
        ("listen/endpoints", "[]", "no listen endpoints"),
        ("scouting/multicast/enabled", "true", "multicast"),
        ("plugins/rest/http_port", '"8000"', "REST plugin"),
        ("adminspace/permissions/write", "true", "writable"),
    ],
)
def test_the_exposure_check_catches_each_mistake(key: str, value: str, problem: str) -> None:
    config = load(ZENOH_DIR / "router.json5")
    config.insert_json5(key, value)
    assert any(problem in p for p in exposure_problems(config))


def test_the_vehicle_router_requires_mtls_and_denies_by_default() -> None:
    config = load(MTLS)
    protos = {e.partition("/")[0] for e in get(config, "listen/endpoints")}
    assert "tls" in protos
    assert get(config, "transport/link/tls/enable_mtls") is True
    assert get(config, "access_control/enabled") is True
    assert get(config, "access_control/default_permission") == "deny"
    assert get(config, "adminspace/enabled") is False
    assert get(config, "plugins") == {}


# ----------------------------------------------------------------------------- live router
def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def _issue(tmp: Path, name: str, cn: str, ext: str) -> None:
    (tmp / f"{name}.ext").write_text(ext)
    _openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={cn}",
        cwd=tmp,
    )  # fmt: skip
    _openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "2", "-out", f"{name}.pem", "-extfile", f"{name}.ext",
        cwd=tmp,
    )  # fmt: skip


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    tmp = tmp_path_factory.mktemp("certs")
    _openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
        "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=test fleet CA",
        "-addext", "basicConstraints=critical,CA:TRUE",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        cwd=tmp,
    )  # fmt: skip
    leaf = "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n"
    _issue(
        tmp,
        "gateway",
        "gateway-a",
        leaf + "extendedKeyUsage=serverAuth\nsubjectAltName=IP:127.0.0.1\n",
    )
    for vehicle in ("truck-07", "van-02"):
        _issue(tmp, vehicle, vehicle, leaf + "extendedKeyUsage=clientAuth\n")
    return tmp


class Router:
    def __init__(self, certs: Path) -> None:
        self.tls = f"tls/127.0.0.1:{free_port()}"
        self.tcp = f"tcp/127.0.0.1:{free_port()}"
        self._certs = certs
        self.session = self._open()

    def _open(self) -> zenoh.Session:
        config = load(MTLS)
        config.insert_json5("listen/endpoints", json.dumps([self.tls, self.tcp]))
        config.insert_json5("connect/endpoints", "[]")
        tls = "transport/link/tls"
        for key, name in (
            ("root_ca_certificate", "ca.pem"),
            ("listen_private_key", "gateway.key"),
            ("listen_certificate", "gateway.pem"),
        ):
            config.insert_json5(f"{tls}/{key}", json.dumps(str(self._certs / name)))
        return zenoh.open(config)

    def restart_after(self, outage_s: float, during: Callable[[], None]) -> None:
        """Every link cut (the router gone), ``during`` called until ``outage_s`` has
        passed, then the router back on the same addresses: its clients reconnect."""
        self.session.close()  # type: ignore[no-untyped-call]
        deadline = time.monotonic() + outage_s
        while time.monotonic() < deadline:
            during()
        self.session = self._open()


def vehicle_session(router: Router, certs: Path, name: str | None) -> zenoh.Session:
    """The vehicle example config, pointed at the test router and certificates."""
    config = load(VEHICLE)
    config.insert_json5("connect/endpoints", json.dumps([router.tls]))
    tls = "transport/link/tls"
    config.insert_json5(f"{tls}/root_ca_certificate", json.dumps(str(certs / "ca.pem")))
    for key, suffix in (("connect_private_key", "key"), ("connect_certificate", "pem")):
        if name is None:
            config.insert_json5(f"{tls}/{key}", "null")
        else:
            config.insert_json5(f"{tls}/{key}", json.dumps(str(certs / f"{name}.{suffix}")))
    return zenoh.open(config)


class Inbox:
    def __init__(self) -> None:
        self.keys: list[str] = []
        self.payloads: list[bytes] = []
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.keys.append(str(sample.key_expr))
            self.payloads.append(sample.payload.to_bytes())

    def snapshot(self) -> list[str]:
        with self._lock:
            return list(self.keys)


@pytest.fixture
def router(certs: Path) -> Iterator[Router]:
    r = Router(certs)
    try:
        yield r
    finally:
        r.session.close()  # type: ignore[no-untyped-call]


@pytest.mark.zenoh
def test_a_vehicle_without_a_certificate_cannot_connect(router: Router, certs: Path) -> None:
    with pytest.raises(zenoh.ZError):
        vehicle_session(router, certs, None).close()  # type: ignore[no-untyped-call]


@pytest.mark.zenoh
def test_each_vehicle_reaches_only_its_own_keys(router: Router, certs: Path) -> None:
    service = open_session(mode="client", connect=[router.tcp])  # the backbone side
    truck = vehicle_session(router, certs, "truck-07")
    try:
        detections, own_errors, all_errors = Inbox(), Inbox(), Inbox()
        service.declare_subscriber("fleet/*/*/detections", detections)
        # What DetectionPublisher subscribes to, and a fleet-wide snoop the router refuses.
        truck.declare_subscriber("fleet/truck-07/lidar/errors", own_errors)
        truck.declare_subscriber("fleet/*/*/errors", all_errors)

        own = truck.declare_publisher("fleet/truck-07/lidar/detections")
        # The service's subscription reaches the vehicle (egress rule): its publisher matches.
        wait_for(lambda: own.matching_status.matching, 10, "the service's subscriber")
        other = truck.declare_publisher("fleet/van-02/lidar/detections")
        wait_for(lambda: other.matching_status.matching, 10, "a match: the router must refuse")

        other.put(b"spoofed")  # sent first: were it let through, it would arrive first
        own.put(b"frame")
        wait_for(lambda: bool(detections.snapshot()), 10, "the vehicle's own detections")
        assert detections.snapshot() == ["fleet/truck-07/lidar/detections"]

        def deliver() -> bool:  # until the truck's subscription has reached the router
            service.put("fleet/van-02/lidar/errors", b"not for the truck")
            service.put("fleet/truck-07/lidar/errors", b"error")
            return bool(own_errors.snapshot())

        wait_for(deliver, 10, "an error for the truck")
        assert set(own_errors.snapshot()) == {"fleet/truck-07/lidar/errors"}
        # The session hands its own errors to both subscribers; never another vehicle's.
        assert set(all_errors.snapshot()) == {"fleet/truck-07/lidar/errors"}

        # The service's status and snapshots are for the backbone, not for vehicles.
        service.declare_queryable("fleet/@simpletrack/svc/status", _answer)
        backbone = open_session(mode="client", connect=[router.tcp])
        try:
            wait_for(lambda: _replies(backbone) == 1, 10, "the status on the backbone")
        finally:
            backbone.close()  # type: ignore[no-untyped-call]
        assert _replies(truck) == 0
    finally:
        truck.close()  # type: ignore[no-untyped-call]
        service.close()  # type: ignore[no-untyped-call]


PERIOD_S = 0.1
TRUCK_CACHE = "fleet/truck-07/lidar/detections/@adv/**"  # what a service asks after a gap


@pytest.mark.zenoh
def test_frames_sent_while_the_router_is_down_are_recovered_through_it(
    router: Router, certs: Path, tmp_path: Path
) -> None:
    """The rules let a service ask a vehicle's cache for what it missed: truck-07 streams
    at 10 Hz over mTLS, the router goes away for 2 s (every link cut) and comes back; every
    frame is tracked in order and none is counted as missed."""
    service = start_client_service(tmp_path, router.tcp, instance="acl-recover")
    planner: Client | None = None
    truck = vehicle_session(router, certs, "truck-07")
    try:
        wait_for(lambda: service.http("/readyz")[0] == 200, 30, "the service ready")
        planner = Client(router.tcp)
        pub = DetectionPublisher(truck, "truck-07", "lidar", classes=("Car",))
        assert pub.wait_for_service(10)
        t0 = time.monotonic()

        def send() -> None:
            k = pub.next_seq
            pub.publish(moving_cars(k), stamp_ns=stamp(k))
            time.sleep(max(0.0, t0 + (k + 1) * PERIOD_S - time.monotonic()))

        for _ in range(10):
            send()
        router.restart_after(2.0, during=send)
        wait_for(lambda: pub.delivering, 15, "the truck reconnected")
        for _ in range(10):
            send()
        sent = pub.next_seq
        assert pub.held >= 10, "the break did not hold frames back"

        def tracked() -> list[int]:
            assert planner is not None
            with planner.received.lock:
                return [f.seq for f, _ in planner.received.tracks.get("truck-07/lidar", [])]

        def counted(name: str, **labels: str) -> float:
            return metric(service.metrics(), f"simpletrack_frames_{name}_total", **labels)

        # The service's own count: the planner reconnects on its own schedule and may miss
        # the first recovered tracks, the service has tracked them all the same.
        wait_for(lambda: counted("tracked") >= sent, 20, "every frame tracked")
        assert counted("tracked") == sent
        assert counted("dropped", reason="missed") == 0
        wait_for(lambda: tracked()[-1:] == [sent - 1], 10, "the last frame's tracks")
        seqs = tracked()
        assert seqs == sorted(set(seqs)), "recovered frames must come before later live ones"
        pub.close()
    finally:
        if planner is not None:
            planner.close()
        truck.close()  # type: ignore[no-untyped-call]
        service.stop()


@pytest.mark.zenoh
def test_another_vehicle_can_neither_feed_nor_read_a_vehicles_cache(
    router: Router, certs: Path
) -> None:
    service = open_session(mode="client", connect=[router.tcp])
    truck = vehicle_session(router, certs, "truck-07")
    # Two sessions with van-02's certificate: what one forges the other must not see
    # locally (a session delivers its own puts and queries to itself, router or not).
    van = vehicle_session(router, certs, "van-02")
    forger = vehicle_session(router, certs, "van-02")
    try:
        seen = Inbox()  # the service's side: frames and the recovery keys (heartbeats)
        service.declare_subscriber("fleet/*/*/detections", seen)
        service.declare_subscriber("fleet/*/*/detections/@adv/**", seen)
        snooped = Inbox()  # the van's attempts to watch the truck
        van.declare_subscriber("fleet/truck-07/*/detections", snooped)
        van.declare_subscriber(TRUCK_CACHE, snooped)
        # A fake cache for the truck's sensor: were it declared, recovery would ask it.
        fake = "fleet/truck-07/lidar/detections/@adv/pub/f00d/1/_"
        forger.declare_queryable(fake, lambda q: q.reply(fake, b"spoofed"))
        for key in ("fleet/truck-07/lidar/detections", fake):
            spoof = forger.declare_publisher(key)
            # The van is told of the service's subscriptions, so it does send.
            wait_for(_matching(spoof), 10, "a match: the router refuses")
            spoof.put(b"spoofed")

        pub = DetectionPublisher(truck, "truck-07", "lidar", classes=("Car",))
        assert pub.wait_for_service(10)
        for k in range(3):
            pub.publish(moving_cars(k), stamp_ns=stamp(k))

        def cache(session: zenoh.Session, selector: str = TRUCK_CACHE) -> list[bytes]:
            # As recovery does: the cache answers with the frames' own key, outside the
            # query's, one reply per frame (all on that key: no consolidation).
            replies = session.get(
                selector,
                accept_replies=zenoh.ReplyKeyExpr.ANY,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=1.0,
            )
            return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

        # The backbone reaches the truck's cache (all three frames), never the van's fake.
        wait_for(lambda: len(cache(service)) == 3, 10, "the truck's cache on the backbone")
        assert b"spoofed" not in cache(service)
        assert cache(van) == []
        assert cache(van, "fleet/*/*/detections/@adv/**") == []
        frames = "fleet/truck-07/lidar/detections"
        wait_for(lambda: seen.snapshot().count(frames) == 3, 10, "the truck's frames")
        time.sleep(1.0)  # the truck's heartbeats come every 0.5 s: the van's would too
        assert b"spoofed" not in seen.payloads
        assert any("/@adv/pub/" in k for k in seen.snapshot()), "no heartbeat reached the service"
        assert snooped.snapshot() == []
        pub.close()
    finally:
        forger.close()  # type: ignore[no-untyped-call]
        van.close()  # type: ignore[no-untyped-call]
        truck.close()  # type: ignore[no-untyped-call]
        service.close()  # type: ignore[no-untyped-call]


def _matching(publisher: zenoh.Publisher) -> Callable[[], bool]:
    # The stubs say bool; zenoh 1.10 returns a MatchingStatus.
    return lambda: bool(getattr(publisher.matching_status, "matching", False))


def _answer(query: zenoh.Query) -> None:
    query.reply("fleet/@simpletrack/svc/status", b"status")


def _replies(session: zenoh.Session) -> int:
    return sum(1 for r in session.get("fleet/@simpletrack/*/status", timeout=1.0) if r.ok)


# ----------------------------------------------------------------------------- compose wiring
@pytest.mark.zenoh
def test_the_compose_stack_tracks_the_demo_fleet_through_the_router(tmp_path: Path) -> None:
    """deploy/zenoh/router.json5 in a router, every `simpletrack serve` instance of
    compose.yaml with its environment as the router's client (addresses moved to 127.0.0.1),
    and the simulated fleet of docs/DEPLOY.md (`simpletrack demo --service external`)
    through the router: the instances share the sensors, every frame comes back tracked by
    exactly one of them, and SIGTERM leaves a snapshot of every sensor with its owner."""
    compose = yaml.safe_load((ROOT / "deploy" / "compose.yaml").read_text())
    names = sorted(n for n in compose["services"] if n.startswith("simpletrack-"))
    assert len(names) >= 2, names
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = load(ZENOH_DIR / "router.json5")
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    router = zenoh.open(config)
    procs: dict[str, tuple[subprocess.Popen[bytes], int]] = {}
    try:
        for name in names:
            env = {
                k: re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", str(v))  # compose's ${VAR:-default}
                for k, v in compose["services"][name]["environment"].items()
            }
            assert json.loads(env["SIMPLETRACK_ZENOH__CONNECT"]) == ["tcp/zenoh-router:7447"]
            metrics_port = free_port()
            env |= {
                "SIMPLETRACK_ZENOH__CONNECT": json.dumps([endpoint]),
                "SIMPLETRACK_METRICS_HOST": "127.0.0.1",
                "SIMPLETRACK_METRICS_PORT": str(metrics_port),
                "SIMPLETRACK_STATE_DIR": str(tmp_path / name),
            }
            log = tmp_path / f"{name}.log"
            with log.open("wb") as out:
                proc = subprocess.Popen(
                    [sys.executable, "-m", "simpletrack.cli.main", "serve"],
                    cwd=ROOT,
                    env={**_clean_environ(), **env},
                    stdout=out,
                    stderr=out,
                )
            procs[name] = (proc, metrics_port)
        for name, (proc, port) in procs.items():
            log = tmp_path / f"{name}.log"
            wait_for(lambda p=proc, q=port, g=log: _ready(p, q, g), 60, f"{name} ready")  # type: ignore[misc]
        # The command docs/DEPLOY.md gives for feeding the compose stack.
        summary = tmp_path / "demo.json"
        command = "demo --service external --mode client --connect {} --duration 3 --no-live"
        argv = [*command.format(endpoint).split(), "--json", str(summary)]
        demo = subprocess.run(
            [sys.executable, "-m", "simpletrack.cli.main", *argv],
            cwd=ROOT,
            env=_clean_environ(),
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert demo.returncode == 0, demo.stdout + demo.stderr
        frames = json.loads(summary.read_text())["frames"]
        assert frames["published"] > 0
        assert frames["tracked"] == frames["published"] and frames["rejected"] == {}
        streams = sorted(json.loads(summary.read_text())["streams"])
        tracked = {name: _tracked(port) for name, (_, port) in procs.items()}
        assert sum(tracked.values()) == frames["published"], tracked  # each frame once
        assert sum(1 for n in tracked.values() if n > 0) >= 2, tracked  # shared, not copied
    finally:
        for proc, _ in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc, _ in procs.values():
            try:
                assert proc.wait(30) == 0
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise
        router.close()  # type: ignore[no-untyped-call]
    for stream in streams:  # every sensor snapshotted on SIGTERM, by the member that had it
        assert any((tmp_path / n / f"{stream}.snap").is_file() for n in names), stream


def _tracked(port: int) -> float:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        text = r.read().decode()
    return sum(
        float(line.rpartition(" ")[2])
        for line in text.splitlines()
        if line.startswith("simpletrack_frames_tracked_total")
    )


def _clean_environ() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("SIMPLETRACK_")}


def _ready(proc: subprocess.Popen[bytes], port: int, log: Path) -> bool:
    if proc.poll() is not None:
        raise AssertionError(f"serve exited with {proc.returncode}:\n{log.read_text()}")
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=2) as r:
            return int(r.status) == 200
    except OSError:
        return False
