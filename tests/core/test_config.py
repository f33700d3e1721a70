"""Configuration is validated with the bad value in the message; presets are the paper's."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from simpletrack.core.config import ClassConfig, OutputPolicy, TrackerConfig, preset


def test_bad_values_are_rejected_with_the_value() -> None:
    with pytest.raises(ValidationError, match=r"1\.7"):
        ClassConfig(score_high=1.7)
    with pytest.raises(ValidationError, match="-3"):
        ClassConfig(max_age=-3)
    with pytest.raises(ValidationError, match="bogus"):
        TrackerConfig.model_validate({"classes": {"car": {}}, "output": "bogus"})
    with pytest.raises(ValidationError, match="extra"):
        ClassConfig.model_validate({"score_hi": 0.5})


def test_score_low_above_score_high_is_rejected() -> None:
    with pytest.raises(ValidationError, match="score_low"):
        ClassConfig(score_high=0.2, score_low=0.5)


def test_presets_match_the_paper_appendix() -> None:
    wod = preset("wod")
    assert wod.classes["vehicle"].score_high == 0.7
    assert wod.classes["pedestrian"].score_high == 0.5
    assert wod.classes["cyclist"].score_high == 0.7
    assert {c.nms_iou for c in wod.classes.values()} == {0.25}
    assert {(c.min_hits, c.max_age) for c in wod.classes.values()} == {(3, 2)}
    nus = preset("nuscenes")
    assert set(nus.classes) == {
        "car", "bus", "trailer", "truck", "pedestrian", "bicycle", "motorcycle"
    }  # fmt: skip
    assert {(c.nms_iou, c.score_high, c.min_hits, c.max_age, c.two_stage) for c in nus.classes.values()} == {
        (0.1, 0.01, 0, 2, False)
    }  # fmt: skip
    assert nus.output is OutputPolicy.NUSCENES
    for c in [*wod.classes.values(), *nus.classes.values()]:
        assert c.max_distance == 1.5


def test_unknown_preset_and_class_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown preset 'foo'"):
        preset("foo")
    with pytest.raises(KeyError, match="unknown class 'tram'"):
        preset("wod").class_code("tram")


def test_config_is_frozen() -> None:
    c = preset("wod")
    with pytest.raises(ValidationError):
        c.output = OutputPolicy.PAPER  # type: ignore[misc]
