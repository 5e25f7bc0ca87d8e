"""Heatmaps of person crops -> keypoints in image px (one peak per joint, or candidates and joint association)."""

from __future__ import annotations

from collections import defaultdict
from typing import Sequence

import numpy as np
import torch

from data.keypoints import FLIP_PAIRS
from models.candidates import candidates_to_image, find_candidates
from models.heatmap_codec import MultiModalHeatmapCodec
from models.joint_association import associate_joints

DECODERS = ("single", "association")
# the pairs separate_pairs keeps apart: shoulders down; the eyes and ears sit closer than min_sep anyway
SEPARATED_PAIRS = tuple((a, b) for a, b in FLIP_PAIRS if a >= 5)


def single_peaks(
    codec: MultiModalHeatmapCodec, heatmaps: torch.Tensor, inverse_affines: torch.Tensor | np.ndarray
) -> np.ndarray:
    """Heatmaps (B, 23, h, w), crop-to-image affines (B, 2, 3) -> keypoints (B, 23, 3) x, y, score in image px."""
    points, scores = codec.decode(heatmaps)
    affines = torch.as_tensor(inverse_affines, dtype=torch.float64).cpu().numpy().reshape(-1, 2, 3)
    xy = points @ affines[:, :, :2].transpose(0, 2, 1) + affines[:, None, :, 2]  # transform_points, batched
    return np.concatenate([xy, scores[..., None]], axis=-1)


def joint_candidates(
    codec: MultiModalHeatmapCodec,
    heatmaps: torch.Tensor,
    inverse_affines: torch.Tensor | np.ndarray,
    threshold: float = 0.1,
    top_m: int = 3,
) -> np.ndarray:
    """Heatmaps (B, 23, h, w), crop-to-image affines (B, 2, 3) -> candidates (B, 23, M, 3) x, y, score in image px."""
    xy, scores = find_candidates(heatmaps, threshold=threshold, top_m=top_m)
    stride = np.array(codec.input_size, dtype=np.float64) / np.array(codec.heatmap_size)
    return torch.cat([candidates_to_image(xy, inverse_affines, stride), scores[..., None]], dim=-1).cpu().numpy()


def associate_by_image(
    candidates: np.ndarray, boxes: np.ndarray, image_keys: Sequence, dist_thresh: float = 1.0
) -> np.ndarray:
    """Candidates (B, 23, M, 3), boxes (B, 4) xywh, image of each crop (B,) -> keypoints (B, 23, 3), per image."""
    by_image: dict = defaultdict(list)
    for i, key in enumerate(image_keys):
        by_image[key].append(i)
    out = np.zeros(candidates.shape[:2] + (3,))
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    for indices in by_image.values():
        cands = candidates[indices]
        out[indices] = associate_joints(cands[..., :2], cands[..., 2], boxes[indices], dist_thresh)
    return out


def separate_pairs(
    keypoints: np.ndarray, candidates: np.ndarray, boxes: np.ndarray, min_sep: float = 0.05, min_ratio: float = 0.3
) -> np.ndarray:
    """Keypoints (B, 23, 3), candidates (B, 23, M, 3), boxes (B, 4) xywh -> (B, 23, 3) with left/right joints apart."""
    # a network unsure of a person's sides gives both channels one arm: the side with the better other one moves
    out = np.array(keypoints, dtype=np.float64)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    for b in range(len(out)):
        x, y, w, h = boxes[b]
        sep, low, high = min_sep * h, np.array([x - 0.1 * w, y - 0.1 * h]), np.array([x + 1.1 * w, y + 1.1 * h])
        for left, right in SEPARATED_PAIRS:
            kl, kr = out[b, left], out[b, right]
            if kl[2] <= 0 or kr[2] <= 0 or np.hypot(*(kl[:2] - kr[:2])) >= sep:
                continue
            best = None
            for joint, other in ((left, kr), (right, kl)):
                c = candidates[b, joint]
                ok = (c[:, 2] >= min_ratio * out[b, joint, 2]) & (np.hypot(*(c[:, :2] - other[:2]).T) >= sep)
                ok &= np.all((c[:, :2] >= low) & (c[:, :2] <= high), axis=1)
                for k in np.flatnonzero(ok):
                    if best is None or c[k, 2] > best[1][2]:
                        best = (joint, c[k])
            if best is not None:
                out[b, best[0]] = best[1]
    return out


def person_scores(box_scores: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Box scores (B,) x mean joint score of keypoints (B, 23, 3) -> (B,); a box that lost its joints ranks low."""
    return np.asarray(box_scores, dtype=np.float64).reshape(-1) * np.asarray(keypoints)[..., 2].mean(axis=-1)
