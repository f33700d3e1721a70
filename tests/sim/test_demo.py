"""``simpletrack demo``: runs on its own (no router, no data), ends cleanly and reports."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simpletrack.sim.demo import DemoOptions, DemoResult, FleetDemo, ServiceMode
from simpletrack.sim.simulator import SimConfig
from tests.service_helpers import ROOT

pytestmark = pytest.mark.zenoh
MAIN = [sys.executable, "-c", "import sys; from simpletrack.cli.main import main; sys.exit(main())"]
ENV = {**os.environ, "NO_COLOR": "1"}


def test_demo_duration_5_exits_0_with_a_summary(tmp_path: Path) -> None:
    summary = tmp_path / "demo.json"
    proc = subprocess.run(
        [*MAIN, "demo", "--duration", "5", "--json", str(summary)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=ENV,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    assert "simpletrack demo: duration" in out
    assert "MOTA" in out and "tracks" in out and "latency" in out
    # The last line says what fusion adds: the fused tracks next to the per-sensor ones.
    last = out.strip().splitlines()[-2]  # the very last is "wrote ..."
    assert last.startswith("tracked ") and "frames · fused p50 " in last, last
    assert "(per-sensor together " in last and "ids per object (together " in last, last
    assert "detections alone" in out and "truth: every object in view of any" in out
    s = json.loads(summary.read_text())
    frames = s["frames"]
    # 3 vehicles of a 10 Hz lidar and a 15 Hz camera for 5 s, every frame answered on its
    # sensor's key (the demo's service publishes each sensor's own tracks too).
    assert frames["published"] >= 0.8 * 5 * 25 * 3
    assert (
        frames["tracked"] + sum(frames["rejected"].values()) + frames["unanswered"]
        == frames["published"]
    )
    assert frames["tracked"] >= 0.95 * frames["published"]
    assert frames["fused_messages"] >= 0.8 * frames["published"]  # the camera's first watched
    assert s["tracks"]["active"] > 0 and s["tracks"]["ids_seen"] > 0
    rows = s["rows"]
    # Every row scored on the same stamps against the same truth.
    assert len({r["gt"] for r in rows.values()}) == 1 and rows["fused"]["gt"] > 500
    assert len({r["frames"] for r in rows.values()}) == 1
    # The fused tracks beat each sensor alone and the sensors' tracks taken together, and
    # give fewer ids per object (measured over 5 s, seed 0: MOTA fused 0.62, lidar 0.62,
    # camera 0.03, together 0.36; 1.25 ids per object against 2.41).
    fused, together = rows["fused"], rows["together"]
    assert fused["mota"] > together["mota"] + 0.1, rows
    assert fused["mota"] > rows["camera"]["mota"] + 0.3, rows
    assert fused["ids_per_object"] < together["ids_per_object"], rows
    assert s["summary"] == last
    assert s["latency_ms"]["fused_p50"] is not None and s["latency_ms"]["p50"] is not None


def test_ctrl_c_ends_the_demo_cleanly_with_its_summary() -> None:
    proc = subprocess.Popen(
        [*MAIN, "demo", "--vehicles", "1"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()  # not a terminal: one line once the fleet is running
    assert line.startswith("demo: running:"), line
    time.sleep(1.5)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, out + err
    assert "simpletrack demo: interrupted" in out and "MOTA" in out
    assert "Traceback" not in err


def test_broken_frames_are_rejected_and_counted() -> None:
    demo = FleetDemo(
        DemoOptions(
            sim=SimConfig(seed=2, vehicles=1),
            duration=2.0,
            inject_errors=0.3,
            service=ServiceMode.INPROCESS,
        )
    )
    result = demo.run()
    rejected = result.stats.rejected
    assert set(rejected) == {"non_finite"}
    assert rejected["non_finite"] > 3
    st = result.stats
    assert st.tracked + rejected["non_finite"] + result.unanswered == st.sent
    assert st.tracked > 10


def test_bad_arguments_are_one_line_errors(capsys: pytest.CaptureFixture[str]) -> None:
    from simpletrack.cli.main import main

    for args, word in (
        (["--duration", "-1"], "--duration"),
        (["--vehicles", "0"], "--vehicles"),
        (["--inject-errors", "2"], "--inject-errors"),
        (["--service", "external"], "--connect"),
    ):
        assert main(["demo", *args]) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("simpletrack demo: error: ") and word in err, err
        assert len(err.strip().splitlines()) == 1, err


def test_the_tracker_settings_sweep_refuses_the_demos_seed(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from simpletrack.sim.sweep import main

    with pytest.raises(SystemExit) as exc:
        main(["--seed", "0"])
    assert exc.value.code == 2
    assert "seed 0 is the seed the demo reports" in capsys.readouterr().err


def test_the_demo_serves_its_fleet_in_the_browser_view_and_loses_no_frame() -> None:
    """The view is a planner of its own: every sensor's tracks, detections and field of view
    appear while the demo runs, and its detections subscriber never passes for the service
    (the first frames were once sent before the service listened, and went unanswered)."""
    import urllib.request

    seen: list[dict[str, object]] = []

    def on_tick(result: DemoResult) -> None:
        if result.view_url and result.elapsed > 2.0 and not seen:
            url = result.view_url.split("?")[0] + "state.json"
            with urllib.request.urlopen(url, timeout=5) as reply:
                seen.append(json.loads(reply.read()))

    demo = FleetDemo(DemoOptions(sim=SimConfig(seed=3, vehicles=2), duration=4.0, view_port=0))
    result = demo.run(on_tick)
    assert result.view_url is not None and "?sensor=veh00/@vehicle" in result.view_url
    assert seen, "the view never answered"
    sensors = seen[0]["sensors"]
    assert isinstance(sensors, dict)
    assert set(sensors) == {f"veh0{v}/{s}" for v in range(2) for s in ("lidar", "front")}
    vehicles = seen[0]["vehicles"]
    assert isinstance(vehicles, dict)
    assert {f"veh0{v}/@vehicle" for v in range(2)} <= set(vehicles)
    for name, s in sensors.items():
        assert s["tracks"], name
        assert s["detections"]["boxes"], name
        assert s["fov"]["deg"] == (360.0 if name.endswith("lidar") else 100.0)
    assert result.unanswered == 0
    assert result.stats.tracked == result.stats.sent


def test_a_demo_recording_opens_in_mcap_and_replays_to_the_same_tracks(tmp_path: Path) -> None:
    """``demo --mcap`` records what travelled; ``replay mcap`` of its detections into a fresh
    service with the demo's tracker settings gives the tracks the demo's planner got."""
    from simpletrack.sim.demo_tracker import write_class_overrides
    from tests.cli.test_record_mcap import kill_leftovers, read, record, tracks_by_frame
    from tests.cli.test_replay_record import cli
    from tests.service_helpers import start_service

    out = tmp_path / "demo.mcap"
    proc = subprocess.run(
        [*MAIN, "demo", "--duration", "3", "--vehicles", "1", "--no-view", "--mcap", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=120, env=ENV,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"wrote {out}" in proc.stdout
    (summary, metadata), messages = read(out)
    assert summary is not None and metadata["simpletrack"]["prefix"] == "fleet"
    detections = [m for _, c, m in messages if c.topic.endswith("/detections")]
    want = tracks_by_frame(messages)
    assert len(want) == len(detections) > 40  # every frame answered, and recorded

    overrides = write_class_overrides()
    state = tmp_path / "state"
    state.mkdir()
    svc = start_service(
        tmp_path, "--preset", "wod", "--class-overrides", str(overrides),
        "--backpressure", "block", "--state-dir", str(state), instance="demo-replay",
    )  # fmt: skip
    try:
        again = tmp_path / "again.mcap"
        rec = record(
            "--format", "mcap", "--out", str(again), "--connect", svc.endpoint,
            "--what", "tracks", "--frames", str(len(want)), "--no-foxglove",
        )  # fmt: skip
        done = cli("replay", "mcap", str(out), "--rate", "max", "--connect", svc.endpoint)
        assert done.returncode == 0, done.stdout + done.stderr
        code, _, err = rec.wait()
        assert code == 0, err
    finally:
        kill_leftovers()
        svc.stop()
        overrides.unlink()
    got = tracks_by_frame(read(again)[1])
    assert sorted(got) == sorted(want)
    for frame, (ids, classes, center, size, yaw, state_codes) in want.items():
        g_ids, g_classes, g_center, g_size, g_yaw, g_state = got[frame]
        assert (g_ids, g_classes, g_state) == (ids, classes, state_codes), frame
        assert (g_center == center).all() and (g_size == size).all() and (g_yaw == yaw).all()
    assert sum(len(v[0]) for v in want.values()) > 100  # the demo's world was tracked
