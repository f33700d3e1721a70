"""The KITTI cross-validation's candidates on the simulated fleet, in the world and in the
moving sensor frame.

KITTI here has no ego poses, so the candidates were chosen on tracks in a moving camera
frame, where a turn model also follows the ego's turns (docs/KITTI_TUNING.md). The simulator
has poses: ``python -m simpletrack.sim.motion_check --seed 1 --frames 200`` tracks its fleet
(one tracker per sensor stream, the `wod` settings with each candidate's changes for every
class) once with the pose (the world frame, where a turn rate is the object's own) and once
without (the sensor's frame, as KITTI is tracked, against the truth moved into it), and
prints CLEAR-MOT figures per candidate. Seed 0 is the demo's; the default is another.

``--noise-grid`` chooses a process noise per motion model on the simulator instead (in the
sensor frame), for KITTI candidates whose noise no KITTI figure chose (docs/KITTI_TUNING.md).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

from simpletrack.core.config import TrackerConfig, preset
from simpletrack.core.frames import Frame
from simpletrack.core.tracker import Tracker
from simpletrack.eval.clear_mot import MotCounts, MotScorer
from simpletrack.eval.cv import ALL_CANDIDATES, BASE, Candidate
from simpletrack.sim.demo_tracker import SWEEP_SEED
from simpletrack.sim.simulator import FleetSimulator, SimConfig


def score(config: TrackerConfig, seed: int, frames: int, world: bool) -> MotCounts:
    """Every stream tracked (with its pose if ``world``), scored against the truth in the
    same frame."""
    sim = FleetSimulator(SimConfig(seed=seed))
    sim.config.check_tracker_config(config)
    trackers = {s: Tracker(config) for s in sim.streams}
    scorers = {s: MotScorer() for s in sim.streams}
    for step in sim.frames(frames):
        for f in step:
            key = (f.vehicle, f.sensor)
            out = trackers[key].step(Frame(f.detections, f.stamp, f.pose if world else None))
            truth = f.truth if world else f.truth_in_sensor_frame
            scorers[key].update(f.truth_ids, truth, out.ids, out.boxes, f.truth_ignore)
    return sum((s.counts for s in scorers.values()), MotCounts())


def _line(job: tuple[Candidate, int, int]) -> str:
    cand, seed, frames = job
    config = cand.in_every_class(preset(BASE))
    cells = []
    for world in (True, False):
        m = score(config, seed, frames, world)
        cells.append(f"{m.mota:6.3f} {m.ids:5d} {m.fp:6d} {m.fn:6d} {m.ids_per_object:6.2f}")
    return f"{cand.name:<30} " + "   ".join(cells)


# The process-noise grid (``--noise-grid``): each model under each (box, velocity) noise per
# frame, AB3DMOT's (1, 1) among them.
NOISE_MODELS = ("cv", "ca", "ctra", "bicycle")
NOISE_LEVELS = (1.0, 0.1, 0.01)


def _noise_line(job: tuple[str, float, float, int, int]) -> tuple[str, float, float, float, int]:
    model, q_box, q_vel, seed, frames = job
    cand = Candidate(
        f"{model}_{q_box:g}_{q_vel:g}",
        (("motion_model", model), ("process_noise", (q_box, q_vel))),
    )
    m = score(cand.in_every_class(preset(BASE)), seed, frames, world=False)
    return model, q_box, q_vel, m.mota, m.ids


def noise_grid(seed: int, frames: int, jobs: int) -> None:
    """Each model's best process noise in the sensor frame (as KITTI is tracked): the
    highest MOTA, among equal MOTAs (three decimals) the fewest ID switches."""
    work = [
        (model, q_box, q_vel, seed, frames)
        for model in NOISE_MODELS
        for q_box in NOISE_LEVELS
        for q_vel in NOISE_LEVELS
    ]
    best: dict[str, tuple[float, int, float, float]] = {}
    with ProcessPoolExecutor(max(1, jobs)) as pool:
        for model, q_box, q_vel, mota, ids in pool.map(_noise_line, work):
            print(
                f"{model:<8} box {q_box:<5g} velocity {q_vel:<5g} MOTA {mota:.3f} IDS {ids}",
                flush=True,
            )
            key = (round(mota, 3), -ids, q_box, q_vel)
            if model not in best or key[:2] > best[model][:2]:
                best[model] = key
    for model, (mota, ids, q_box, q_vel) in best.items():
        print(
            f"best for {model} on seed {seed}: process_noise ({q_box:g}, {q_vel:g}): MOTA {mota:.3f} IDS {-ids}"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--seed", type=int, default=SWEEP_SEED, help=f"default {SWEEP_SEED}")
    p.add_argument("--frames", type=int, default=200, help="frames per sensor (default 200)")
    p.add_argument(
        "--candidates",
        help="comma-separated names from simpletrack.eval.cv.ALL_CANDIDATES (default: all)",
    )
    p.add_argument("--jobs", type=int, default=2, help="candidates at once (default 2)")
    p.add_argument(
        "--noise-grid",
        action="store_true",
        help="instead: each motion model under each process noise (NOISE_LEVELS) in the "
        "sensor frame, and each model's best",
    )
    args = p.parse_args(argv)
    if args.seed == 0:
        p.error("--seed 0 is the seed the demo reports: check on another one")
    if args.noise_grid:
        noise_grid(args.seed, args.frames, args.jobs)
        return 0
    known = {c.name: c for c in ALL_CANDIDATES}
    names = list(known) if args.candidates is None else args.candidates.split(",")
    unknown = [n for n in names if n not in known]
    if unknown:
        p.error(f"unknown candidate(s) {', '.join(unknown)}; known: {', '.join(known)}")
    print(
        f"seed {args.seed}, {args.frames} frames per sensor; in each frame: MOTA IDS FP FN ids/object"
    )
    print(f"{'candidate':<30} {'world frame (poses)':<36}   sensor frame (no poses, as KITTI)")
    jobs = [(known[n], args.seed, args.frames) for n in names]
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        for line in pool.map(_line, jobs):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
