"""Track life-cycle states."""

from enum import IntEnum


class TrackState(IntEnum):
    TENTATIVE = 0  # born, fewer than min_hits hits
    CONFIRMED = 1
    DEAD = 2  # removed at the end of the frame; never reported


class UpdateKind(IntEnum):
    """What happened to a track on the latest frame (the reference's 'mode')."""

    COASTED = 0  # no detection: prediction only
    MATCHED = 1  # stage-1 match: filter corrected with the detection
    EXTENDED = 3  # stage-2: a low-score detection agreed; corrected with its own prediction
