"""Reference bone lengths of the MAP bone prior (paper Eq. 7), and their estimation from 3D ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from data.keypoints import BONES, COCO23_NAMES, NUM_JOINTS

RELATIVE_SD = 0.057
ABSOLUTE_SD_M = 0.010

# Mean bone length (m) of the 1.70 m mean body by bone name; a sided name ("torso") stands for both sides.
_MEAN_M: Mapping[str, float] = {
    "shoulders": 0.3740,
    "hips": 0.1870,
    "torso": 0.4984,
    "upper_arm": 0.3162,
    "forearm": 0.2482,
    "thigh": 0.4165,
    "shin": 0.4182,
    "nose_eye": 0.0556,
    "eye_ear": 0.0900,
    "ankle_heel": 0.0788,
    "ankle_big_toe": 0.2233,
    "toes": 0.0802,
    "heel_big_toe": 0.2556,
}

# The same mean body standing (knees 3 deg flexed), which initialises unseen joints: x forward, y left, z up, lowest
# sole point at z = 0, rounded to 1 mm; a sided name gives the left joint, the right one is its mirror (y -> -y).
_MEAN_POSITION_M: Mapping[str, tuple[float, float, float]] = {
    "nose": (0.111, 0.000, 1.559),
    "eye": (0.085, 0.032, 1.597),
    "ear": (0.009, 0.072, 1.571),
    "shoulder": (0.000, 0.187, 1.389),
    "elbow": (0.000, 0.231, 1.076),
    "wrist": (0.052, 0.265, 0.836),
    "hip": (0.000, 0.093, 0.900),
    "knee": (0.000, 0.109, 0.484),
    "ankle": (-0.022, 0.124, 0.066),
    "big_toe": (0.191, 0.129, 0.000),
    "small_toe": (0.142, 0.192, 0.000),
    "heel": (-0.064, 0.120, 0.000),
}


def _by_side(table: Mapping, name: str, mirror: bool = False) -> Any:
    """The entry of a name in a table whose sided entries are keyed without "left_" / "right_"."""
    side, _, rest = name.partition("_")
    if name in table or side not in ("left", "right"):
        return table[name]
    value = table[rest]
    return (value[0], -value[1], value[2]) if mirror and side == "right" else value


def _frozen(values: Any, dtype: Any = np.float64) -> np.ndarray:
    """A read-only array copy."""
    out = np.array(values, dtype=dtype)
    out.flags.writeable = False
    return out


BONE_NAMES: tuple[str, ...] = tuple(BONES)
BONE_PAIRS = _frozen([BONES[n] for n in BONE_NAMES], np.int64)  # (L, 2)
BONE_MEAN = _frozen([_by_side(_MEAN_M, n) for n in BONE_NAMES])  # (L,)
BONE_STD = _frozen(np.sqrt((RELATIVE_SD * BONE_MEAN) ** 2 + ABSOLUTE_SD_M**2))  # (L,)
MEAN_POSE = _frozen([_by_side(_MEAN_POSITION_M, n, mirror=True) for n in COCO23_NAMES])  # (J, 3)


def bone_lengths(poses: np.ndarray) -> np.ndarray:
    """Length of every bone of every pose (m): (..., J, >=3) -> (..., L)."""
    poses = np.asarray(poses, dtype=np.float64)
    return np.linalg.norm(poses[..., BONE_PAIRS[:, 0], :3] - poses[..., BONE_PAIRS[:, 1], :3], axis=-1)


def estimate_bone_table(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, SD (ddof 1, NaN below 2 samples) and count of each bone over valid joint pairs: (N, J, 4) -> (L,) x3."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, NUM_JOINTS, 4)
    ok = (poses[..., 3] > 0) & np.all(np.isfinite(poses[..., :3]), axis=-1)
    both = ok[:, BONE_PAIRS[:, 0]] & ok[:, BONE_PAIRS[:, 1]]
    lengths = np.where(both, bone_lengths(np.where(ok[..., None], poses, 0.0)), 0.0)
    count = both.sum(axis=0)
    mean = np.where(count > 0, lengths.sum(axis=0) / np.maximum(count, 1), np.nan)
    sq = np.where(both, (lengths - mean) ** 2, 0.0).sum(axis=0)
    std = np.where(count > 1, np.sqrt(sq / np.maximum(count - 1, 1)), np.nan)
    return mean, std, count


def bone_table_dict(mean: np.ndarray, std: np.ndarray, count: np.ndarray | None = None, source: str = "") -> dict:
    """The JSON document of a bone table, bones without a finite mean and SD left out: (L,) x 3 -> dict."""
    bones = {}
    for i, name in enumerate(BONE_NAMES):
        if np.isfinite(mean[i]) and np.isfinite(std[i]) and std[i] > 0:
            entry = {"mean": round(float(mean[i]), 5), "std": round(float(std[i]), 5)}
            if count is not None:
                entry["count"] = int(count[i])
            bones[name] = entry
    return {"source": source, "units": "m", "bones": bones}


def resolve_bone_table(table: str | Path | Mapping | None) -> tuple[np.ndarray, np.ndarray]:
    """Reference mean, std (L,) from None (defaults), a JSON path or {"bones": ...}; bad bone or value: ValueError."""
    mean, std = BONE_MEAN.copy(), BONE_STD.copy()
    if table is None:
        return mean, std
    where = "bone table"
    if isinstance(table, (str, Path)):
        where = f"bone table {table}"
        try:
            table = json.loads(Path(table).read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{where}: cannot read it ({exc})") from None
    bones = table.get("bones", table) if isinstance(table, Mapping) else None
    if not isinstance(bones, Mapping):
        raise ValueError(f"{where}: expected a mapping 'bones' of name -> {{mean, std}}")
    for name, entry in bones.items():
        if name not in BONE_NAMES:
            raise ValueError(f"{where}: unknown bone {name!r} (known: {', '.join(BONE_NAMES)})")
        i = BONE_NAMES.index(name)
        try:
            m, s = float(entry["mean"]), float(entry["std"])
        except (TypeError, KeyError, ValueError):
            raise ValueError(f"{where}: bone {name!r} needs numeric 'mean' and 'std'") from None
        if not (np.isfinite(m) and np.isfinite(s) and m > 0 and s > 0):
            raise ValueError(f"{where}: bone {name!r} has mean {m} and std {s}; both must be finite and > 0")
        mean[i], std[i] = m, s
    return mean, std
