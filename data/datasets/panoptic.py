"""CMU Panoptic sequences as shipped as a Sequence: GT joints19 in m, z up, as COCO-23; 2D from poses2d.json or GT."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from data.datasets.files import position_slice
from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import load_panoptic, panoptic_world_to_ours
from data.geometry.camera import Camera, Rig
from data.keypoints import FOOT_JOINTS, LEFT_ANKLE, LEFT_FOOT, PANOPTIC19_TO_COCO23, RIGHT_ANKLE, RIGHT_FOOT, to_coco23
from data.multiview import Frame, Sequence, ViewDetections
from data.synthetic.config import SyntheticConfig, observation_options
from data.synthetic.observe import bbox_from_keypoints, observe_view

# The five HD cameras of VoxelPose's Panoptic experiments (panel 0, nodes 3, 6, 12, 13, 23).
DEFAULT_CAMERAS = ("00_03", "00_06", "00_12", "00_13", "00_23")
POSE_DIR = "hdPose3d_stage1_coco19"
GT_MIN_CONFIDENCE = 0.1
NUM_PANOPTIC_JOINTS = 19
_POSE_FILE = re.compile(r"body3DScene_(\d+)\.json")


def load_panoptic_sequence(
    root: str | Path,
    sequence: str = "160906_band1",
    cameras: list[str] | None = None,  # None: DEFAULT_CAMERAS
    frames: list[int] | slice | str | None = None,  # frame numbers, or a slice / "start:stop[:step]" of positions
    poses2d: str | None = None,
    seed: int = 0,
    **observation: Any,
) -> Sequence:
    """One Panoptic sequence: the rig of ``cameras``, GT (P, 23, 4) and V 2D views per frame."""
    keys = ("noise_px", "occlusion", "occluded_drop_prob", "occluded_noise_scale", "min_joints_in_view")
    fixed = dict(noise_depth_exponent=0.0, miss_rate=0.0, fp_rate=0.0)
    observation = observation_options("load_panoptic_sequence", observation, keys, **fixed)
    seq_dir = Path(root) / sequence
    names = list(DEFAULT_CAMERAS if cameras is None else (str(c) for c in cameras))
    rig = load_panoptic(seq_dir / f"calibration_{sequence}.json", names)
    all_files = find_pose_files(seq_dir)
    files = _select_frames(all_files, frames, seq_dir / POSE_DIR)
    ground_truth = {frame: read_bodies(path) for frame, path in files.items()}
    meta = {"dataset": "panoptic", "root": str(root), "sequence": sequence, "cameras": names}
    meta["gt_min_confidence"] = GT_MIN_CONFIDENCE
    gt15 = {}
    if poses2d is not None:
        views_by_frame = read_poses2d(poses2d, list(rig.names), [c.size for c in rig])
        meta["poses2d"] = str(poses2d)
        source = f"2D poses from {poses2d}"
    else:
        cfg, rng = SyntheticConfig(**observation), np.random.default_rng(seed)
        views_by_frame = {
            f: observe_ground_truth(rig, _coco23(joints19), ids, cfg, rng)
            for f, (ids, joints19) in ground_truth.items()
        }
        source = (
            f"2D generated from GT: {observation['noise_px']} px noise, occlusion "
            f"{'on' if observation['occlusion'] else 'off'}, seed {seed}, no foot joints"
        )
    out = []
    for frame, (ids, joints19) in ground_truth.items():
        gt15[frame] = panoptic19_to_ours(joints19)[:, :15]
        views = views_by_frame.get(frame) or [ViewDetections.empty() for _ in names]
        out.append(Frame(frame, views, _coco23(joints19), ids))
    # Counted, not dropped silently: GT frames without 2D input, 2D frames without GT (not evaluated).
    meta["frames_without_2d"] = sum(f not in views_by_frame for f in ground_truth)
    meta["frames_2d_without_gt"] = sum(f not in all_files for f in views_by_frame)
    description = f"CMU Panoptic {sequence}: cameras {', '.join(names)}; {source}"
    protocol = [{"name": "panoptic", "gt15": gt15}]  # Panoptic body ids name one person over the sequence
    return Sequence(rig, out, meta, description=description, persistent_ids=True, protocol_inputs=protocol)


def find_pose_files(seq_dir: str | Path) -> dict[int, Path]:
    """{frame number: path} of the body3DScene_*.json files of a sequence folder, by frame number."""
    pose_dir = Path(seq_dir) / POSE_DIR
    if not pose_dir.is_dir():
        raise FileNotFoundError(f"{pose_dir}: Panoptic ground-truth folder not found")
    found = {int(m.group(1)): p for p in pose_dir.iterdir() if (m := _POSE_FILE.fullmatch(p.name))}
    if not found:
        raise FileNotFoundError(f"{pose_dir}: no body3DScene_*.json files")
    return dict(sorted(found.items()))


def read_bodies(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A body3DScene file -> body ids (G,), joints19 (G, 19, 4) as stored (cm, y down, confidence)."""
    try:
        with open(path, encoding="utf-8") as f:
            bodies = json.load(f)["bodies"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: cannot read Panoptic bodies ({type(exc).__name__}: {exc})") from None
    if not isinstance(bodies, list):
        raise ValueError(f"{path}: 'bodies' is not a list")
    ids, joints = [], []
    for n, body in enumerate(bodies):
        try:
            ids.append(int(body["id"]))
            j19 = np.array(body["joints19"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{path}: bodies[{n}] needs an integer 'id' and numeric 'joints19'") from None
        if j19.size != NUM_PANOPTIC_JOINTS * 4 or not np.all(np.isfinite(j19)):
            raise ValueError(f"{path}: bodies[{n}] (id {ids[-1]}) 'joints19' must be 76 finite numbers, got {j19.size}")
        joints.append(j19.reshape(NUM_PANOPTIC_JOINTS, 4))
    return np.array(ids, dtype=np.int64), np.array(joints).reshape(-1, NUM_PANOPTIC_JOINTS, 4)


def panoptic19_to_ours(joints19: np.ndarray) -> np.ndarray:
    """Panoptic joints (cm, y down, confidence): (..., 19, 4) -> (metres, z up, validity 0/1) (..., 19, 4)."""
    joints19 = np.asarray(joints19, dtype=np.float64)
    valid = joints19[..., 3:4] > GT_MIN_CONFIDENCE
    xyz = np.where(valid, panoptic_world_to_ours(joints19[..., :3]), 0.0)
    return np.concatenate([xyz, valid.astype(np.float64)], axis=-1)


def _coco23(joints19: np.ndarray) -> np.ndarray:
    """Panoptic joints as stored -> COCO-23 ground truth (m, z up, validity), feet invalid: (G, 19, 4) -> (G, 23, 4)."""
    return to_coco23(panoptic19_to_ours(joints19), PANOPTIC19_TO_COCO23)


def observe_ground_truth(
    rig: Rig, gt_poses: np.ndarray, gt_ids: np.ndarray, cfg: SyntheticConfig, rng: np.random.Generator
) -> list[ViewDetections]:
    """Noisy, occluded 2D detections of GT poses (P, 23, 4) with ids (P,) in every camera: V ViewDetections."""
    gt_poses = np.asarray(gt_poses, dtype=np.float64)
    ids = np.asarray(gt_ids, dtype=np.int64)
    valid_by_id = {int(i): gt_poses[n, :, 3] > 0 for n, i in enumerate(ids)}
    filled = _fill_invalid(gt_poses)
    return [_mask_invalid(observe_view(camera, filled, ids, cfg, rng), valid_by_id, camera, cfg) for camera in rig]


def _fill_invalid(poses: np.ndarray) -> np.ndarray:
    """World joints with invalid ones filled (see observe_ground_truth): (P, 23, 4) -> new (P, 23, 3)."""
    out = poses[..., :3].copy()
    for p, pose in enumerate(poses):
        valid = pose[:, 3] > 0
        centre = pose[valid, :3].mean(axis=0) if np.any(valid) else np.zeros(3)
        out[p, ~valid] = centre
        for ankle, foot in ((LEFT_ANKLE, LEFT_FOOT), (RIGHT_ANKLE, RIGHT_FOOT)):
            for j in foot:
                if not valid[j]:
                    out[p, j] = out[p, ankle]
    return out


def _mask_invalid(
    views: ViewDetections, valid_by_id: dict[int, np.ndarray], camera: Camera, cfg: SyntheticConfig
) -> ViewDetections:
    """Zero the joints invalid in the ground truth, drop persons left with too few joints, redo boxes."""
    keypoints = views.keypoints.copy()
    for n, pid in enumerate(views.person_ids):
        if pid >= 0:
            keypoints[n, ~valid_by_id[int(pid)]] = 0.0
    keypoints[:, list(FOOT_JOINTS)] = 0.0
    keep = (keypoints[..., 2] > 0).sum(axis=1) >= cfg.min_joints_in_view
    if not np.any(keep):
        return ViewDetections.empty(keypoints.shape[1])
    keypoints = keypoints[keep]
    valid = keypoints[..., 2] > 0
    scores = (keypoints[..., 2] * valid).sum(axis=1) / valid.sum(axis=1)
    return ViewDetections(
        keypoints, bbox_from_keypoints(keypoints, camera.size), scores, views.person_ids[keep], views.occluded[keep]
    )


def _select_frames(files: dict[int, Path], frames: list[int] | slice | str | None, pose_dir: Path) -> dict[int, Path]:
    """The requested subset of {frame: path} (see load_panoptic_sequence for ``frames``)."""
    if frames is None:
        return files
    if isinstance(frames, str):
        frames = position_slice(frames)
    numbers = list(files)
    if isinstance(frames, slice):
        return {f: files[f] for f in numbers[frames]}
    missing = [int(f) for f in frames if int(f) not in files]
    if missing:
        raise ValueError(
            f"{pose_dir}: frame {missing[0]} requested but body3DScene_{missing[0]:08d}.json "
            f"is not there (found {numbers[0]}..{numbers[-1]}, {len(numbers)} files)"
        )
    return {int(f): files[int(f)] for f in frames}
