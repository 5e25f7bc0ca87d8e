"""The options of the synthetic crowd generator (flat keys of ``configs/dataset/synthetic.yaml``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np


@dataclass
class SyntheticConfig:
    """Every option of :func:`data.synthetic.generate_sequence`, with its default (configs/dataset/synthetic.yaml)."""

    # scene
    seed: int = 0  # seed of the numpy Generators: the same seed gives identical arrays
    num_frames: int = 20  # ignored when ``positions`` is given (one frame per entry)
    num_persons: int = 10  # ignored when ``positions`` is given
    density: float = 0.3  # persons per m^2: a square of side sqrt(num_persons / density) at the origin, unless area
    min_spacing_m: float = 0.6  # least distance between two persons' ground points, walking too
    walking_fraction: float = 0.5  # share of persons that walk; the others stand
    walk_speed_mps: tuple[float, float] = (1.2, 1.5)  # (low, high) of the walking speeds, uniform per walker
    fps: float = 5.0  # a walker moves speed / fps metres between frames
    area: tuple[float, float, float, float] | None = None  # [xmin, xmax, ymin, ymax] (m) the persons stay in
    # ground positions per frame, (N_f, 2) each (m); row i is person i, a NaN row an absent person
    positions: list | None = None
    # cameras: a ring around the area centre looking at look_at_height_m, or a calibration file / folder
    rig: str = "ring"
    rig_format: str = "auto"  # data.geometry.calibration.load_rig's fmt
    num_cameras: int = 5
    camera_radius_m: float | None = None  # None: the area's half diagonal + 4 m
    camera_height_m: float = 2.5
    look_at_height_m: float = 1.0
    image_size: tuple[int, int] = (1280, 720)  # (width, height) px
    focal_px: float = 1000.0  # no distortion
    # observations
    noise_px: float = 2.0  # pixel noise SD at noise_ref_depth_m (0 = exact)
    noise_ref_depth_m: float = 5.0
    noise_depth_exponent: float = 1.0  # SD = noise_px * (depth / noise_ref_depth_m) ** exponent
    occlusion: bool = True  # mark joints hidden behind another person's body (capsule model)
    occluded_drop_prob: float = 0.3  # a hidden joint is missing (score 0) with this probability
    occluded_noise_scale: float = 3.0  # factor on the pixel noise SD of hidden joints
    miss_rate: float = 0.0  # probability that a person is missed in one view
    fp_rate: float = 0.0  # mean false-positive detections per view per frame (Poisson)
    min_joints_in_view: int = 5  # fewer valid joints in a view: not detected there

    def __post_init__(self) -> None:
        # Hydra hands over ListConfig / str values; normalise them to plain Python types.
        plain = {"int": int, "float": float, "bool": bool, "str": str}
        for f in fields(self):
            if f.type in plain:
                try:
                    setattr(self, f.name, plain[f.type](getattr(self, f.name)))
                except (TypeError, ValueError):
                    raise ValueError(
                        f"synthetic dataset option {f.name}={getattr(self, f.name)!r} must be {f.type}"
                    ) from None
        if self.camera_radius_m is not None:
            self.camera_radius_m = float(self.camera_radius_m)
        self.walk_speed_mps = _floats(self.walk_speed_mps, 2, "walk_speed_mps")
        self.image_size = tuple(int(v) for v in _floats(self.image_size, 2, "image_size"))
        if self.area is not None:
            self.area = _floats(self.area, 4, "area")
        if self.positions is not None:
            self.positions = [_positions_frame(p, f) for f, p in enumerate(self.positions)]
        self._validate()

    def _validate(self) -> None:
        """Raise ValueError naming the first option that is out of range."""
        low_speed, high_speed = self.walk_speed_mps
        checks = [
            ("num_frames", self.num_frames >= 1, "must be >= 1"),
            ("num_persons", self.num_persons >= 1 or self.positions is not None, "must be >= 1"),
            ("density", self.density > 0, "must be > 0 persons per m^2"),
            ("min_spacing_m", self.min_spacing_m >= 0, "must be >= 0"),
            ("fps", self.fps > 0, "must be > 0"),
            ("walk_speed_mps", 0 <= low_speed <= high_speed, "must be [low, high], 0 <= low <= high"),
            ("num_cameras", self.num_cameras >= 2 or self.rig != "ring", "must be >= 2 (triangulation needs 2 views)"),
            ("camera_radius_m", self.camera_radius_m is None or self.camera_radius_m > 0, "must be > 0 or null"),
            ("image_size", min(self.image_size) > 0, "must be positive (width, height)"),
            ("focal_px", self.focal_px > 0, "must be > 0"),
            ("noise_px", self.noise_px >= 0, "must be >= 0"),
            ("noise_ref_depth_m", self.noise_ref_depth_m > 0, "must be > 0"),
            ("occluded_noise_scale", self.occluded_noise_scale >= 0, "must be >= 0"),
            ("fp_rate", self.fp_rate >= 0, "must be >= 0"),
            ("min_joints_in_view", self.min_joints_in_view >= 1, "must be >= 1"),
            ("positions", self.positions is None or len(self.positions) >= 1, "must hold at least one frame"),
        ]
        for key in ("walking_fraction", "occluded_drop_prob", "miss_rate"):
            checks.append((key, 0.0 <= getattr(self, key) <= 1.0, "must be a probability in [0, 1]"))
        if self.area is not None:
            xmin, xmax, ymin, ymax = self.area
            checks.append(("area", xmin < xmax and ymin < ymax, "must be [xmin, xmax, ymin, ymax] with min < max"))
        for key, ok, what in checks:
            if not ok:
                raise ValueError(f"synthetic dataset option {key}={getattr(self, key)!r} {what}")

    def to_dict(self) -> dict[str, Any]:
        """The options as plain Python types (lists, not tuples or arrays), e.g. for Sequence.meta."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple):
                value = list(value)
            elif f.name == "positions" and value is not None:
                value = [p.tolist() for p in value]
            out[f.name] = value
        return out


OBSERVATION_KEYS = tuple(
    "noise_px noise_ref_depth_m noise_depth_exponent occlusion occluded_drop_prob occluded_noise_scale miss_rate"
    " fp_rate min_joints_in_view".split()
)


def observation_options(where: str, options: dict, keys: tuple[str, ...] = OBSERVATION_KEYS, **fixed: Any) -> dict:
    """SyntheticConfig's observation defaults, then ``fixed``, then ``options`` (names outside keys: ValueError)."""
    unknown = sorted(set(options) - set(keys))
    if unknown:
        raise ValueError(f"{where}: unknown option {unknown[0]!r} (known: {', '.join(keys)})")
    return {**{k: getattr(SyntheticConfig, k) for k in OBSERVATION_KEYS}, **fixed, **options}


def _floats(value: Any, n: int, key: str) -> tuple[float, ...]:
    """A tuple of n finite floats, or a ValueError naming the option."""
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"synthetic dataset option {key}={value!r} must be a list of {n} numbers") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise ValueError(f"synthetic dataset option {key}={value!r} must be a list of {n} finite numbers")
    return out


def _positions_frame(value: Any, frame: int) -> np.ndarray:
    """One frame of the positions hook as a new (N, 2) float array (NaN rows allowed)."""
    arr = np.array(value, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"synthetic dataset option positions[{frame}] has shape {arr.shape}, expected (N, 2)")
    if np.any(np.isinf(arr)):
        raise ValueError(f"synthetic dataset option positions[{frame}] has an infinite value")
    return arr
