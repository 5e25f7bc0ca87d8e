"""Reprojection error of 3D joints in undistorted pixels, against the 2D detections or the GT (paper Table 3)."""

from __future__ import annotations

import numpy as np

from data.geometry.camera import Rig
from data.geometry.triangulation import reprojection_error
from data.multiview import ViewDetections
from reconstruction.pipeline import gather_views


def reprojection_stats(errors: np.ndarray) -> dict[str, float]:
    """Mean, min, max, variance (population) and count of the finite errors: (...) px -> dict (NaN when none)."""
    err = np.asarray(errors, dtype=np.float64).ravel()
    err = err[np.isfinite(err)]
    stats = {k: float(getattr(err, k)()) if err.size else float("nan") for k in ("mean", "min", "max", "var")}
    return {**stats, "count": int(err.size)}


def frame_reprojection_errors(
    poses3d: np.ndarray,
    assignment: np.ndarray,
    views: list[ViewDetections],
    rig: Rig,
    gt_points3d: np.ndarray | None = None,
) -> np.ndarray:
    """Pixel errors of one frame: (P, J, 4), (P, V), V views [, GT (P, J, 3|4)] -> (V, P, J), NaN where unscored."""
    poses2d, _ = gather_views(views, assignment)
    und = rig.undistort(poses2d)
    proj = rig.projection_matrices()
    if gt_points3d is not None:
        gt = np.asarray(gt_points3d, dtype=np.float64)[..., :3]
        homog = np.concatenate([gt, np.ones(gt.shape[:-1] + (1,))], axis=-1)
        hom = np.einsum("vab,pjb->vpja", proj, homog)
        und = np.concatenate([hom[..., :2] / hom[..., 2:3], und[..., 2:3]], axis=-1)
    return reprojection_error(poses3d, und, proj)
