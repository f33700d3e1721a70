"""``simpletrack watch`` draws the same screen with rich (service extra) or as plain text (the
light install has no rich): columns aligned, the detail's tracks nearest first."""

from __future__ import annotations

from simpletrack.cli.watch import STREAM_COLUMNS, TRACK_COLUMNS, Screen, render, render_plain


def _screen() -> Screen:
    streams = [
        ["veh00/lidar", "41", "42", "10.0", "12.3 ms", "30.1 ms", "3", "1", "0", "world", "0.1"],
        ["veh01/camera-front", "7", "8", "15.0", "-", "-", "0", "0", "0", "world", "0.0"],
    ]
    tracks = [
        ["12", "Car", "4.0", "-1.0", "0.10", "9.5", "0.91", "confirmed", "9", "11"],
        ["3", "Pedestrian", "12.5", "2.0", "1.57", "1.2", "0.40", "tentative", "1", "1"],
    ]
    return Screen("watching fleet/*/*/tracks: 2 stream(s)", streams, ["why"], "veh00/lidar", tracks)


def test_plain_text_has_every_row_with_aligned_columns() -> None:
    lines = render_plain(_screen()).splitlines()
    assert lines[0] == "watching fleet/*/*/tracks: 2 stream(s)"
    header, first, second = lines[1:4]
    assert header.split() == [*STREAM_COLUMNS[:9], "frame", "age", "s"]
    # Numbers right-aligned under their header: the seq column ends where "seq" ends.
    end = header.index("seq") + len("seq")
    assert first[:end].endswith("41") and second[:end].endswith(" 7")
    assert lines[4] == "! why"
    assert lines[6] == "veh00/lidar"
    assert lines[7].split()[:3] == list(TRACK_COLUMNS[:3])
    assert lines[8].split()[:2] == ["12", "Car"] and lines[9].split()[:2] == ["3", "Pedestrian"]


def test_rich_draws_the_same_rows() -> None:
    from rich.console import Console

    console = Console(width=200, record=True, color_system=None)
    console.print(render(_screen()))
    text = console.export_text()
    for cell in ("veh01/camera-front", "30.1 ms", "Pedestrian", "tentative", "! why"):
        assert cell in text
