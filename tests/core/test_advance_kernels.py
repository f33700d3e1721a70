"""The compiled tail of a step (core/advance_kernels.py) gives exactly what its own Python
function gives, under every option it reads; what that tail must do is held by the scenario,
option, life-cycle and parity tests, which now run through it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from simpletrack.core import advance_kernels as akn
from simpletrack.core import jit
from simpletrack.core import tracker as tracker_module
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import MotionModel, OutputPolicy, TrackerConfig, TrackScore
from simpletrack.core.frames import Frame
from simpletrack.core.lifecycle import TrackState, UpdateKind
from simpletrack.core.tracker import Tracker
from tests.core.helpers import config, models_config
from tests.core.helpers import crowd as helpers_crowd


def crowd(seed: int, frames: int = 30) -> list[Frame]:
    """Two classes of boxes with velocities that come and go; every fourth frame non-key."""
    return helpers_crowd(seed, frames, 40, seen=0.75, with_velocity=True, non_key_every=4)


def configs() -> list[TrackerConfig]:
    fused = {"track_score": TrackScore.FUSED, "score_decay": 0.15}
    return [
        config(),
        config(OutputPolicy.REFERENCE, min_hits=2),
        config(OutputPolicy.NUSCENES, min_hits=0, **fused),
        config(max_age=4, coast_output=2, delete_below=0.3, **fused),
        config(max_age=3, gate_widening=0.3, max_position_std=1.2),
        config(OutputPolicy.NUSCENES, max_age=3, coast_output=1).model_copy(
            update={"motion": MotionModel.CONSTANT_VELOCITY}
        ),
        models_config(),
        models_config(OutputPolicy.NUSCENES, pedestrian="cv"),
    ]


def _same(a: Any, b: Any) -> None:
    assert len(a) == len(b) == 27
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x.dtype == y.dtype and x.shape == y.shape, k
        np.testing.assert_array_equal(x, y, err_msg=f"output {k}")


@pytest.mark.skipif(not jit.compiled(), reason="numba is unavailable: nothing compiled to compare")
@pytest.mark.parametrize("index", range(len(configs())))
@pytest.mark.parametrize("seed", range(2))
def test_compiled_tail_equals_its_python_function(
    index: int, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    frames = crowd(seed)
    # A restored stream resumes across an outage: the re-associated matches go through too.
    frames[20] = replace(frames[20], after_gap=True)
    seen: dict[str, int] = {"calls": 0, "births": 0, "deaths": 0, "coasted": 0}

    def both(*args: Any) -> Any:
        got, plain = akn.advance(*args), akn.advance.py(*args)
        _same(got, plain)
        seen["calls"] += 1
        seen["births"] += int(args[19].size) if args[24] else 0
        seen["deaths"] += int(args[0].size) + int(args[19].size) * args[24] - int(got[0].size)
        seen["coasted"] += int((got[10] == UpdateKind.COASTED).sum())
        return got

    monkeypatch.setattr(tracker_module, "advance", both)
    t = Tracker(configs()[index])
    t._fused = False  # the staged path calls advance itself (step_kernels calls it compiled)
    out = [t.step(f) for f in frames]
    assert akn.advance.is_compiled
    assert seen["calls"] == len(frames)
    # The streams exercise what the tail decides: births, deaths, coasting, confirmations.
    assert seen["births"] > 30 and seen["deaths"] >= 2 and seen["coasted"] >= 10, seen
    assert any((o.state == TrackState.CONFIRMED).any() for o in out)


def test_births_take_the_next_ids_and_non_key_frames_bear_none() -> None:
    t = Tracker(config(min_hits=0))
    boxes = Boxes.from_arrays(
        [[0, 0, 0, 0, 4, 2, 1.5], [30, 0, 0, 0, 4, 2, 1.5]], [0.9, 0.8], [0, 1]
    )
    first = t.step(Frame(boxes=boxes, stamp=0.0))
    np.testing.assert_array_equal(first.ids, [0, 1])
    far = Boxes.from_arrays([[0, 60, 0, 0, 4, 2, 1.5]], [0.9], [0])
    t.step(Frame(boxes=far, stamp=0.1, key_frame=False))
    assert t.next_id == 2 and len(t.tracks) == 2  # no birth, no death off the key frames
    third = t.step(Frame(boxes=far, stamp=0.2))
    assert t.next_id == 3 and 2 in third.ids.tolist()


_UNCOMPILED = """
import json
from simpletrack.core import jit
from simpletrack.core.tracker import Tracker
from tests.core.test_advance_kernels import configs, crowd
assert not jit.compiled()
t = Tracker(configs()[INDEX])
out = [t.step(f) for f in crowd(0, frames=12)]
print(json.dumps([[o.ids.tolist(), o.boxes.params.tolist(), o.state.tolist()] for o in out]))
"""


@pytest.mark.parametrize("index", [0, 3, 5])
def test_the_uncompiled_step_tracks_as_the_compiled_one(index: int) -> None:
    """SIMPLETRACK_JIT=0 (or a missing numba) runs every kernel as Python: the same tracks."""
    env = {**os.environ, jit.ENV_VAR: "0", "PYTHONPATH": os.pathsep.join(sys.path)}
    code = _UNCOMPILED.replace("INDEX", str(index))
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    plain = json.loads(done.stdout.strip().splitlines()[-1])
    assert sum(len(ids) for ids, _, _ in plain) > 50  # tracks were reported, not none
    t = Tracker(configs()[index])
    for o, (ids, params, state) in zip(
        (t.step(f) for f in crowd(0, frames=12)), plain, strict=True
    ):
        assert o.ids.tolist() == ids and o.state.tolist() == state
        np.testing.assert_allclose(o.boxes.params, np.array(params).reshape(-1, 7), atol=1e-9)
