"""A vehicle that never imports the core can still build and classify every frame it publishes:
the publisher recognises core ``Boxes`` without importing the core itself."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_publishing_box_lists_never_loads_the_core() -> None:
    code = textwrap.dedent(
        """
        import sys
        from simpletrack.client.publisher import Box, _is_core_boxes, box_list_to_arrays
        arrays = box_list_to_arrays([Box(1, 2, 0.5, 0.1, 4, 2, 1.5, 0.9, "Car")], ("Car",))
        assert not _is_core_boxes(arrays) and not _is_core_boxes([])
        assert arrays.center.tolist() == [[1, 2, 0.5]]
        print(sorted(m for m in sys.modules if m.startswith(("simpletrack.core", "scipy"))))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_core_boxes_are_recognised_once_the_core_is_loaded() -> None:
    from simpletrack.client.publisher import _is_core_boxes
    from simpletrack.core.boxes import Boxes

    assert _is_core_boxes(Boxes.empty())
    assert not _is_core_boxes([])
