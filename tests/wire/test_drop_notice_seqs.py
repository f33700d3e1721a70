"""FrameError.seqs (drop notices): the light validator and the pydantic model agree on it,
and a message without it is what it was before the field existed."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from simpletrack.wire import Rejection, decode_message, generate
from simpletrack.wire.messages import MAX_NOTICE_SEQS, FrameError, to_map
from tests.wire.test_validator_agrees import BASES, EDGE_VALUES, _assert_agree

SEQS: list[Any] = [
    *EDGE_VALUES,
    [1, None, 3],
    [None],
    [2**63],
    [-1],
    [1.0],
    ["1"],
    [True],
    list(range(MAX_NOTICE_SEQS)),
    list(range(MAX_NOTICE_SEQS + 1)),
]


@pytest.mark.parametrize("value", SEQS, ids=lambda v: repr(v)[:30])
def test_seqs_gets_the_same_verdict_from_both_validators(value: Any) -> None:
    obj = copy.deepcopy(BASES["FrameError"])
    obj["seqs"] = copy.deepcopy(value)
    _assert_agree("FrameError", obj)


def test_an_error_without_seqs_keeps_its_golden_bytes() -> None:
    payload = (generate.VECTOR_DIR / "error_unknown_class.msgpack").read_bytes()
    assert generate._error() == payload
    decoded = decode_message(payload, FrameError)
    assert not isinstance(decoded, Rejection) and "seqs" not in to_map(decoded)
