"""Wildtrack as a semi-synthetic crowd: the 7 real calibrations, synthetic bodies at the annotated positions."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from data.geometry.calibration import load_wildtrack, load_wildtrack_positions
from data.geometry.camera import Rig
from data.multiview import Frame, Sequence
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.config import observation_options

POSITIONS_FILE = "gt_positions_mvdet.txt"
# The annotated region (m), grid cells 0..480 x 0..1440 of 2.5 cm from (-3, -9).
WILDTRACK_AREA = (-3.0, 9.0, -9.0, 27.0)


def load_wildtrack_crowd(
    root: str | Path = "../shared/data/wildtrack",
    frames: int | list[int] = 20,
    seed: int = 0,
    coco_min_joints: int = 1,
    coco_max_dets: int = 100,
    **observation: Any,
) -> Sequence:
    """The Wildtrack rig (7 views) and synthetic bodies, GT (P, 23, 4), at the positions of ``frames`` (N or a list)."""
    options = observation_options("load_wildtrack_crowd", observation, noise_px=5.0, noise_depth_exponent=0.0)
    root = Path(root)
    rig = load_wildtrack(root)
    positions = load_wildtrack_positions(root / POSITIONS_FILE)
    chosen = _choose_frames(positions, frames, root / POSITIONS_FILE)
    out = [_frame(number, positions[number], rig, root, seed, options) for number in chosen]
    meta = {"dataset": "wildtrack", "root": str(root), "frames": chosen, "seed": int(seed), "options": options}
    protocol = [{"name": "reprojection_coco", "min_joints": coco_min_joints, "max_dets": coco_max_dets}]
    description = _description(chosen, positions, seed, options)
    return Sequence(rig, out, meta, description=description, protocol_inputs=protocol)


def _frame(number: int, positions: np.ndarray, rig: Rig, root: Path, seed: int, options: dict) -> Frame:
    """Frame ``number``: synthetic bodies standing at its annotated positions (P, 2), drawn from (seed, number)."""
    frame_seed = int(np.random.SeedSequence([int(seed), number]).generate_state(1)[0])
    fixed = dict(area=WILDTRACK_AREA, min_spacing_m=0.0, rig=str(root), rig_format="wildtrack")
    cfg = SyntheticConfig(seed=frame_seed, positions=[positions], **fixed, **options)
    frame = generate_sequence(cfg, rig=rig).frames[0]
    return Frame(number, frame.views, frame.gt_poses, frame.gt_ids)


def _choose_frames(positions: dict[int, np.ndarray], frames: int | list[int], path: Path) -> list[int]:
    """The annotated frame numbers asked for: the first N (int) or the listed ones, each annotated."""
    numbers = sorted(positions)
    if isinstance(frames, (int, np.integer)) and not isinstance(frames, bool):
        if not 1 <= frames <= len(numbers):
            raise ValueError(f"{path}: frames={frames}, expected 1..{len(numbers)} (the annotated frames)")
        return numbers[: int(frames)]
    chosen = [int(f) for f in frames]
    missing = [f for f in chosen if f not in positions]
    if missing or not chosen:
        raise ValueError(
            f"{path}: frame {missing[0] if missing else '(none)'} is not annotated "
            f"(annotated: {numbers[0]}, {numbers[1]}, ..., {numbers[-1]})"
        )
    return chosen


def _description(chosen: list[int], positions: dict[int, np.ndarray], seed: int, o: dict) -> str:
    """One line saying what the sequence is, from the observation options o."""
    people = np.mean([len(positions[f]) for f in chosen])
    exponent = o["noise_depth_exponent"]
    depth = "every depth" if exponent == 0 else f"{o['noise_ref_depth_m']:g} m x (depth ratio)^{exponent:g}"
    return (
        f"Wildtrack rig (7 real calibrations), synthetic bodies at the annotated positions of {len(chosen)} "
        f"frames ({people:.1f} persons per frame), seed {seed}: 2D noise {o['noise_px']:g} px at {depth}, "
        f"occlusion {'on' if o['occlusion'] else 'off'}, miss rate {o['miss_rate']:g}, "
        f"false positives {o['fp_rate']:g} per view"
    )
