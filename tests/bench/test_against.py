"""``bench core --against REF``: a real, tiny comparison against HEAD (both sides run, each
with its own code, and the temporary tree is gone afterwards), the refusals a user meets
(no such revision, no git checkout), and the table when one side lacks a figure. Figures
are never asserted: only the structure a reader relies on."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from simpletrack.bench import against
from simpletrack.bench.against import AgainstError, against_table, compare_docs
from simpletrack.cli.main import main

ROOT = against.checkout_root()
DATA = ROOT.parent / "shared" / "data"


def _in_git_checkout() -> bool:
    if shutil.which("git") is None:
        return False
    top = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--show-toplevel"], capture_output=True, text=True
    )
    return top.returncode == 0 and Path(top.stdout.strip()).resolve() == ROOT


needs_git = pytest.mark.skipif(not _in_git_checkout(), reason="not run from a git checkout")


def _run(tmp_path: Path, *load: str) -> tuple[dict[str, Any], str]:
    out = tmp_path / "against.json"
    rc = main(["bench", "core", *load, "--against", "HEAD", "--rounds", "1", "--json", str(out)])
    assert rc == 0
    return json.loads(out.read_text()), out.name


def _check_both_sides_ran(doc: dict[str, Any], rounds: int) -> None:
    ref_tree = Path(doc["ref_tree"])
    assert not ref_tree.exists()  # removed after the runs
    assert not ref_tree.is_relative_to(ROOT)  # and never inside the checkout
    assert doc["order"] == ["this", "ref"] * rounds
    assert doc["ref_compile_seconds"] >= 0  # REF's kernels compiled once, before its rounds
    head = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert doc["against"]["revision"] == head
    this, ref = doc["sides"]["this"], doc["sides"]["ref"]
    assert this["root"] == str(ROOT) and ref["root"] == str(ref_tree)
    assert len(this["runs"]) == len(ref["runs"]) == rounds
    # Each side's process imported its own tree's package, not the other's.
    for run in this["runs"]:
        assert Path(run["imported"]["core"]).is_relative_to(ROOT / "service")
        assert Path(run["imported"]["bench"]).is_relative_to(ROOT)
    for run in ref["runs"]:
        assert Path(run["imported"]["core"]).is_relative_to(ref_tree / "service")
        assert Path(run["imported"]["bench"]).is_relative_to(ref_tree)
        assert run["benchmark"] == "core"


@needs_git
def test_against_head_on_the_synthetic_sweep(tmp_path: Path, capsys: Any) -> None:
    load = ("--scenes", "0", "--kitti-sequences", "0", "--sizes", "10,20", "--sweep-frames", "3")
    doc, _ = _run(tmp_path, *load)
    _check_both_sides_ran(doc, rounds=1)
    assert doc["options_passed"][doc["options_passed"].index("--sizes") + 1] == "10,20"
    rows = {r["figure"]: r for r in doc["figures"]}
    for name in ("sweep 10 boxes p50", "sweep 20 boxes p50"):
        r = rows[name]
        assert r["kind"] == "time"
        assert r["this"] > 0 and r["ref"] > 0
        assert r["ratio"] == pytest.approx(r["ref"] / r["this"], rel=1e-3)
    assert rows["sweep growth exponent"]["ratio"] is None  # neither better when larger
    printed = capsys.readouterr().out
    header = next(line for line in printed.splitlines() if "figure" in line)
    assert "this code" in header and "HEAD" in header and "ratio" in header
    assert "REF/this for times" in printed
    assert "sweep 20 boxes p50" in printed


@needs_git
@pytest.mark.skipif(not (DATA / "kitti" / "detections").is_dir(), reason="no KITTI data")
def test_against_head_on_kitti(tmp_path: Path) -> None:
    load = ("--data", str(DATA), "--scenes", "0", "--kitti-sequences", "1", "--sizes", "none")
    doc, _ = _run(tmp_path, *load)
    _check_both_sides_ran(doc, rounds=1)
    rows = {r["figure"]: r for r in doc["figures"]}
    r = rows["kitti_car frames/s"]
    assert r["kind"] == "rate"
    assert r["ratio"] == pytest.approx(r["this"] / r["ref"], rel=1e-3)
    assert not any(name.startswith("sweep") for name in rows)


@needs_git
def test_an_unknown_revision_is_a_one_line_error(capsys: Any) -> None:
    rc = main(["bench", "core", "--sizes", "none", "--scenes", "0", "--kitti-sequences", "0",
               "--against", "no-such-revision-0x"])  # fmt: skip
    assert rc != 0
    err = capsys.readouterr().err
    assert "'no-such-revision-0x': not a git revision" in err
    assert "Traceback" not in err


def test_outside_a_git_checkout_the_option_says_so(tmp_path: Path) -> None:
    if shutil.which("git") is None:
        pytest.skip("no git")
    with pytest.raises(AgainstError, match="needs this code in a git checkout"):
        against.compare("core", [], "HEAD", 1, progress=lambda _: None, root=tmp_path)


def _core_doc(fps: float | None, with_stage: bool) -> dict[str, Any]:
    stages = {"ms_per_frame": {"nms": 0.5, **({"cost_matrix": 1.0} if with_stage else {})}}
    return {
        "loads": {"kitti_car": {"frames_per_s": fps, "latency": {"p50_ms": 2.0}, "stages": stages}},
        "sweep": None,
    }


def test_a_figure_one_side_lacks_is_a_dash() -> None:
    rows = compare_docs("core", [_core_doc(200.0, True)], [_core_doc(100.0, False)])
    by_name = {r["figure"]: r for r in rows}
    assert by_name["kitti_car frames/s"]["ratio"] == pytest.approx(2.0)  # this/REF
    assert by_name["kitti_car p50"]["ratio"] == pytest.approx(1.0)  # REF/this
    lacking = by_name["kitti_car stage cost_matrix"]
    assert lacking["this"] == 1.0 and lacking["ref"] is None and lacking["ratio"] is None
    assert "kitti_car p99" in by_name and by_name["kitti_car p99"]["this"] is None
    doc = {
        "benchmark": "bench core",
        "against": {"ref": "old", "revision": "0" * 40},
        "rounds": 1,
        "order": ["this", "ref"],
        "sides": {"this": {"label": "this code"}, "ref": {"label": "old (0000000)"}},
        "figures": rows,
    }
    line = next(x for x in against_table(doc).splitlines() if "stage cost_matrix" in x)
    assert line.split()[-3:] == ["1.000", against.MISSING, against.MISSING]


def test_medians_leave_out_rounds_without_the_figure() -> None:
    this = [_core_doc(v, True) for v in (100.0, None, 300.0, 200.0)]
    ref = [_core_doc(v, True) for v in (50.0, 100.0, 150.0, None)]
    row = next(r for r in compare_docs("core", this, ref) if r["figure"] == "kitti_car frames/s")
    assert row["this"] == 200.0 and row["ref"] == 100.0
    assert row["this_rounds"] == [100.0, None, 300.0, 200.0]


@needs_git
@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_an_interrupted_comparison_removes_refs_tree(tmp_path: Path, how: str) -> None:
    # TMPDIR: the run's temporary directory lands here, where nothing else runs.
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "bench", "core", "--scenes", "0",
           "--kitti-sequences", "0", "--sizes", "10,20,50", "--sweep-frames", "200",
           "--against", "HEAD", "--rounds", "3"]  # fmt: skip
    proc = subprocess.Popen(
        cmd,
        env=env,
        start_new_session=True,  # a group of its own, as a terminal's Ctrl-C reaches
        # a background child inherits SIGINT ignored from a non-interactive shell
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob("simpletrack-against-*/ref/service")):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode != 0
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--server-only"], "--server-only needs --against REF"),
        (["--against", "HEAD", "--profile", "p"], "--profile combines with --against only with"),
    ],
)
def test_server_only_and_profile_refusals_name_what_is_missing(
    capsys: Any, extra: list[str], message: str
) -> None:
    rc = main(["bench", "service", "--source", "synthetic", "--sensors", "1", *extra])
    assert rc != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_server_only_runs_this_bench_with_the_other_side_s_service_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    this = against.Side("this", "this code", tmp_path / "a", None, False)
    ref = against.Side("ref", "REF", tmp_path / "b", "0" * 40, False)
    monkeypatch.setenv(against.SERVER_PATH_ENV, "stray")  # a caller's never leaks into a run
    plain = against._env(ref)
    assert plain["PYTHONPATH"] == ref.pythonpath() and against.SERVER_PATH_ENV not in plain
    mixed = against._env(this, server=ref)
    assert mixed["PYTHONPATH"] == this.pythonpath()
    assert mixed[against.SERVER_PATH_ENV] == ref.pythonpath()
    assert str(tmp_path / "b" / "service") in mixed[against.SERVER_PATH_ENV].split(os.pathsep)


def test_the_interpreter_lock_per_frame_is_compared_when_both_sides_profiled_it() -> None:
    def doc(gil: float | None) -> dict[str, Any]:
        step = {"kind": "tracker", "sensors": 60, "latency": {"p50_ms": 1.0, "p99_ms": 2.0}}
        if gil is not None:
            step["profile"] = {"gil_ms_per_frame": gil}
        return {"steps": [step], "capacity": {}}

    rows = {r["figure"]: r for r in compare_docs("service", [doc(0.25)], [doc(0.5)])}
    lock = rows["tracker 60 sensors interpreter lock per frame"]
    assert lock["ratio"] == pytest.approx(2.0)
    unprofiled = {r["figure"] for r in compare_docs("service", [doc(None)], [doc(None)])}
    assert not any("interpreter lock" in name for name in unprofiled)
