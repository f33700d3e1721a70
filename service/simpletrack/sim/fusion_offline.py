"""The simulated fleet tracked offline, as the service tracks it: per vehicle, one fused
tracker over its sensors (core/vehicle.py) and each sensor's own tracker, every frame in
stamp order, scored by ``vehicle_score`` at the stamps where every sensor has a frame.

What the demo measures live through Zenoh, without Zenoh and as fast as the machine goes:
the settings sweep uses it (``sweep.py --fusion``), and so do tests. The service also
applies frames in stamp order (its reorder window); late frames it re-processes into the
same state, so this is the service's result whenever every frame arrives in the window.
"""

from __future__ import annotations

import argparse

from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Frame
from simpletrack.core.fusion_config import FusionConfig, SensorTrust
from simpletrack.core.tracker import Tracker
from simpletrack.core.vehicle import SensorInput, VehicleTracker
from simpletrack.eval.clear_mot import MotCounts
from simpletrack.sim.baseline import detections_alone
from simpletrack.sim.simulator import FleetSimulator, SensorFrame, SensorSpec, SimConfig
from simpletrack.sim.vehicle_score import FUSED, FleetScores, Stamp


def sensor_trust(spec: SensorSpec, **trust: object) -> SensorTrust:
    """A simulated sensor's view as the fusion's trust (its field of view and range)."""
    view = {"fov_deg": spec.fov_deg, "min_range_m": spec.min_range, "max_range_m": spec.max_range}
    return SensorTrust.model_validate({**view, **trust})


def fusion_config(
    sim: SimConfig, trust: dict[str, dict[str, object]], **options: object
) -> FusionConfig:
    """The fleet's sensors (in the simulator's order, the first the reference) with the
    given per-sensor trust over their views, and the vehicle's ``options``."""
    sensors = {s.name: sensor_trust(s, **trust.get(s.name, {})) for s in sim.sensors}
    return FusionConfig.model_validate({"sensors": sensors, **options})


def run_offline(
    config: TrackerConfig, fusion: FusionConfig, sim_config: SimConfig, ticks: int
) -> FleetScores:
    sim = FleetSimulator(sim_config)
    sim.config.check_tracker_config(config)
    names = tuple(s.name for s in sim.config.sensors)
    scores = FleetScores(names)
    vehicles: dict[str, VehicleTracker] = {}
    trackers: dict[tuple[str, str], Tracker] = {}
    for _ in range(ticks):
        step = sim.step()
        by_vehicle: dict[str, list[SensorFrame]] = {}
        for f in step:
            by_vehicle.setdefault(f.vehicle, []).append(f)
        for vehicle, frames in by_vehicle.items():
            v = vehicles.setdefault(vehicle, VehicleTracker(config, fusion))
            fused = None
            stamp = Stamp.of(frames)
            for f in frames:  # one stamp, the sensors in the configured order
                stamp_ns = round(f.stamp * 1e9)
                if f.sensor in fusion.sensors:  # a sensor left out: its own tracks only
                    r = v.apply(SensorInput(f.sensor, f.seq, stamp_ns, f.detections, f.pose))
                    if r.tracks is not None:
                        t = r.tracks
                        fused = (t.tracks.ids.copy(), t.tracks.boxes, t.existence)
                tracker = trackers.setdefault((vehicle, f.sensor), Tracker(config))
                out = tracker.step(Frame(f.detections, f.stamp, f.pose))
                stamp.tracks[f.sensor] = (out.ids.copy(), out.boxes)
                stamp.detections[f.sensor] = detections_alone(f.detections, f.pose, config)
            if len(frames) == len(names):
                stamp.fused = fused
                scores.vehicle(vehicle).score(stamp)
    return scores


def what_each_sensor_adds(seed: int, ticks: int) -> list[tuple[str, MotCounts]]:
    """The demo's fused vehicle (``DEMO_FUSION``) with all its sensors, then with each alone,
    the same settings otherwise: (sensors fused, fused counts against the vehicle's truth)."""
    from simpletrack.sim.demo_tracker import DEMO_FUSION, demo_tracker_config
    from simpletrack.sim.fusion_sensors import fusion_sensors
    from simpletrack.sim.sweep import fusion_candidate

    sim = SimConfig(seed=seed, sensors=fusion_sensors())
    trust, options = fusion_candidate(**DEMO_FUSION)  # type: ignore[arg-type]
    every = fusion_config(sim, trust, **options)
    names = [s.name for s in sim.sensors]
    out = []
    for kept in (names, *([n] for n in names)):
        fusion = every.model_copy(update={"sensors": {n: every.sensors[n] for n in kept}})
        scores = run_offline(demo_tracker_config(), fusion, sim, ticks)
        out.append((" + ".join(kept), scores.counts(FUSED)))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description="What each sensor adds to the demo's fused vehicle: its fused tracks with "
        "every sensor, then with each sensor alone (the same settings), scored against the "
        "vehicle's truth (every object in view of any of its sensors)."
    )
    p.add_argument("--seed", type=int, default=0, help="default 0 (the seed the demo reports)")
    p.add_argument("--frames", type=int, default=200, help="lidar frames (default 200)")
    args = p.parse_args(argv)
    print(f"{'fused sensors':<16} {'MOTA':>6} {'FP':>5} {'FN':>5} {'IDS':>4} ids/object doubled")
    for kept, c in what_each_sensor_adds(args.seed, args.frames * 3):  # 30 Hz ticks
        if not c.objects:  # no track at all: a sensor that may not start tracks, alone
            print(f"{kept:<16} {c.mota:6.3f} {c.fp:5d} {c.fn:5d}    -  no track started")
            continue
        print(
            f"{kept:<16} {c.mota:6.3f} {c.fp:5d} {c.fn:5d} {c.ids:4d} "
            f"{c.ids_per_object:10.2f} {c.doubled_share:7.2%}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["fusion_config", "run_offline", "sensor_trust", "what_each_sensor_adds"]
