"""A seeded, pure-numpy world for demos and tests: a fleet of vehicles with sensors, moving
objects of several classes, and a detector model with the faults a real one has.

Nothing here touches the network or a clock: ``FleetSimulator.step()`` advances simulated time
by one base tick and returns, for every sensor of every vehicle that is due at that tick, the
detections (sensor frame, as ``simpletrack.core.boxes.Boxes``), the sensor->world pose, the
publish latency and the ground truth (world frame), the sensor's and its vehicle's. Sensors
have their own rates, latencies and detectors; by default all run at the fleet's rate with the
fleet's detector and no latency, one frame of each per tick.

The world is shared by the fleet: one object may be seen by several sensors. Random streams are
split per purpose (world motion, each sensor's detector, each sensor's latency) from one seed,
so the same seed gives the same world, and changing the detector model, the latencies or the
number of sensors does not change how the objects move. The base tick does: the objects'
random walk is integrated once per tick (see ``FleetSimulator``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, model_validator

from simpletrack.core.boxes import Boxes, transform_boxes, wrap_angle
from simpletrack.core.config import TrackerConfig
from simpletrack.core.occlusion import occlusion as core_occlusion
from simpletrack.sim import clock

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

Fraction = Annotated[float, Field(ge=0.0, le=1.0)]
Positive = Annotated[float, Field(gt=0.0)]
NonNegative = Annotated[float, Field(ge=0.0)]


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


class ObjectClass(_Frozen):
    """How one class of object looks and moves."""

    size: tuple[Positive, Positive, Positive] = Field(description="mean l, w, h in metres")
    size_jitter: Fraction = Field(default=0.1, description="relative std of each object's size")
    speed: tuple[NonNegative, NonNegative] = Field(description="min, max cruise speed (m/s)")
    turn_rate_std: NonNegative = Field(
        description="random-walk std of the turn rate (rad/s/sqrt(s))"
    )
    max_turn_rate: NonNegative = Field(default=0.5, description="turn rate bound (rad/s)")
    share: Positive = Field(description="relative share of the population")
    detect_prob: Fraction = Field(
        default=0.95, description="chance of a detection when fully visible"
    )

    @model_validator(mode="after")
    def _speed_ordered(self) -> ObjectClass:
        if self.speed[0] > self.speed[1]:
            raise ValueError(f"speed range {self.speed} must be (min, max)")
        return self


def default_classes() -> dict[str, ObjectClass]:
    """vehicle, pedestrian, cyclist: the class names (and order) of the ``wod`` preset."""
    return {
        "vehicle": ObjectClass(
            size=(4.6, 1.9, 1.6), speed=(3.0, 12.0), turn_rate_std=0.15, share=0.5
        ),
        "pedestrian": ObjectClass(
            size=(0.8, 0.7, 1.75),
            speed=(0.6, 1.8),
            turn_rate_std=0.4,
            max_turn_rate=1.0,
            share=0.3,
            detect_prob=0.9,
        ),
        "cyclist": ObjectClass(
            size=(1.8, 0.7, 1.7), speed=(2.5, 7.0), turn_rate_std=0.25, share=0.2, detect_prob=0.92
        ),
    }


class DetectorModel(_Frozen):
    """The faults of the simulated detector. Scores are probabilities in [0, 1].

    The model, per sensor and object in view, every frame:

    - **Correlated misses** (a Gilbert-Elliott chain): each object is in a *seen* state, where
      it is detected with its class's ``detect_prob``, or a *lost* state, where it is detected
      with ``lost_detect`` (and then mostly with a low score). It stays seen ``seen_s`` and
      lost ``lost_s`` on average (geometric sojourns), so misses come in bursts, as a real
      detector's do: what makes an object hard to see (few lidar points, an odd pose, clutter
      nearby) lasts for several sweeps. An object entering the view starts in the chain's
      stationary state; one leaving it is forgotten.
    - **Occlusion**: the share of the object's angular interval (seen from the sensor) covered
      by nearer boxes cuts its detection chance by up to ``occlusion_miss`` and makes a low
      score likelier (``occlusion_low_score``).
    - **Range**: the detection chance falls by ``range_miss`` x (range / max range)^2, and the
      centre noise grows by ``centre_noise_per_m``. ``range_noise_per_m`` adds noise along the
      line of sight only, growing with range: how a camera's 3D boxes fail (depth is inferred,
      not measured); 0 for a lidar, whose range is measured.
    - **Clutter**: Poisson false positives, uniform over the view, mostly low-scored; duplicate
      overlapping boxes (pre-NMS output).
    - **Scores**: true boxes score uniform in ``score_high`` unless low-scored (then uniform in
      ``score_low``); false positives the other way round (``false_positive_high`` high).

    Where the figures come from (chosen from published detector figures and reasoning before
    any tracking result was looked at; the simulator is not tuned to flatter the tracker, and
    the tracker's settings are chosen on another seed than the demo reports, see
    ``simpletrack.sim.sweep``):

    - Recall: CenterPoint (Yin et al., CVPR 2021, arXiv:2006.11275; 65.5 NDS, 63.8 AMOTA on
      the nuScenes test set) is run for tracking at a low score threshold, where its recall
      is roughly 0.7-0.85 for cars and lower for small classes. Seen-state chances 0.9-0.95
      (per class), 12 % of the time lost (0.4 s of every 3.4 s) at 0.15, a 0.3 range
      penalty and occlusion give a fleet-wide recall in that band.
    - Bursts: no published figure for burst lengths; 0.4 s lost (4 sweeps at 10 Hz) is the
      time an object stays at a hard pose or range while the ego and it move a few metres.
    - Position noise: 0.12 m at the sensor growing to about 0.32 m at 50 m, in the 0.1-0.3 m
      band of lidar detectors' centre errors (nuScenes translation errors of a few tenths of
      a metre for CenterPoint-class detectors).
    - Clutter: 0.8 false positives per frame, 15 % of them above the tracker's high score,
      so a frame of ~20 true boxes is ~95 % precise at the high threshold.
    """

    centre_noise: NonNegative = Field(default=0.12, description="centre std (m) at zero range")
    centre_noise_per_m: NonNegative = Field(default=0.004, description="extra centre std per metre")
    range_noise_per_m: NonNegative = Field(
        default=0.0,
        description="extra std (m) along the line of sight per metre of range (depth error)",
    )
    yaw_noise: NonNegative = Field(default=0.06, description="yaw std (rad)")
    size_noise: Fraction = Field(default=0.05, description="relative size std")
    seen_s: Positive = Field(default=3.0, description="mean time (s) an object stays 'seen'")
    lost_s: Positive = Field(default=0.4, description="mean time (s) an object stays 'lost'")
    lost_detect: Fraction = Field(
        default=0.15, description="detection chance of an object in the 'lost' state"
    )
    lost_low_score: Fraction = Field(
        default=0.7, description="a 'lost' object, when detected, gets a low score this often"
    )
    occlusion_miss: Fraction = Field(
        default=0.85,
        description="a fully hidden object's detection chance is cut by this fraction",
    )
    occlusion_low_score: Fraction = Field(
        default=0.6, description="a fully hidden object, when detected, gets a low score this often"
    )
    range_miss: Fraction = Field(
        default=0.3,
        description="an object at max range has its detection chance cut by this fraction",
    )
    low_score_prob: Fraction = Field(
        default=0.08, description="chance a clear detection gets a low score (stage-2 material)"
    )
    score_high: tuple[Fraction, Fraction] = (0.72, 0.99)
    score_low: tuple[Fraction, Fraction] = (0.12, 0.45)
    duplicate_prob: Fraction = Field(
        default=0.08,
        description="chance of a second, overlapping, lower-score box (NMS removes it)",
    )
    false_positives: NonNegative = Field(
        default=0.8, description="mean false positives per sensor frame (Poisson)"
    )
    false_positive_high: Fraction = Field(
        default=0.15, description="share of false positives with a high score"
    )

    @property
    def lost_share(self) -> float:
        """The chain's stationary share of time in the 'lost' state."""
        return self.lost_s / (self.seen_s + self.lost_s)


class SensorSpec(_Frozen):
    """A sensor mounted on every vehicle of the fleet.

    ``rate_hz`` and ``detector`` default to the fleet's (``SimConfig.rate_hz``,
    ``SimConfig.detector``). ``latency_s``: the delay from a frame's stamp to the moment the
    vehicle publishes it (capture, transfer, the detection network), drawn uniformly in
    [min, max] per frame; a sensor's frames leave in the order they were stamped (its pipeline
    is a queue), so a draw that would overtake the previous frame waits for it, which keeps
    the delay within [min, max]."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="key-safe sensor id")
    mount: tuple[float, float, float, float] = Field(
        default=(0.0, 0.0, 1.8, 0.0), description="x, y, z, yaw of the sensor in the vehicle frame"
    )
    fov_deg: Annotated[float, Field(gt=0.0, le=360.0)] = 360.0
    max_range: Positive = 50.0
    min_range: NonNegative = 1.0
    rate_hz: Annotated[float, Field(gt=0.0, le=1000.0)] | None = Field(
        default=None, description="frames per second (None: the fleet's rate_hz)"
    )
    latency_s: tuple[NonNegative, NonNegative] = Field(
        default=(0.0, 0.0), description="min, max delay (s) from a frame's stamp to its publication"
    )
    detector: DetectorModel | None = Field(
        default=None, description="this sensor's detector (None: the fleet's detector)"
    )

    @model_validator(mode="after")
    def _latency_ordered(self) -> SensorSpec:
        if self.latency_s[0] > self.latency_s[1]:
            raise ValueError(f"latency_s {self.latency_s} must be (min, max)")
        return self


def default_sensors() -> tuple[SensorSpec, ...]:
    return (
        SensorSpec(name="lidar", mount=(0.0, 0.0, 1.8, 0.0), fov_deg=360.0, max_range=50.0),
        SensorSpec(name="front", mount=(1.6, 0.0, 1.4, 0.0), fov_deg=100.0, max_range=70.0),
    )


class SimConfig(_Frozen):
    """The whole simulated world. Validated: a bad value is named in the error."""

    seed: int = 0
    vehicles: Annotated[int, Field(ge=1, le=256)] = 3
    sensors: tuple[SensorSpec, ...] = Field(default_factory=default_sensors, min_length=1)
    classes: dict[str, ObjectClass] = Field(default_factory=default_classes, min_length=1)
    objects: Annotated[int, Field(ge=0, le=10_000)] = Field(
        default=90, description="objects alive at any time (leavers are replaced by newcomers)"
    )
    area: Annotated[float, Field(gt=10.0)] = Field(
        default=180.0, description="side of the square world (m), centred on the origin"
    )
    rate_hz: Annotated[float, Field(gt=0.0, le=1000.0)] = Field(
        default=10.0, description="frames per second of the sensors without a rate_hz of their own"
    )
    ego_speed: tuple[NonNegative, NonNegative] = (5.0, 10.0)
    detector: DetectorModel = Field(
        default=DetectorModel(), description="the detector of the sensors without one of their own"
    )
    truth_ignore_occlusion: Fraction = Field(
        default=0.8, description="ground truth hidden more than this is 'ignored' by the scorer"
    )

    @model_validator(mode="after")
    def _unique_sensors(self) -> SimConfig:
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"sensor names must be unique, got {names}")
        return self

    @model_validator(mode="after")
    def _rates_share_a_tick(self) -> SimConfig:
        clock.base_tick(self.sensor_rates)  # raises ValueError naming the rates
        return self

    @property
    def sensor_rates(self) -> dict[str, float]:
        """Each sensor's frames per second, by name (the fleet's rate where it has none)."""
        return {s.name: self.rate_hz if s.rate_hz is None else s.rate_hz for s in self.sensors}

    @property
    def base_tick(self) -> clock.BaseTick:
        """The world's time step and each sensor's frame interval in steps (``clock``)."""
        return clock.base_tick(self.sensor_rates)

    def sensor_detector(self, sensor: SensorSpec) -> DetectorModel:
        return self.detector if sensor.detector is None else sensor.detector

    @property
    def class_names(self) -> tuple[str, ...]:
        return tuple(self.classes)

    def check_tracker_config(self, config: TrackerConfig) -> None:
        """Class codes are indices into both lists: they must name the same classes in order."""
        if config.class_names[: len(self.classes)] != self.class_names:
            raise ValueError(
                f"simulator classes {self.class_names} are not the first classes of the tracker "
                f"config {config.class_names}"
            )


def vehicle_id(index: int) -> str:
    return f"veh{index:02d}"


@dataclass(frozen=True, slots=True)
class SensorFrame:
    """One sensor's frame: what the detector saw, where the sensor was, and what was there.

    ``seq`` counts this stream's frames (0, 1, 2, ...); ``stamp`` is the simulated time the
    frame shows; ``latency_s`` the delay after it before the vehicle publishes the frame (0 for
    a sensor without latency). ``detections`` are in the sensor frame; ``pose`` maps sensor ->
    world. The truth is in the world frame: ``truth_ids`` are global object ids (stable while
    an object lives, never reused); ``truth_ignore`` marks objects hidden more than
    ``truth_ignore_occlusion``; ``truth_occlusion`` is the hidden fraction of each object's
    outline seen from the sensor.

    ``vehicle_truth*`` is the truth a fusion of all the vehicle's sensors is scored against:
    every object in view of any of its sensors at this stamp (whether or not that sensor has a
    frame now), ignored where every sensor that has it in view sees it hidden more than
    ``truth_ignore_occlusion``. The vehicle's frames of one stamp share these arrays, read-only.
    """

    vehicle: str
    sensor: str
    seq: int
    stamp: float
    pose: F64
    detections: Boxes
    truth_ids: I64
    truth: Boxes
    truth_ignore: Bool
    truth_occlusion: F64
    latency_s: float
    vehicle_truth_ids: I64
    vehicle_truth: Boxes
    vehicle_truth_ignore: Bool

    @property
    def truth_in_sensor_frame(self) -> Boxes:
        return transform_boxes(self.truth, np.linalg.inv(self.pose).astype(np.float64))


def pose_matrix(x: float, y: float, z: float, yaw: float) -> F64:
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = [x, y, z]
    return m


class _Objects:
    """Struct-of-arrays object population with constant turn-rate and velocity motion."""

    def __init__(self, config: SimConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.models = list(config.classes.values())
        share = np.array([m.share for m in self.models])
        self.class_p = share / share.sum()
        self.mean_size = np.array([m.size for m in self.models])
        self.size_jitter = np.array([m.size_jitter for m in self.models])
        self.speed_range = np.array([m.speed for m in self.models])
        self.turn_std = np.array([m.turn_rate_std for m in self.models])
        self.max_turn = np.array([m.max_turn_rate for m in self.models])
        self.detect_prob = np.array([m.detect_prob for m in self.models])
        self.fleet_dt = 1.0 / config.rate_hz
        self.next_id = 0
        n = config.objects
        self.ids = np.zeros(0, dtype=np.int64)
        self.cls = np.zeros(0, dtype=np.int32)
        self.xy = np.zeros((0, 2))
        self.yaw = np.zeros(0)
        self.speed = np.zeros(0)
        self.target_speed = np.zeros(0)
        self.turn = np.zeros(0)
        self.size = np.zeros((0, 3))
        half = config.area / 2
        self._spawn(rng.uniform(-half, half, size=(n, 2)), rng.uniform(-np.pi, np.pi, size=n))

    def _spawn(self, xy: F64, yaw: F64) -> None:
        n = xy.shape[0]
        if n == 0:
            return
        rng = self.rng
        cls = np.asarray(rng.choice(len(self.models), size=n, p=self.class_p), dtype=np.int32)
        lo, hi = self.speed_range[cls, 0], self.speed_range[cls, 1]
        speed = rng.uniform(lo, hi)
        size = self.mean_size[cls] * (
            1.0 + self.size_jitter[cls, None] * rng.standard_normal((n, 3))
        )
        size = np.maximum(size, 0.3 * self.mean_size[cls])
        self.ids = np.concatenate([self.ids, np.arange(self.next_id, self.next_id + n)])
        self.next_id += n
        self.cls = np.concatenate([self.cls, cls])
        self.xy = np.concatenate([self.xy, xy])
        self.yaw = np.concatenate([self.yaw, yaw])
        self.speed = np.concatenate([self.speed, speed])
        self.target_speed = np.concatenate([self.target_speed, speed])
        self.turn = np.concatenate([self.turn, np.zeros(n)])
        self.size = np.concatenate([self.size, size])

    def _cruise_change_chance(self, dt: float) -> float:
        # 1 % per frame at the fleet's rate (the world before sensors had rates of their own),
        # and the same chance per second on any other tick, so a finer tick does not make
        # cruise speeds change more often.
        if dt == self.fleet_dt:
            return 0.01
        return 1.0 - math.pow(0.99, dt / self.fleet_dt)

    def step(self, dt: float) -> None:
        rng = self.rng
        n = self.ids.shape[0]
        # Turn rate: a random walk pulled back to zero, so paths bend and then straighten.
        self.turn += -0.5 * self.turn * dt + self.turn_std[self.cls] * math.sqrt(
            dt
        ) * rng.standard_normal(n)
        self.turn = np.clip(self.turn, -self.max_turn[self.cls], self.max_turn[self.cls])
        # Speed relaxes towards a per-object cruise speed that itself drifts now and then.
        change = rng.random(n) < self._cruise_change_chance(dt)
        lo, hi = self.speed_range[self.cls, 0], self.speed_range[self.cls, 1]
        self.target_speed = np.where(change, rng.uniform(lo, hi), self.target_speed)
        self.speed += (self.target_speed - self.speed) * min(1.0, 0.5 * dt)
        # Exact CTRV integration (straight-line limit for tiny turn rates).
        w = self.turn
        v = self.speed
        small = np.abs(w) < 1e-6
        safe_w = np.where(small, 1.0, w)
        new_yaw = self.yaw + w * dt
        dx = np.where(
            small,
            v * dt * np.cos(self.yaw),
            v / safe_w * (np.sin(new_yaw) - np.sin(self.yaw)),
        )
        dy = np.where(
            small,
            v * dt * np.sin(self.yaw),
            v / safe_w * (np.cos(self.yaw) - np.cos(new_yaw)),
        )
        self.xy += np.stack([dx, dy], axis=1)
        self.yaw = wrap_angle(new_yaw)
        self._replace_leavers()

    def _replace_leavers(self) -> None:
        half = self.config.area / 2
        gone = (np.abs(self.xy) > half).any(axis=1)
        k = int(gone.sum())
        if k == 0:
            return
        keep = ~gone
        for name in ("ids", "cls", "xy", "yaw", "speed", "target_speed", "turn", "size"):
            setattr(self, name, getattr(self, name)[keep])
        # Newcomers enter from a random edge, heading roughly inwards.
        rng = self.rng
        edge = rng.integers(0, 4, size=k)
        along = rng.uniform(-half, half, size=k)
        inset = half - 0.5
        x = np.select([edge == 0, edge == 1, edge == 2], [-inset, inset, along], along)
        y = np.select([edge == 0, edge == 1, edge == 2], [along, along, -inset], inset)
        inward = np.select([edge == 0, edge == 1, edge == 2], [0.0, np.pi, np.pi / 2], -np.pi / 2)
        yaw = wrap_angle(inward + rng.uniform(-0.6, 0.6, size=k))
        self._spawn(np.stack([x, y], axis=1), yaw)

    def boxes(self) -> Boxes:
        n = self.ids.shape[0]
        params = np.empty((n, 7))
        params[:, 0:2] = self.xy
        params[:, 2] = self.size[:, 2] / 2  # standing on the ground, z up
        params[:, 3] = self.yaw
        params[:, 4:7] = self.size
        vel = self.speed[:, None] * np.stack([np.cos(self.yaw), np.sin(self.yaw)], axis=1)
        return Boxes(params=params, score=np.ones(n), cls=self.cls.copy(), velocity=vel)


class _Ego:
    """One fleet vehicle driving a circle about the world centre (deterministic given the seed)."""

    def __init__(self, index: int, config: SimConfig, rng: np.random.Generator) -> None:
        half = config.area / 2
        self.radius = rng.uniform(0.25, 0.6) * half
        self.speed = rng.uniform(*config.ego_speed)
        self.direction = 1.0 if index % 2 == 0 else -1.0
        self.phase = rng.uniform(-np.pi, np.pi)

    def pose(self, t: float) -> F64:
        angle = self.phase + self.direction * self.speed / self.radius * t
        x, y = self.radius * math.cos(angle), self.radius * math.sin(angle)
        heading = angle + self.direction * math.pi / 2
        return pose_matrix(x, y, 0.0, heading)


def occlusion(local: Boxes) -> F64:
    """Fraction of each box's angular extent hidden behind nearer boxes, seen from the origin
    (``simpletrack.core.occlusion``: the tracker's estimate uses the same geometry)."""
    return core_occlusion(local.params[:, :2], local.yaw, local.l, local.w)


def in_view(sensor: SensorSpec, local: Boxes) -> Bool:
    """Boxes (sensor frame) whose centre lies within the sensor's field of view and range."""
    r = np.hypot(local.x, local.y)
    bearing = np.abs(np.arctan2(local.y, local.x))
    half_fov = math.radians(sensor.fov_deg) / 2
    return (r <= sensor.max_range) & (r >= sensor.min_range) & (bearing <= half_fov)


class _Detector:
    """Turns one sensor's view of the world into detections."""

    def __init__(
        self, config: SimConfig, sensor: SensorSpec, detect_prob: F64, rng: np.random.Generator
    ) -> None:
        self.model = config.sensor_detector(sensor)
        self.sensor = sensor
        self.detect_prob = detect_prob
        self.rng = rng
        self.mean_size = np.array([m.size for m in config.classes.values()])
        self.n_classes = len(config.classes)
        dt = 1.0 / config.sensor_rates[sensor.name]
        # Per-frame switching chances: geometric sojourns with the stated mean durations.
        self._to_lost = min(1.0, dt / self.model.seen_s)
        self._to_seen = min(1.0, dt / self.model.lost_s)
        # The chain's state of the objects in view last frame, by id (sorted).
        self._ids = np.zeros(0, dtype=np.int64)
        self._lost = np.zeros(0, dtype=bool)

    def lost_state(self, ids: I64) -> Bool:
        """Advance each object's seen/lost chain one frame; True where it is now lost."""
        n = ids.shape[0]
        u = self.rng.random(n)
        if self._ids.size:
            pos = np.minimum(np.searchsorted(self._ids, ids), self._ids.size - 1)
            known = self._ids[pos] == ids
            before = self._lost[pos] & known
        else:
            known = np.zeros(n, dtype=bool)
            before = known
        switched = np.where(before, u < self._to_seen, u < self._to_lost)
        lost = np.where(known, before ^ switched, u < self.model.lost_share)
        order = np.argsort(ids, kind="stable")
        self._ids, self._lost = ids[order], lost[order]
        return lost

    def detect(self, truth: Boxes, ids: I64, occluded: F64) -> Boxes:
        m, rng, n = self.model, self.rng, len(truth)
        r = np.hypot(truth.x, truth.y)
        lost = self.lost_state(ids)
        p = (
            np.where(lost, m.lost_detect, self.detect_prob[truth.cls])
            * (1.0 - m.occlusion_miss * occluded)
            * (1.0 - m.range_miss * (r / self.sensor.max_range) ** 2)
        )
        hit = rng.random(n) < p
        det = truth.take(hit)
        k, rr, occ = len(det), r[hit], occluded[hit]
        params = det.params.copy()
        sigma = m.centre_noise + m.centre_noise_per_m * rr
        params[:, 0:2] += sigma[:, None] * rng.standard_normal((k, 2))
        if m.range_noise_per_m > 0.0:  # drawn only then: a lidar's stream stays as it was
            along = m.range_noise_per_m * rr * rng.standard_normal(k)
            params[:, 0:2] += (along / np.maximum(rr, 1e-9))[:, None] * det.params[:, 0:2]
        params[:, 2] += 0.5 * sigma * rng.standard_normal(k)
        params[:, 3] = wrap_angle(params[:, 3] + m.yaw_noise * rng.standard_normal(k))
        params[:, 4:7] *= np.clip(1.0 + m.size_noise * rng.standard_normal((k, 3)), 0.5, 1.5)
        # Weak evidence (hidden, or in a lost spell) more often comes out with a low score.
        p_low = np.where(
            lost[hit], m.lost_low_score, m.low_score_prob + m.occlusion_low_score * occ
        )
        low = rng.random(k) < p_low
        score = np.where(low, rng.uniform(*m.score_low, size=k), rng.uniform(*m.score_high, size=k))
        boxes = [Boxes(params=params, score=score, cls=det.cls.copy())]
        boxes.append(self._duplicates(boxes[0]))
        boxes.append(self._false_positives())
        return _concat(boxes)

    def _duplicates(self, det: Boxes) -> Boxes:
        m, rng = self.model, self.rng
        dup = rng.random(len(det)) < m.duplicate_prob
        d = det.take(dup)
        k = len(d)
        params = d.params.copy()
        # Shifted by a fraction of the box size: overlapping well above any NMS threshold.
        params[:, 0:2] += 0.08 * d.params[:, 4:6] * rng.standard_normal((k, 2))
        params[:, 3] = wrap_angle(params[:, 3] + 0.03 * rng.standard_normal(k))
        score = d.score * rng.uniform(0.5, 0.95, size=k)
        return Boxes(params=params, score=score, cls=d.cls.copy())

    def _false_positives(self) -> Boxes:
        m, rng, s = self.model, self.rng, self.sensor
        k = int(rng.poisson(m.false_positives))
        half_fov = math.radians(s.fov_deg) / 2
        r = rng.uniform(max(s.min_range, 3.0), s.max_range, size=k)
        bearing = rng.uniform(-half_fov, half_fov, size=k)
        cls = rng.integers(0, self.n_classes, size=k).astype(np.int32)
        size = self.mean_size[cls] * rng.uniform(0.8, 1.2, size=(k, 3))
        params = np.empty((k, 7))
        params[:, 0] = r * np.cos(bearing)
        params[:, 1] = r * np.sin(bearing)
        params[:, 2] = size[:, 2] / 2 - s.mount[2]
        params[:, 3] = rng.uniform(-np.pi, np.pi, size=k)
        params[:, 4:7] = size
        high = rng.random(k) < m.false_positive_high
        score = np.where(
            high, rng.uniform(*m.score_high, size=k), rng.uniform(*m.score_low, size=k)
        )
        return Boxes(params=params, score=score, cls=cls)


def _concat(parts: list[Boxes]) -> Boxes:
    return Boxes(
        params=np.concatenate([b.params for b in parts]),
        score=np.concatenate([b.score for b in parts]),
        cls=np.concatenate([b.cls for b in parts]).astype(np.int32),
    )


class _Latency:
    """One stream's publish delays: uniform draws on their own random stream, in stamp order."""

    def __init__(self, sensor: SensorSpec, rng: np.random.Generator) -> None:
        self.low, self.high = sensor.latency_s
        self.rng = rng
        self._last_publish = -math.inf

    def draw(self, stamp: float) -> float:
        if self.high == 0.0:
            return 0.0
        # A frame does not overtake the one before it: the sensor's pipeline is a queue. The
        # wait stays below ``high``, since the previous frame left before its stamp + high.
        latency = max(self.rng.uniform(self.low, self.high), self._last_publish - stamp)
        self._last_publish = stamp + latency
        return latency


@dataclass(frozen=True, slots=True)
class _View:
    """What one sensor has in view at one stamp (world-order indices into the object arrays)."""

    pose: F64
    visible: Bool
    local: Boxes
    occluded: F64


class FleetSimulator:
    """The fleet and its world, advanced one base tick per ``step()``.

    The base tick (``dt``, ``base_hz``) is the longest step every sensor's period is a whole
    number of (``clock.base_tick``): with every sensor at the fleet's ``rate_hz`` (the
    default) it is one frame of every sensor, as before sensors had rates of their own.

    The objects' random walk is integrated once per base tick: its turn-rate noise scales with
    the square root of the tick, speed relaxation and cruise changes with the tick, so the
    process is the same at any tick, but its sample path is not. A config whose base tick
    differs (a sensor at another rate: 10 and 15 Hz tick at 30 Hz) moves the same seed's
    objects along other paths than the lockstep fleet; detectors, latencies and sensors that
    leave the base tick as it is change nothing in the world.
    """

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        cfg = self.config
        tick = cfg.base_tick
        self.base_hz = tick.hz
        self.ticks_per_frame: dict[str, int] = dict(tick.every)
        # Spawned children keep their index: the fourth stream (latency) leaves the first three
        # as they were before it existed.
        world_seed, ego_seed, det_seed, latency_seed = np.random.SeedSequence(cfg.seed).spawn(4)
        self._objects = _Objects(cfg, np.random.default_rng(world_seed))
        ego_rng = np.random.default_rng(ego_seed)
        self._egos = [_Ego(i, cfg, ego_rng) for i in range(cfg.vehicles)]
        n_sensors = len(cfg.sensors)
        det_seeds = det_seed.spawn(cfg.vehicles * n_sensors)
        latency_seeds = latency_seed.spawn(cfg.vehicles * n_sensors)
        self._mounts = [pose_matrix(*s.mount) for s in cfg.sensors]
        self._detectors = [
            [
                _Detector(
                    cfg,
                    s,
                    self._objects.detect_prob,
                    np.random.default_rng(det_seeds[v * n_sensors + j]),
                )
                for j, s in enumerate(cfg.sensors)
            ]
            for v in range(cfg.vehicles)
        ]
        self._latencies = [
            [
                _Latency(s, np.random.default_rng(latency_seeds[v * n_sensors + j]))
                for j, s in enumerate(cfg.sensors)
            ]
            for v in range(cfg.vehicles)
        ]
        self._seqs = [[0] * n_sensors for _ in range(cfg.vehicles)]
        self.frame = 0  # base ticks taken so far

    @property
    def dt(self) -> float:
        """The base tick (s): the step of simulated time one ``step()`` takes."""
        return 1.0 / self.base_hz

    @property
    def stamp(self) -> float:
        """Simulated time (s) of the tick the next ``step()`` returns frames for."""
        return self.frame * self.dt

    @property
    def streams(self) -> list[tuple[str, str]]:
        """(vehicle, sensor) of every stream, in the order ``step()`` returns the frames of the
        streams that are due."""
        return [
            (vehicle_id(v), s.name)
            for v in range(self.config.vehicles)
            for s in self.config.sensors
        ]

    def due(self) -> list[bool]:
        """Per sensor (config order): does it produce a frame at the next ``step()``?"""
        return [self.frame % self.ticks_per_frame[s.name] == 0 for s in self.config.sensors]

    def step(self) -> list[SensorFrame]:
        """Advance one base tick: the frames of the sensors due at this tick's stamp, vehicle by
        vehicle in sensor order; none at a tick where no sensor is due."""
        t = self.stamp
        due = self.due()
        out: list[SensorFrame] = []
        if any(due):
            world = self._objects.boxes()
            ids = self._objects.ids.copy()
            for v, ego in enumerate(self._egos):
                out.extend(self._observe_vehicle(v, ego.pose(t), due, world, ids, t))
        self._objects.step(self.dt)
        self.frame += 1
        return out

    def frames(self, n: int) -> Iterator[list[SensorFrame]]:
        """``step()`` ``n`` times: ``n`` base ticks (``n`` frames of every sensor when all run
        at the base rate)."""
        for _ in range(n):
            yield self.step()

    def _view(self, j: int, vehicle_pose: F64, world: Boxes) -> _View:
        pose = vehicle_pose @ self._mounts[j]
        local_all = transform_boxes(world, np.linalg.inv(pose).astype(np.float64))
        visible = in_view(self.config.sensors[j], local_all)
        local = local_all.take(visible)
        return _View(pose, visible, local, occlusion(local))

    def _observe_vehicle(
        self, v: int, vehicle_pose: F64, due: list[bool], world: Boxes, ids: I64, t: float
    ) -> list[SensorFrame]:
        cfg = self.config
        views = [self._view(j, vehicle_pose, world) for j in range(len(cfg.sensors))]
        # The least hidden any in-view sensor sees each object (inf: in view of none).
        least_hidden = np.full(len(world), np.inf)
        for view in views:
            least_hidden[view.visible] = np.minimum(least_hidden[view.visible], view.occluded)
        seen = np.isfinite(least_hidden)
        vehicle_ids = ids[seen]
        vehicle_truth = world.take(seen)
        vehicle_ignore = least_hidden[seen] > cfg.truth_ignore_occlusion
        for a in (vehicle_ids, vehicle_truth.params, vehicle_truth.score, vehicle_truth.cls):
            a.setflags(write=False)
        if vehicle_truth.velocity is not None:
            vehicle_truth.velocity.setflags(write=False)
        vehicle_ignore.setflags(write=False)
        out: list[SensorFrame] = []
        for j, sensor in enumerate(cfg.sensors):
            if not due[j]:
                continue
            view = views[j]
            visible = view.visible
            detections = self._detectors[v][j].detect(view.local, ids[visible], view.occluded)
            out.append(
                SensorFrame(
                    vehicle=vehicle_id(v),
                    sensor=sensor.name,
                    seq=self._seqs[v][j],
                    stamp=t,
                    pose=view.pose,
                    detections=detections,
                    truth_ids=ids[visible],
                    truth=world.take(visible),
                    truth_ignore=view.occluded > cfg.truth_ignore_occlusion,
                    truth_occlusion=view.occluded,
                    latency_s=self._latencies[v][j].draw(t),
                    vehicle_truth_ids=vehicle_ids,
                    vehicle_truth=vehicle_truth,
                    vehicle_truth_ignore=vehicle_ignore,
                )
            )
            self._seqs[v][j] += 1
        return out
