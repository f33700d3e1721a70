"""``simpletrack bench``: each benchmark runs for about a second with tiny sizes and writes its
JSON and PNGs, so it cannot rot. Figures are never asserted (machines are shared and noisy);
what is asserted is what a reader of the output relies on: every load, size and step is
there, the stage shims still reach the functions the tracker calls, and the counts add up.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from simpletrack.bench import loadgen
from simpletrack.bench.core import synthetic_stream
from simpletrack.bench.service import gil_ms_per_frame, summarize_profile
from simpletrack.bench.stages import STAGES, TARGETS, MissingStageTarget, StageTimer
from simpletrack.cli.bench import drawn
from simpletrack.cli.main import main
from simpletrack.core.config import preset
from simpletrack.core.tracker import Tracker
from simpletrack.wire import encode_detection_frame

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
PNG = b"\x89PNG\r\n\x1a\n"


def is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG


def test_core_sweep_writes_json_and_plot(tmp_path: Path) -> None:
    out = tmp_path / "core.json"
    rc = main(
        [
            "bench",
            "core",
            "--scenes",
            "0",
            "--kitti-sequences",
            "0",
            "--sizes",
            "5,20,40",
            "--sweep-frames",
            "3",
            "--json",
            str(out),
            "--plot-dir",
            str(tmp_path),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    sweep = doc["sweep"]
    assert [p["boxes"] for p in sweep["points"]] == [5, 20, 40]
    assert all(p["latency"]["count"] == 3 for p in sweep["points"])
    assert np.isfinite(sweep["exponent"])
    assert doc["machine_before"]["cpus"] >= 1
    assert is_png(tmp_path / "core_scaling.png")


def test_without_matplotlib_the_figures_still_reach_the_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bare host without the plot extra (scripts/bench_host.sh): the run's JSON is written,
    the plots are not, and one line says what to install; it lost a whole run before."""
    for name in [m for m in sys.modules if m.split(".")[0] == "matplotlib"]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib... fails
    out = tmp_path / "core.json"
    load = ["--scenes", "0", "--kitti-sequences", "0", "--sizes", "5,20", "--sweep-frames", "3"]
    rc = main(["bench", "core", *load, "--json", str(out), "--plot-dir", str(tmp_path)])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert [p["boxes"] for p in doc["sweep"]["points"]] == [5, 20] and doc["plots"] == []
    assert not list(tmp_path.glob("*.png"))
    assert "no plots drawn: needs the plot extra" in capsys.readouterr().err
    with pytest.raises(ModuleNotFoundError):  # any other missing module is a real error
        drawn(lambda: [Path(str(__import__("simpletrack_no_such_module")))])


def test_stage_shims_reach_every_stage_the_tracker_uses() -> None:
    """If the core renames a function the shims wrap, its stage goes silent: catch that here."""
    config = preset("nuscenes")
    frames = synthetic_stream(12, 4)
    fused, staged = Tracker(config), Tracker(config)
    staged._fused = False  # the path of gated frames, frames after a gap, L2 classes
    with StageTimer() as timer:
        for f in frames:
            fused.step(f)
    assert timer.calls["step"] == len(frames)
    assert timer.calls["nms"] == timer.calls["predict"] == timer.calls["advance"] == 0
    with StageTimer() as timer:
        for f in frames:
            staged.step(f)
    assert timer.calls["nms"] == timer.calls["predict"] == len(frames)
    assert timer.calls["step"] == 0
    # From the second frame on there are tracks to match and correct.
    for stage in ("cost_matrix", "assignment", "advance"):
        assert timer.calls[stage] >= len(frames) - 1, (stage, timer.calls)
    assert set(timer.seconds) == set(STAGES)
    # Removed on exit: the tracker runs unshimmed again.
    from simpletrack.core import tracker as tracker_module

    assert not hasattr(tracker_module.nms, "__wrapped__")


@pytest.mark.parametrize(
    ("target", "needle"),
    [
        (("cost_matrix", "simpletrack.core.tracker", "Tracker._pair_distances"), "does not exist"),
        (("nms", "simpletrack.core.nowhere", "nms"), "no module simpletrack.core.nowhere"),
        (("advance", "simpletrack.core.config", "PRESETS"), "not a plain function"),
    ],
)
def test_a_stage_whose_target_is_missing_fails_naming_stage_and_target(
    target: tuple[str, str, str], needle: str
) -> None:
    with pytest.raises(MissingStageTarget) as info:
        StageTimer((*TARGETS, target))
    assert f"stage {target[0]!r}" in str(info.value) and needle in str(info.value)
    assert target[2].split(".")[-1] in str(info.value) or target[1] in str(info.value)


def test_bench_core_fails_before_timing_when_a_stage_target_is_gone(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from simpletrack.bench import stages

    gone = ("cost_matrix", "simpletrack.core.tracker", "Tracker._pair_distances")
    monkeypatch.setattr(stages, "TARGETS", (*stages.TARGETS, gone))
    out = tmp_path / "core.json"
    argv = ["bench", "core", "--scenes", "0", "--kitti-sequences", "0", "--sizes", "5"]
    with pytest.raises(
        MissingStageTarget, match=r"stage 'cost_matrix': .*Tracker\._pair_distances"
    ):
        main([*argv, "--sweep-frames", "3", "--json", str(out)])
    assert not out.exists()


def test_stage_shims_do_not_change_the_output() -> None:
    config = preset("nuscenes")
    frames = synthetic_stream(15, 5, seed=3)
    plain, shimmed = Tracker(config), Tracker(config)
    for f in frames:
        a = plain.step(f)
        with StageTimer():
            b = shimmed.step(f)
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.boxes.params, b.boxes.params)


@pytest.mark.data
def test_core_on_real_data_reports_every_load_and_the_reference_ratio(tmp_path: Path) -> None:
    if not (DATA / "nuscenes").is_dir() or not (DATA / "kitti").is_dir():
        pytest.skip(f"needs {DATA}/nuscenes and {DATA}/kitti")
    out = tmp_path / "core.json"
    rc = main(
        [
            "bench",
            "core",
            "--data",
            str(DATA),
            "--scenes",
            "1",
            "--kitti-sequences",
            "1",
            "--sizes",
            "none",
            "--json",
            str(out),
            "--plot-dir",
            str(tmp_path),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    assert set(doc["loads"]) == {"nuscenes", "nuscenes_parity", "kitti_car", "kitti_all"}
    nu = doc["loads"]["nuscenes"]
    assert nu["classes"] == list(preset("nuscenes").class_names)
    assert nu["frames"] == nu["stages"]["frames"] > 0
    assert nu["stages"]["calls"]["step"] == nu["frames"]  # every frame: one compiled call
    assert doc["loads"]["kitti_all"]["classes"] == ["Car", "Pedestrian", "Cyclist"]
    assert doc["reference"]["nuscenes"]["median_speedup"] > 0
    assert doc["reference"]["nuscenes_parity"]["median_speedup"] > 0
    assert doc["sweep"] is None
    assert is_png(tmp_path / "core_stages.png")


def test_mistakes_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = [
        ["core", "--sizes", "10,x"],
        ["core", "--sizes", "50,10"],
        ["core", "--scenes", "3", "--data", str(tmp_path / "nowhere")],
        ["core", "--sweep-frames", "1", "--scenes", "0", "--kitti-sequences", "0"],
        ["core", "--options", "ctra,warp", "--scenes", "0", "--kitti-sequences", "0"],
        ["core", "--options", "ctra", "--against", "main", "--scenes", "0"],
        ["service", "--sensors", "0"],
        ["service", "--seconds", "0"],
        ["service", "--source", "nuscenes", "--data", str(tmp_path / "nowhere")],
        ["service", "--profile-gil"],
    ]
    for args in bad:
        assert main(["bench", *args]) == 2, args
        err = capsys.readouterr().err.strip()
        assert err.startswith("simpletrack bench: error:") and "\n" not in err, err


def test_an_option_times_the_load_again_with_its_changes_in_every_class() -> None:
    from simpletrack.bench.core import Load, _with_options

    config = preset("kitti")
    load = Load("kitti_all", config, config.class_names, [synthetic_stream(5, 8)])
    out = _with_options(load, ["ctra_immortal_gated", "ca"], lambda _: None)
    assert list(out) == ["kitti_all+ctra_immortal_gated", "kitti_all+ca"]
    assert out["kitti_all+ca"]["frames"] == 8
    assert out["kitti_all+ca"]["stages"]["calls"]


def test_load_generator_payload_is_the_codec_s_bytes() -> None:
    boxes = loadgen.synthetic_box_arrays(7, seed=1)[0]
    cached = loadgen.box_columns(boxes)
    fast = loadgen.detection_payload("v0", "s0003", 42, 1_700_000_000_000_000_000, cached)
    slow = encode_detection_frame(
        vehicle="v0",
        sensor="s0003",
        seq=42,
        stamp_ns=1_700_000_000_000_000_000,
        frame_id=loadgen.FRAME_ID,
        boxes=boxes,
    )
    assert fast == slow
    assert loadgen.peek(fast, "seq") == 42
    assert loadgen.peek(fast, "sensor") == "s0003"


def test_profile_summary_ranks_functions(tmp_path: Path) -> None:
    raw = tmp_path / "p.txt"
    raw.write_text(
        'process 1:"python";thread (0x1);run (service/simpletrack/server/worker.py:150);step (core/tracker.py:60) 30\n'
        'process 1:"python";thread (0x1);run (service/simpletrack/server/worker.py:150);decode (schemas/simpletrack/wire/codec.py:9) 10\n'
    )
    prof = summarize_profile(raw)
    assert prof["samples"] == 40
    assert prof["self"][0] == ("step (tracker.py)", 0.75)
    assert dict(prof["inclusive"])["run (worker.py)"] == 1.0
    assert prof["roles"] == [("other", 1.0)]


def test_gil_time_per_frame_is_the_held_share_of_the_window_over_its_frames() -> None:
    # 600 of 2,400 samples (12 s at 200 Hz) held the lock: a quarter of a 12 s window, 7,200
    # frames in it (60 sensors at 10 Hz): 3 s / 7,200 = 0.417 ms a frame.
    assert gil_ms_per_frame(600, 12, 12.0, 7200) == pytest.approx(0.4167, abs=1e-4)
    assert gil_ms_per_frame(0, 12, 12.0, 7200) == 0.0
    assert gil_ms_per_frame(10, 12, 12.0, 0) > 0  # no frames: no division by zero


@pytest.mark.zenoh
def test_service_bench_one_short_step_each(tmp_path: Path) -> None:
    out = tmp_path / "service.json"
    rc = main(
        [
            "bench",
            "service",
            "--sensors",
            "2",
            "--seconds",
            "1",
            "--warmup",
            "0.3",
            "--source",
            "synthetic",
            "--synthetic-boxes",
            "20",
            "--json",
            str(out),
            "--plot-dir",
            str(tmp_path),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    kinds = [(s["kind"], s["sensors"]) for s in doc["steps"]]
    assert kinds == [("tracker", 2), ("echo", 2)]
    for step in doc["steps"]:
        # Every frame is accounted for: answered, refused, or never answered.
        assert step["received"] + step["refused"] + step["lost"] == step["sent"] == 2 * 13
        assert step["received"] > 0
        assert step["latency"]["count"] > 0
    tracker = doc["steps"][0]
    assert tracker["metrics"]["received"] == tracker["sent"]
    assert doc["capacity"]["goal_streams_per_core"] == 500
    assert is_png(tmp_path / "service_latency_cdf.png")
    assert is_png(tmp_path / "service_capacity.png")
