"""Where the commands that read datasets find them: ``--data``, else ``SIMPLETRACK_DATA``, and no
default folder (an installed user has no ``../shared/data``). Without either, each command says
in one line what to pass and what the folder must hold."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from simpletrack.bench import gaps
from simpletrack.cli import bench
from simpletrack.cli.main import main
from simpletrack.datasets import paths
from simpletrack.eval import track_nuscenes, tune

ROOT = Path(__file__).resolve().parents[2]

# argv of each `simpletrack` command that needs data, without --data; what the message names
COMMANDS = {
    "eval kitti": (["eval", "kitti"], paths.KITTI),
    "eval kitti --results": (["eval", "kitti", "--results", "out"], paths.KITTI),
    "eval kitti --cv": (["eval", "kitti", "--cv", "loso"], paths.KITTI),
    "track nuscenes": (["track", "nuscenes"], paths.NUSCENES),
    "bench core": (["bench", "core"], paths.DATA),
    "bench core --kitti-sequences 1": (
        ["bench", "core", "--scenes", "0", "--kitti-sequences", "1"],
        paths.DATA,
    ),
    "bench service": (["bench", "service"], paths.DATA),
    "bench scale": (["bench", "scale"], paths.DATA),
}


@pytest.fixture(autouse=True)
def no_data_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(paths.ENV, raising=False)


def one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err
    return err.strip()


def says_what_to_pass(line: str, layout: paths.Layout) -> None:
    assert "--data FOLDER" in line and "SIMPLETRACK_DATA" in line, line
    assert layout.holds in line, line
    assert "shared/data" not in line, line


@pytest.mark.parametrize("name", list(COMMANDS))
def test_without_data_a_command_says_in_one_line_what_to_pass(
    name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv, layout = COMMANDS[name]
    assert main(argv) == 2
    line = one_line(capsys.readouterr().err)
    says_what_to_pass(line, layout)
    assert line.startswith(f"simpletrack {argv[0]}: error: no {layout.what}: "), line


def test_the_messages_word_for_word(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", "kitti"]) == 2
    assert one_line(capsys.readouterr().err) == (
        "simpletrack eval: error: no KITTI data: pass --data FOLDER (with labels/, calib/, "
        "detections/pointrcnn/) or set SIMPLETRACK_DATA to the folder holding kitti/"
    )
    assert main(["bench", "service"]) == 2
    assert one_line(capsys.readouterr().err) == (
        "simpletrack bench: error: no data folder: pass --data FOLDER (with kitti/ and "
        "nuscenes/centerpoint_val/) or set SIMPLETRACK_DATA to it; or --source synthetic"
    )


def _exits(run: Callable[[], object]) -> int:
    with pytest.raises(SystemExit) as exc:
        run()
    return int(exc.value.code or 0)


def test_the_module_tools_say_the_same(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _exits(lambda: tune.main(["--cls", "Car"])) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("python -m simpletrack.eval.tune: error: no KITTI data")
    says_what_to_pass(line, paths.KITTI)

    assert _exits(lambda: gaps.main([])) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("python -m simpletrack.bench.gaps: error: no KITTI data")
    says_what_to_pass(line, paths.KITTI)

    monkeypatch.setattr(sys, "argv", ["track_nuscenes"])
    assert _exits(track_nuscenes.main) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("python -m simpletrack.eval.track_nuscenes: error: no nuScenes")
    says_what_to_pass(line, paths.NUSCENES)


def test_simpletrack_data_is_the_folder_holding_the_datasets(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv(paths.ENV, str(tmp_path))
    assert paths.data_root() == tmp_path
    assert paths.data_dir(None, paths.KITTI) == tmp_path / "kitti"
    assert paths.data_dir(None, paths.NUSCENES) == tmp_path / "nuscenes" / "centerpoint_val"
    assert paths.data_dir(None, paths.DATA) == tmp_path
    assert paths.data_dir(tmp_path / "given", paths.KITTI) == tmp_path / "given"  # --data wins
    # the commands look there (the folders are empty: each says what it did not find there)
    assert main(["eval", "kitti", "--seqs", "0000"]) == 2
    assert f"in {tmp_path / 'kitti' / 'labels'}" in one_line(capsys.readouterr().err)
    assert main(["track", "nuscenes"]) == 2
    err = one_line(capsys.readouterr().err)
    assert f"--data {tmp_path / 'nuscenes' / 'centerpoint_val'} is not a directory" in err
    assert main(["bench", "service"]) == 2
    err = one_line(capsys.readouterr().err)
    assert f"no nuScenes detections under {tmp_path / 'nuscenes' / 'centerpoint_val'}" in err
    # --data given: the variable is not consulted
    assert main(["eval", "kitti", "--data", str(tmp_path / "k"), "--seqs", "0000"]) == 2
    assert f"in {tmp_path / 'k' / 'labels'}" in one_line(capsys.readouterr().err)


def test_an_empty_variable_is_no_folder(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(paths.ENV, " ")
    assert paths.data_root() is None
    with pytest.raises(paths.MissingData, match=r"^no KITTI data: pass --data FOLDER"):
        paths.data_dir(None, paths.KITTI)


def test_runs_that_read_no_data_need_none() -> None:
    """Synthetic loads and the core's sweep alone: no folder asked for, none passed to REF."""
    assert bench._data_option(None) == ()
    assert bench._data_option(Path("d")) == ("--data", str(Path("d").resolve()))


def test_no_default_points_into_a_development_checkout(capsys: pytest.CaptureFixture[str]) -> None:
    """No source names ../shared/data as a default, and the --help of every command that
    reads data shows ../shared/data only after an explicit --data."""
    for path in (ROOT / "service" / "simpletrack").rglob("*.py"):
        text = path.read_text()
        assert not re.search(r"default=Path\([^)]*shared", text), path
        assert not re.search(r"/ \"shared\" / \"data\"", text), path
    helps = [
        ["eval", "kitti", "--help"],
        ["track", "--help"],
        ["bench", "--help"],
        ["bench", "core", "--help"],
        ["bench", "service", "--help"],
        ["bench", "scale", "--help"],
    ]
    for argv in helps:
        with pytest.raises(SystemExit):
            main(argv)
        out = capsys.readouterr().out
        assert "SIMPLETRACK_DATA" in out, argv
        for m in re.finditer(r"(\S+)\s+\S*shared/data", out):
            assert m.group(1) in ("--data", "--reference"), (argv, m.group(0))
