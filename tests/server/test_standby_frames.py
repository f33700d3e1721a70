"""Which sensors' frames and tracks a member subscribes to (``subscribe = "owned"``,
server/subscriptions.py ``hears_frames``, ``hears_tracks``). A standby used to hear every frame of the sensors
it stands by for: 0.32 ms a frame of its CPU, a quarter of the owner's, for copies a takeover
can take from the vehicle's cache (scripts/standby_cost.py). With ``standby = "checkpoints"``
(the default) it hears only what the cache cannot give back."""

from __future__ import annotations

import pytest

from simpletrack.server.group import Role
from simpletrack.server.settings import ServiceSettings, StandbyCopy
from simpletrack.server.subscriptions import hears_frames, hears_tracks

OWN, STAND, NO = Role.OWNER, Role.STANDBY, Role.NONE


@pytest.mark.parametrize(
    ("role", "cached", "fuses_later", "standby_frames", "hears"),
    [
        (OWN, True, False, False, True),  # the owner hears its sensors' frames
        (OWN, False, False, False, True),
        (STAND, True, False, False, False),  # the default standby: checkpoints, the cache later
        (STAND, False, False, False, True),  # a plain put keeps no cache: its standby's copy
        (STAND, True, True, False, True),  # fused once the group can: the vehicle's first frames
        (STAND, True, False, True, True),  # standby = "frames"
        (NO, True, False, True, False),  # nobody else, whatever the setting
        (NO, False, True, True, False),
    ],
)
def test_who_hears_a_sensors_frames(
    role: Role, cached: bool, fuses_later: bool, standby_frames: bool, hears: bool
) -> None:
    got = hears_frames(role, cached=cached, fuses_later=fuses_later, standby_frames=standby_frames)
    assert got is hears


@pytest.mark.parametrize(
    ("role", "fuses_later", "hears"),
    [
        (OWN, False, True),  # another member's message on its key fences the owner
        (STAND, False, False),  # its owner tells it, many streams in one message (a fused
        # vehicle's too, with the vehicle's message seq)
        (STAND, True, True),  # a member of before fusion tells nothing
        (NO, True, False),
    ],
)
def test_who_hears_a_streams_tracks(role: Role, fuses_later: bool, hears: bool) -> None:
    assert hears_tracks(role, fuses_later=fuses_later) is hears


def test_the_default_standby_hears_checkpoints_only() -> None:
    assert ServiceSettings().standby is StandbyCopy.CHECKPOINTS
    assert ServiceSettings(standby="frames").standby is StandbyCopy.FRAMES
    with pytest.raises(ValueError, match="checkpoints"):
        ServiceSettings(standby="all")
