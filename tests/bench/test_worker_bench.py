"""``simpletrack bench worker``: a real service's worker fed in-process. Figures are never
asserted; what a reader relies on is: every frame went the whole way (tracked and published,
nothing refused), every stage of the path was reached once per frame, and a stage the worker
no longer has fails the run instead of hiding in "other"."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simpletrack.bench import worker as worker_bench
from simpletrack.bench.stages import MissingStageTarget
from simpletrack.cli.main import main


def test_every_frame_is_tracked_published_and_timed_by_stage(tmp_path: Path) -> None:
    out = tmp_path / "worker.json"
    argv = ["bench", "worker", "--source", "synthetic", "--synthetic-boxes", "20"]
    rc = main([*argv, "--sensors", "3", "--frames", "4", "--warmup", "1", "--json", str(out)])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["frames"] == 12 and doc["shimmed_frames"] == 12
    assert doc["published"] == 12  # each frame answered on its tracks key
    calls = doc["calls_per_frame"]
    for stage in ("decode", "plausibility", "to_core", "step", "to_wire", "encode", "put"):
        assert calls[stage] == 1, stage  # reached once a frame: the shims still fit the worker
    stages = doc["stages_us_per_frame"]
    assert set(stages) == {s for s, _, _ in worker_bench.STAGES} | {worker_bench.OTHER}
    assert all(v >= 0 for v in stages.values())
    assert doc["cpu_us_per_frame"]["median"] > 0


def test_a_stage_the_worker_no_longer_has_fails_before_the_service_starts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    gone = ("decode", "simpletrack.server.worker", "decode_frame_somehow")
    monkeypatch.setattr(worker_bench, "STAGES", (*worker_bench.STAGES, gone))
    opts = worker_bench.WorkerOptions(sensors=1, frames=2, warmup=0, source="synthetic")
    with pytest.raises(MissingStageTarget, match="decode_frame_somehow"):
        worker_bench.run_worker_bench(opts, progress=lambda _: None)


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--sensors", "0"], "bench worker: sensors must be in 1..10000, got 0"),
        (["--frames", "1"], "bench worker: frames must be in 2..100000, got 1"),
        (["--synthetic-boxes", "0"], "synthetic_boxes must be in 1..10000, got 0"),
    ],
)
def test_mistakes_are_one_line_errors(
    args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "worker", "--source", "synthetic", *args]) == 2
    assert says in capsys.readouterr().err


def test_bad_options_are_refused_with_the_value() -> None:
    with pytest.raises(ValueError, match="source must be nuscenes or synthetic, got 'kitti'"):
        worker_bench.WorkerOptions(source="kitti")
    with pytest.raises(ValueError, match="needs data"):
        worker_bench.WorkerOptions(source="nuscenes", data=None)
