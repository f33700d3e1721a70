"""``simpletrack bench scale``: the fault arithmetic on made-up answers, and a tiny real run
(1 and 2 members, 2 sensors, 2 s, synthetic frames; ~30 s) whose JSON, table and PNG carry
every field a reader relies on. Figures are never asserted: they are the machine's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simpletrack.bench.scale import fault_figures
from simpletrack.cli.main import main

PNG = b"\x89PNG\r\n\x1a\n"
MS = 1_000_000
FAULT = 10_000 * MS


def test_fault_figures_time_the_victim_s_sensors_and_count_frames_around_the_fault() -> None:
    # Sensor 0: last served by m1 (the victim), next answered by m0 40 ms after the fault.
    # Sensor 1: last served by m0: not the victim's, not timed.
    # Sensor 2: last served by m1, then only m1 again (drain) and nobody else: never recovered.
    sent = [[FAULT - 3000 * MS, FAULT - 100 * MS, FAULT + 20 * MS] for _ in range(3)]
    answers = [
        (0, 0, "m0", FAULT - 2990 * MS),
        (0, 0, "m1", FAULT - 2980 * MS),  # frame 0 of sensor 0 answered twice
        (0, 1, "m1", FAULT - 90 * MS),
        (0, 2, "m0", FAULT + 40 * MS),
        (1, 0, "m1", FAULT - 2990 * MS),
        (1, 1, "m0", FAULT - 95 * MS),
        (1, 2, "m0", FAULT + 30 * MS),
        (2, 0, "m0", FAULT - 2990 * MS),
        (2, 1, "m1", FAULT - 80 * MS),
        (2, 1, "m1", FAULT + 5 * MS),  # a late duplicate from the victim itself
    ]
    # Sensor 3: the victim's last frame published again by the member that took it over.
    sent.append([FAULT - 3000 * MS, FAULT - 100 * MS, FAULT + 20 * MS])
    answers += [
        (3, 0, "m0", FAULT - 2990 * MS),
        (3, 1, "m1", FAULT - 90 * MS),
        (3, 1, "m0", FAULT + 50 * MS),
        (3, 2, "m0", FAULT + 60 * MS),
    ]
    f = fault_figures(answers, sent, FAULT, "m1")
    assert f["sensors_served_by_victim"] == 3
    assert f["max_ms"] == 50.0 and f["median_ms"] == 45.0
    # Their first frame put after the fault (seq 2, put 20 ms after it): answered 20 ms
    # after its put for sensor 0 (by m0 at +40), 40 ms for sensor 3 (at +60); sensor 2's
    # never was.
    assert f["first_after_max_ms"] == 40.0 and f["first_after_median_ms"] == 30.0
    assert f["first_after_slowest"] == {
        "sensor": 3,
        "seq": 2,
        "put_after_fault_ms": 20.0,
        "answered_after_put_ms": 40.0,
        "by": "m0",
    }
    assert f["not_recovered"] == 1
    # Frames put from 1 s before the fault on: seq 1 and 2 of each sensor.
    assert f["window_frames"] == 8
    assert f["zero_answers"] == 1  # sensor 2, seq 2
    assert f["zero_answers_refused"] == 0
    assert f["unanswered"] == [
        {
            "sensor": 2,
            "seq": 2,
            "put_after_fault_ms": 20.0,
            "served_before": "m1",
            "moved": True,
            "next_answered": None,
            "refused": None,
        }
    ]
    assert f["republished"] == 1  # sensor 3, seq 1
    assert f["multiple_answers"] == 1  # sensor 2, seq 1
    # Before the window: seq 0 of each sensor, answered 2, 1, 1 and 1 times.
    assert f["answers_per_frame_before"] == pytest.approx(5 / 4, abs=0.01)


def test_an_unanswered_frame_refused_with_a_notice_is_told_apart() -> None:
    sent = [[FAULT - 100 * MS, FAULT + 20 * MS, FAULT + 40 * MS]]
    answers = [(0, 0, "m0", FAULT - 90 * MS)]
    refusals = [(0, 1, "dropped_queue_full"), (0, 0, "dropped_queue_full")]
    f = fault_figures(answers, sent, FAULT, "m1", refusals=refusals)
    assert f["zero_answers"] == 2 and f["zero_answers_refused"] == 1
    assert [(u["seq"], u["refused"], u["moved"]) for u in f["unanswered"]] == [
        (1, "dropped_queue_full", False),
        (2, None, False),
    ]


def test_the_survivors_own_sensors_are_timed_before_and_after_the_fault() -> None:
    # Sensors 0 and 1 stay with m0 (bystanders), sensor 2 moves from the victim m1.
    sent = [[FAULT - 4000 * MS, FAULT - 200 * MS, FAULT + 100 * MS, FAULT + 3500 * MS]] * 3
    answers = [
        (0, 0, "m0", FAULT - 3000 * MS),  # put 4 s before: outside the 3 s span
        (0, 1, "m0", FAULT - 190 * MS),  # 10 ms
        (0, 2, "m0", FAULT + 400 * MS),  # 300 ms: held back while m0 took sensor 2
        (0, 2, "m0", FAULT + 900 * MS),  # a repeat: the first answer times it
        (0, 3, "m0", FAULT + 3510 * MS),  # put 3.5 s after: outside the span
        (1, 1, "m0", FAULT - 180 * MS),  # 20 ms; its seq 2 is never answered
        (2, 1, "m1", FAULT - 150 * MS),
        (2, 2, "m0", FAULT + 50 * MS),  # a moved sensor: not a bystander
    ]
    f = fault_figures(answers, sent, FAULT, "m1")
    assert f["bystander_sensors"] == 2
    assert f["bystander_p99_ms_before"] == pytest.approx(19.9, abs=0.05)
    assert f["bystander_p99_ms_after"] == 300.0 and f["bystander_max_ms_after"] == 300.0
    assert f["bystander_unanswered_after"] == 1


def test_warm_up_frames_and_unsent_frames_are_not_counted() -> None:
    sent = [[FAULT - 10 * MS, FAULT + 10 * MS, 0]]
    f = fault_figures([(0, 1, "m0", FAULT + 20 * MS)], sent, FAULT, "m1", warm_ticks=1)
    assert f["window_frames"] == 1 and f["zero_answers"] == 0
    assert f["sensors_served_by_victim"] == 0 and f["max_ms"] is None


@pytest.mark.zenoh
def test_a_tiny_scale_run_reports_capacity_and_both_faults(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(
        [
            *("bench", "scale", "--instances", "1,2", "--sensors", "2", "--duration", "2"),
            *("--warmup", "0.5", "--source", "synthetic", "--synthetic-boxes", "20"),
            *("--fault-sensors", "3", "--out", str(tmp_path)),
        ]
    )
    assert rc == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "| members | capacity | ratio to 1 |" in out
    assert "failover (SIGKILL)" in out and "handoff (SIGTERM)" in out
    assert captured.err.count("refused over the whole run: ") == 2  # the progress lines
    doc = json.loads((tmp_path / "scale.json").read_text())
    rows = {r["members"]: r for r in doc["members"]}
    assert set(rows) == {1, 2}
    for r in rows.values():
        assert [s["sensors"] for s in r["steps"]] == [2]
        assert all(s["members"] == r["members"] for s in r["steps"])
        assert "max_sensors_passing" in r["capacity"]
        assert "ratio_to_one" in r
    assert rows[1]["failover"] is None and rows[1]["handoff"] is None
    for fault in ("failover", "handoff"):
        f = rows[2][fault]
        assert f["victim"] == "m1" and f["members"] == 2 and f["sensors"] == 3
        # 2 s at 10 Hz, the fault at 1 s: the window holds every frame put in the last ~2 s.
        assert 3 * 10 <= f["window_frames"] <= 3 * 25
        assert 0 <= f["zero_answers"] + f["multiple_answers"] <= f["window_frames"]
        # Every unanswered frame named (with the refusal that answered it, if any).
        assert len(f["unanswered"]) == min(f["zero_answers"], 20)
        assert 0 <= f["zero_answers_refused"] <= f["zero_answers"]
        assert isinstance(f["refused_by_reason"], dict)
        served = f["sensors_served_by_victim"]
        assert 0 <= served <= 3
        timed = served - f["not_recovered"]
        assert (f["max_ms"] is None) == (timed == 0)
        if timed:
            assert 0 <= f["median_ms"] <= f["max_ms"]
    assert (tmp_path / "scale_capacity.png").read_bytes()[:8] == PNG


@pytest.mark.parametrize("fused", [False, True])
def test_fused_reaches_the_members_and_the_load(
    fused: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--fused` gives the load's vehicles and the members' fusion settings (launch_tracker
    and load_spec read ``bench.fused``): the run is stopped at its start."""
    from simpletrack.bench import scale
    from simpletrack.bench.generators import BenchError

    seen: list[scale.ScaleOptions] = []

    def start(opts: scale.ScaleOptions, progress: object = None) -> None:
        seen.append(opts)
        raise BenchError("stopped here")

    monkeypatch.setattr(scale, "run_scale", start)
    args = ["bench", "scale", "--instances", "2", "--sensors", "3", "--source", "synthetic"]
    assert main([*args, *(["--fused"] if fused else [])]) != 0  # the error, in one line
    assert [o.bench.fused for o in seen] == [fused]
