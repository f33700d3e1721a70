"""Sensors at the fleet's rate (every existing config) give exactly the world, detections and
seqs the simulator gave before sensors had rates of their own.

The fingerprints were computed from the simulator of commit 83a030f (before per-sensor rates,
latencies and detectors) and written in here; they are not to be regenerated to make a change
pass: a change that moves them changes every existing demo, sweep and test world.
"""

from __future__ import annotations

import hashlib
import math
import platform

import numpy as np
import pytest

from simpletrack.sim.simulator import DetectorModel, FleetSimulator, SensorSpec, SimConfig

TICKS = 50

# The float bytes depend on the machine's kernels, twice over: numpy's (sin/cos/arctan2 differ in
# the last bit between its AVX-512 and AVX2/SSE paths: NPY_DISABLE_CPU_FEATURES) and OpenBLAS's
# (its matrix products for an Intel AVX-512 CPU, SkylakeX, and for AVX2 ones, Haswell, which an
# AMD Zen uses too, sum in other orders: OPENBLAS_CORETYPE). So each config has the hash of the
# four pairs. The Haswell pair's were computed on an AMD EPYC (2026-12-07) by code that gives
# the SkylakeX pair's with OPENBLAS_CORETYPE=SkylakeX: the same world. The discrete content
# (what was detected, ids, seqs, counts) and the float sum do not depend on the machine and are
# checked everywhere.
DEFAULT_SEED_0 = (
    "5c322a96075b6eddbfbd37cabcff21c771c760a2381805ae6ee4586055eb4ec8",
    568555.6562700531,
    {
        "064ddbdb651a462af4022f47060fb3bbe53fb618530cfed05d1bb6d8c6e98d69",  # AVX-512, SkylakeX
        "f8cf31fc3102013c1ceb5a4781f153b8eea1324dbd3121b6fdd8fbb9ffdf380b",  # AVX2 / SSE, SkylakeX
        "9e6045eb7d84bca5d72f5f72ecb731d9a62503c14346434bef78de7c20c44491",  # AVX-512, Haswell
        "d2bac434a9652086fc6d8fbff44431c161a8f86601a449c9eaa8e929643e096a",  # AVX2, Haswell
    },
)
OTHER = (
    "bc9776bfcf41cd94ae244fec9ec3cf34db57379d1811cfe1577c89605e00f0f4",
    51784.696656155786,
    {
        "4cbdbf91bcd0b0c9ab2e03e91d443d7749212a1343b226e74230b436b6acdb61",  # AVX-512, SkylakeX
        "30da2d5292dd0fcfd2f55fb28c451f09c69cbe6941459ff3f25c701d37aa9788",  # AVX2 / SSE, SkylakeX
        "c822426e1f2ba65598ff96f37c13d3f42e50f67a1144b05f9c0aab5f7c1a7d28",  # AVX-512, Haswell
        "0260da2fa9f2fb3f47bb42856a9a54375b1b9b6804211b798976eef49ff9d6be",  # AVX2, Haswell
    },
)


def other_config() -> SimConfig:
    """Not the defaults: another seed, rate, vehicle count, sensor and detector."""
    wide = SensorSpec(name="wide", mount=(0.5, 0.2, 1.5, 0.3), fov_deg=120.0, max_range=40.0)
    return SimConfig(
        seed=3,
        vehicles=2,
        rate_hz=20.0,
        sensors=(wide,),
        detector=DetectorModel(false_positives=2.0, centre_noise=0.3),
    )


def fingerprint(sim: FleetSimulator, ticks: int) -> tuple[str, float, str]:
    """(sha256 of the discrete content, sum of |every float|, sha256 of every float's bytes)
    of every frame ``step()`` returns over ``ticks`` calls, in the order returned."""
    discrete = hashlib.sha256()
    floats = hashlib.sha256()
    total: list[float] = []
    for frames in sim.frames(ticks):
        for f in frames:
            counts = f"{f.vehicle}/{f.sensor}/{f.seq}/{len(f.detections)}/{len(f.truth)};"
            discrete.update(counts.encode())
            for a in (f.detections.cls, f.truth_ids, f.truth.cls, f.truth_ignore):
                discrete.update(np.ascontiguousarray(a).tobytes())
            assert f.truth.velocity is not None
            for a in (
                np.array([f.stamp]),
                f.pose,
                f.detections.params,
                f.detections.score,
                f.truth.params,
                f.truth.velocity,
                f.truth_occlusion,
            ):
                floats.update(np.ascontiguousarray(a).tobytes())
                total.append(float(np.abs(a).sum()))
    return discrete.hexdigest(), math.fsum(total), floats.hexdigest()


@pytest.mark.parametrize(
    ("config", "expected"),
    [(SimConfig(seed=0), DEFAULT_SEED_0), (other_config(), OTHER)],
    ids=["default-seed-0", "other"],
)
def test_sensors_at_the_fleet_rate_give_the_world_of_before(
    config: SimConfig, expected: tuple[str, float, set[str]]
) -> None:
    discrete, total, floats = fingerprint(FleetSimulator(config), TICKS)
    want_discrete, want_total, want_floats = expected
    assert discrete == want_discrete, "different detections, ids, seqs or counts"
    assert total == pytest.approx(want_total, rel=1e-12), "different values"
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert floats in want_floats, (
            "the discrete content and the float sum match, the float bytes do not: an "
            "arithmetic change in the last bits, or numpy or OpenBLAS kernels not seen here"
        )
