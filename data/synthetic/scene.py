"""Where the persons of a synthetic scene stand and walk, frame by frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from data.keypoints import NUM_JOINTS
from data.synthetic.body import BodyShape, pose_joints, sample_body, stride_length
from data.synthetic.config import SyntheticConfig

_PACKING_LIMIT = 0.9069  # densest packing of equal discs (hexagonal)
_PLACEMENT_BATCH = 256  # candidate points drawn at once per person
_PLACEMENT_BATCHES = 40  # batches per person before a restart
_PLACEMENT_RESTARTS = 5
_TURN_STEP = math.pi / 6  # heading change tried when the way ahead is blocked
_HEADING_DRIFT = 0.05  # rad SD of the random heading change per frame
_STAND_SPEED = 0.3  # m/s below which a person of the positions hook is standing


@dataclass(frozen=True)
class SceneTrack:
    """Persons: area (4,) m, bodies (P,), positions (F, P, 2) NaN absent, headings, phases, walking, present (F, P)."""

    area: tuple[float, float, float, float]
    bodies: tuple[BodyShape, ...]
    positions: np.ndarray
    headings: np.ndarray
    phases: np.ndarray
    walking: np.ndarray
    present: np.ndarray

    @property
    def num_frames(self) -> int:
        """F."""
        return self.positions.shape[0]

    @property
    def num_persons(self) -> int:
        """P."""
        return self.positions.shape[1]


def scene_area(cfg: SyntheticConfig) -> tuple[float, float, float, float]:
    """The region (xmin, xmax, ymin, ymax) in m: cfg.area, else a square of area P / density at the origin."""
    if cfg.area is not None:
        return tuple(cfg.area)
    half = math.sqrt(max(cfg.num_persons, 1) / cfg.density) / 2
    return (-half, half, -half, half)


def place_persons(
    num: int, area: tuple[float, float, float, float], min_spacing: float, rng: np.random.Generator
) -> np.ndarray:
    """Uniform ground points in the area at least min_spacing apart (rejection sampling): (num, 2)."""
    xmin, xmax, ymin, ymax = area
    w, h = xmax - xmin, ymax - ymin
    need = num * math.pi * (min_spacing / 2) ** 2
    if need > _PACKING_LIMIT * (w + min_spacing) * (h + min_spacing):
        raise ValueError(_crowded_message(num, area, min_spacing))
    low, high = np.array([xmin, ymin]), np.array([xmax, ymax])
    for _ in range(_PLACEMENT_RESTARTS):
        points = np.zeros((0, 2))
        for _ in range(num):
            for _ in range(_PLACEMENT_BATCHES):
                cand = rng.uniform(low, high, size=(_PLACEMENT_BATCH, 2))
                if len(points):
                    d2 = np.sum((cand[:, None, :] - points[None]) ** 2, axis=-1).min(axis=1)
                    ok = np.flatnonzero(d2 >= min_spacing**2)
                else:
                    ok = np.array([0])
                if len(ok):
                    points = np.vstack([points, cand[ok[0]]])
                    break
            else:
                break
        if len(points) == num:
            return points
    raise ValueError(_crowded_message(num, area, min_spacing))


def _crowded_message(num: int, area: tuple[float, ...], min_spacing: float) -> str:
    xmin, xmax, ymin, ymax = area
    a = (xmax - xmin) * (ymax - ymin)
    return (
        f"cannot place {num} persons at least {min_spacing} m apart in the area "
        f"[{xmin:.2f}, {xmax:.2f}] x [{ymin:.2f}, {ymax:.2f}] ({a:.1f} m^2, {num / a:.2f} persons "
        f"per m^2): lower dataset.density or dataset.min_spacing_m, or enlarge dataset.area"
    )


def simulate_scene(cfg: SyntheticConfig, rng: np.random.Generator) -> SceneTrack:
    """Sample persons and move the walkers frame by frame (or follow cfg.positions)."""
    area = scene_area(cfg)
    if cfg.positions is not None:
        return _track_from_positions(cfg, area, rng)
    num, frames = cfg.num_persons, cfg.num_frames
    bodies = tuple(sample_body(rng) for _ in range(num))
    pos = place_persons(num, area, cfg.min_spacing_m, rng)
    heading = rng.uniform(0.0, 2 * math.pi, num)
    phase = rng.uniform(0.0, 1.0, num)
    walker = np.zeros(num, dtype=bool)
    walker[rng.permutation(num)[: int(round(cfg.walking_fraction * num))]] = True
    speed = rng.uniform(*cfg.walk_speed_mps, num)
    strides = np.array([stride_length(b) for b in bodies])

    positions, headings, phases = np.zeros((frames, num, 2)), np.zeros((frames, num)), np.zeros((frames, num))
    for f in range(frames):
        if f > 0:
            for i in np.flatnonzero(walker):
                step = speed[i] / cfg.fps
                moved = _step(pos, i, heading[i] + rng.normal(0.0, _HEADING_DRIFT), step, area, cfg.min_spacing_m, rng)
                if moved is not None:
                    pos[i], heading[i] = moved
                    phase[i] = (phase[i] + step / strides[i]) % 1.0
        positions[f], headings[f], phases[f] = pos, heading, phase
    walking = np.broadcast_to(walker, (frames, num)).copy()
    return SceneTrack(area, bodies, positions, headings, phases, walking, np.ones((frames, num), dtype=bool))


def _step(
    pos: np.ndarray, i: int, heading: float, step: float, area: tuple, min_spacing: float, rng: np.random.Generator
) -> tuple[np.ndarray, float] | None:
    """Next (position (2,), heading) of walker i, turning away from borders and others; None if stuck."""
    xmin, xmax, ymin, ymax = area
    others = np.delete(pos, i, axis=0)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    for k in range(13):
        turn = sign * _TURN_STEP * ((k + 1) // 2) * (1 if k % 2 else -1)
        h = heading + turn
        nxt = pos[i] + step * np.array([math.cos(h), math.sin(h)])
        if not (xmin <= nxt[0] <= xmax and ymin <= nxt[1] <= ymax):
            continue
        if len(others) and np.min(np.sum((others - nxt) ** 2, axis=1)) < min_spacing**2:
            continue
        return nxt, h % (2 * math.pi)
    return None


def _track_from_positions(cfg: SyntheticConfig, area: tuple[float, ...], rng: np.random.Generator) -> SceneTrack:
    """Persons at the given positions; heading and gait follow their motion between frames."""
    frames = len(cfg.positions)
    num = max((len(p) for p in cfg.positions), default=0)
    positions = np.full((frames, num, 2), np.nan)
    for f, p in enumerate(cfg.positions):
        positions[f, : len(p)] = p
    present = np.all(np.isfinite(positions), axis=-1)
    bodies = tuple(sample_body(rng) for _ in range(num))
    strides = np.array([stride_length(b) for b in bodies])
    heading = rng.uniform(0.0, 2 * math.pi, num)
    phase = rng.uniform(0.0, 1.0, num)
    headings, phases, walking = np.zeros((frames, num)), np.zeros((frames, num)), np.zeros((frames, num), dtype=bool)
    for f in range(frames):
        for i in np.flatnonzero(present[f]):
            nxt = f + 1 if f + 1 < frames and present[f + 1, i] else None
            prev = f - 1 if f > 0 and present[f - 1, i] else None
            if nxt is not None:
                motion = positions[nxt, i] - positions[f, i]
            elif prev is not None:
                motion = positions[f, i] - positions[prev, i]
            else:
                motion = np.zeros(2)
            dist = float(np.hypot(*motion))
            if dist * cfg.fps > _STAND_SPEED:
                heading[i] = math.atan2(motion[1], motion[0]) % (2 * math.pi)
                walking[f, i] = True
            if prev is not None and walking[prev, i]:
                moved = float(np.hypot(*(positions[f, i] - positions[prev, i])))
                phase[i] = (phase[i] + moved / strides[i]) % 1.0
            headings[f, i], phases[f, i] = heading[i], phase[i]
    return SceneTrack(tuple(area), bodies, positions, headings, phases, walking, present)


def scene_poses(scene: SceneTrack) -> np.ndarray:
    """World COCO-23 joints of every person in every frame, NaN where absent: (F, P, 23, 3)."""
    out = np.full((scene.num_frames, scene.num_persons, NUM_JOINTS, 3), np.nan)
    for f in range(scene.num_frames):
        for i in np.flatnonzero(scene.present[f]):
            x, y = scene.positions[f, i]
            out[f, i] = pose_joints(
                scene.bodies[i], x, y, scene.headings[f, i], scene.phases[f, i], bool(scene.walking[f, i])
            )
    return out
