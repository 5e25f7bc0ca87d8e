"""Synthetic multi-view crowd sequences with ground truth: the scene, the rig and the detections."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from data.geometry.calibration import load_rig
from data.geometry.camera import Rig
from data.multiview import Frame, Sequence
from data.synthetic.config import SyntheticConfig
from data.synthetic.observe import observe_view
from data.synthetic.rigs import ring_rig
from data.synthetic.scene import scene_poses, simulate_scene

RING_CLEARANCE_M = 4.0  # default ring radius: the area's half diagonal plus this
PROGRESS_MIN_WORK = 200  # persons x cameras per frame from which building the frames shows a progress bar


def build_rig(cfg: SyntheticConfig, area: tuple[float, float, float, float]) -> Rig:
    """The rig of cfg.rig: a ring around the centre of the area (xmin, xmax, ymin, ymax), or a calibration file."""
    if cfg.rig == "ring":
        xmin, xmax, ymin, ymax = area
        look_at = ((xmin + xmax) / 2, (ymin + ymax) / 2, cfg.look_at_height_m)
        radius = cfg.camera_radius_m
        if radius is None:
            radius = float(np.hypot(xmax - xmin, ymax - ymin)) / 2 + RING_CLEARANCE_M
        return ring_rig(cfg.num_cameras, radius, cfg.camera_height_m, look_at, cfg.image_size, cfg.focal_px)
    return load_rig(cfg.rig, cfg.rig_format)


def generate_sequence(cfg: SyntheticConfig, rig: Rig | None = None) -> Sequence:
    """Synthetic Sequence of F frames, V views, gt_poses (P, 23, 4), gt_ids (P,); streams seeded by cfg.seed."""
    scene_seed, render_seed = np.random.SeedSequence(cfg.seed).spawn(2)
    scene = simulate_scene(cfg, np.random.default_rng(scene_seed))
    if rig is None:
        rig = build_rig(cfg, scene.area)
    poses = scene_poses(scene)
    frames = []
    seeds = render_seed.spawn(scene.num_frames)
    quiet = True if scene.num_persons * len(rig) < PROGRESS_MIN_WORK else None  # None: a bar on a terminal only
    for f, frame_seed in enumerate(tqdm(seeds, desc="synthetic frames", unit="frame", leave=False, disable=quiet)):
        rng = np.random.default_rng(frame_seed)
        ids = np.flatnonzero(scene.present[f])
        views = [observe_view(cam, poses[f, ids], ids, cfg, rng) for cam in rig]
        gt = np.concatenate([poses[f, ids], np.ones((len(ids), poses.shape[2], 1))], axis=-1)
        frames.append(Frame(index=f, views=views, gt_poses=gt, gt_ids=ids.astype(np.int64)))
    persons = [
        {"id": i, "stature": b.stature, "walking": bool(scene.walking[:, i].any())} for i, b in enumerate(scene.bodies)
    ]
    meta = {"source": "synthetic", "config": cfg.to_dict(), "persons": persons}
    return Sequence(rig, frames, meta, persistent_ids=True, area=tuple(float(v) for v in scene.area))
