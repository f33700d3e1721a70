"""Leave-one-sequence-out cross-validation (``simpletrack eval kitti --cv loso``): a held-out
sequence never takes part in choosing its own settings, a candidate replaces ``wod`` only
when it is better on both figures with no more ID switches, and the pooled result is the
held-out files of the per-fold choices."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simpletrack.cli.main import main
from simpletrack.eval.cv import (
    ALL_CANDIDATES,
    BASE,
    CANDIDATES,
    RULES,
    Candidate,
    choose,
    cross_validate,
    fold_choices,
)

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti"
needs_kitti = pytest.mark.skipif(
    not all((KITTI / d).is_dir() for d in ("labels", "calib", "detections")),
    reason=f"needs the KITTI train data in {KITTI}",
)


def figs(samota: float, mota: float, ids: int = 0) -> dict[str, float]:
    return {"sAMOTA_u": samota, "MOTA_u": mota, "IDS": ids}


def test_a_candidate_replaces_wod_only_when_better_on_both_figures_without_more_switches() -> None:
    order = [BASE, "a", "b", "c"]
    scores = {
        BASE: figs(80, 70, 1),
        "a": figs(90, 69, 0),  # much better sAMOTA, worse MOTA
        "b": figs(81, 71, 2),  # better on both, one more switch
        "c": figs(80.5, 70.5, 1),  # a little better on both
    }
    assert choose(scores, order) == "c"
    scores["c"] = figs(80, 71, 1)  # equal sAMOTA is not better
    assert choose(scores, order) == BASE


def test_the_gain_rule_wants_half_a_point_of_samota_and_takes_an_equal_mota() -> None:
    gain = RULES["gain"]
    order = [BASE, "a", "b", "c"]
    scores = {
        BASE: figs(80, 70, 1),
        "a": figs(80.4, 75, 0),  # under half a point
        "b": figs(80.5, 70, 1),  # half a point, MOTA equal: taken
        "c": figs(82, 69.9, 1),  # MOTA lower
    }
    assert choose(scores, order, gain) == "b"
    assert choose(scores, order) == "a"  # "higher" takes any gain with a higher MOTA
    scores["b"] = figs(80.5, 70, 2)  # one more switch
    assert choose(scores, order, gain) == BASE


def test_of_two_better_candidates_the_higher_sum_wins_and_a_tie_goes_to_the_first() -> None:
    order = [BASE, "a", "b"]
    scores = {BASE: figs(80, 70), "a": figs(82, 72), "b": figs(83, 72)}
    assert choose(scores, order) == "b"
    scores["b"] = figs(82, 72)
    assert choose(scores, order) == "a"


def test_each_fold_is_chosen_on_the_other_sequences_only() -> None:
    seqs = ["s0", "s1", "s2"]
    # "x" is better than wod exactly on the training sets that contain s0.
    scores = {}
    for held in seqs:
        train = tuple(s for s in seqs if s != held)
        scores[BASE, train] = figs(80, 70)
        scores["x", train] = figs(85, 75) if "s0" in train else figs(79, 69)
    assert fold_choices(scores, seqs, [BASE, "x"]) == {"s0": BASE, "s1": "x", "s2": "x"}


def test_the_candidates_start_with_wod_and_every_one_is_a_valid_config_for_each_class() -> None:
    assert CANDIDATES[0].name == BASE and not CANDIDATES[0].changes
    assert len({c.name for c in ALL_CANDIDATES}) == len(ALL_CANDIDATES)
    for cand in ALL_CANDIDATES:
        for cls in ("Car", "Pedestrian", "Cyclist"):
            config = cand.config(cls)
            assert config.class_names  # built and validated


def test_a_bad_candidate_or_too_few_sequences_is_refused_before_any_tracking() -> None:
    with pytest.raises(ValueError, match="at least 2 sequences"):
        cross_validate(KITTI, ["0000"], ["Car"])
    with pytest.raises(ValueError, match="start with 'wod'"):
        cross_validate(KITTI, ["0000", "0001"], ["Car"], [Candidate("x")])
    with pytest.raises(ValueError, match="max_age"):
        cross_validate(
            KITTI, ["0000", "0001"], ["Car"], [Candidate(BASE), Candidate("y", (("max_age", 0),))]
        )


@pytest.mark.data
@needs_kitti
def test_the_pooled_held_out_figures_are_those_of_the_per_fold_choices(tmp_path: Path) -> None:
    seqs = ["0000", "0002", "0003"]
    longer = Candidate("age3", (("max_age", 3),))
    same = Candidate("same", (("max_age", 2),))  # the wod settings under another name
    cv = cross_validate(KITTI, seqs, ["Cyclist"], [Candidate(BASE), same, longer], jobs=1)
    r = cv.classes["Cyclist"]
    assert set(r.choices) == set(seqs) and set(r.choices.values()) <= {BASE, "age3"}
    assert r.fixed[BASE] == r.fixed["same"]  # equal settings never replace wod
    for chosen in (BASE, "age3"):
        if set(r.choices.values()) == {chosen}:
            assert r.loso == r.fixed[chosen]  # one choice everywhere: its own figures
    assert cv.configurations_tried == 3
    for k in ("sAMOTA", "MOTA", "IDS", "sAMOTA_u", "MOTA_u", "HOTA", "IDF1"):
        assert k in r.loso


@pytest.mark.data
@needs_kitti
def test_the_command_prints_the_table_the_verdicts_and_writes_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cv.json"
    args = ["eval", "kitti", "--cv", "loso", "--seqs", "0000,0002,0003", "--classes", "Cyclist"]
    assert main([*args, "--data", str(KITTI), "--jobs", "2", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"{len(CANDIDATES)} configurations tried" in text
    assert (
        "loso (chosen per fold)" in text
        and "chosen on all 3 sequences" in text
        and "Cyclist: per fold" in text
    )
    doc = json.loads(out.read_text())
    assert doc["configurations_tried"] == len(CANDIDATES)
    assert set(doc["classes"]["Cyclist"]["choices"]) == {"0000", "0002", "0003"}
    assert [c["name"] for c in doc["candidates"]] == [c.name for c in CANDIDATES]


@needs_kitti
def test_cv_refuses_result_files_and_a_bad_job_count(capsys: pytest.CaptureFixture[str]) -> None:
    base = ["eval", "kitti", "--cv", "loso", "--data", str(KITTI)]
    assert main([*base, "--results", str(KITTI)]) == 2
    assert "--cv tracks the sequences itself: drop --results" in capsys.readouterr().err
    assert main([*base, "--jobs", "0"]) == 2
    assert "--jobs must be at least 1, not 0" in capsys.readouterr().err


def test_a_candidate_in_every_class_changes_each_class_and_nothing_else() -> None:
    from simpletrack.core.config import preset

    known = {c.name: c for c in ALL_CANDIDATES}
    base = preset("nuscenes")
    changed = known["ctra_sim_noise_immortal_gated"].in_every_class(base)
    for name, c in changed.classes.items():
        assert (c.motion_model, c.process_noise, c.revive_frames) == ("ctra", (0.1, 1.0), 100)
        assert (
            c.model_copy(
                update={
                    "motion_model": "cv",
                    "process_noise": None,
                    "revive_frames": 0,
                    "revive_gate": None,
                }
            )
            == base.classes[name]
        )
    assert changed.output == base.output and changed.state_dim == 12
