"""3D reconstruction stages behind one interface: ``stage(poses2d, bboxes, rig) -> Reconstruction`` (CONTRIBUTING)."""

from __future__ import annotations

import numpy as np

from data.geometry.camera import Rig
from data.geometry.triangulation import triangulate_dlt
from reconstruction.results import Reconstruction


class VanillaTriangulation:
    """Score-weighted DLT on undistorted pixels (the paper's "vanilla triangulation")."""

    takes_skeleton_prior = False

    def __init__(self, min_views: int = 2) -> None:
        self.min_views = min_views

    def __call__(self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> Reconstruction:
        """Triangulate matched persons: (V, P, J, 3), (V, P, 4) -> Reconstruction (poses (P, J, 4))."""
        und = rig.undistort(poses2d)
        poses = triangulate_dlt(und, rig.projection_matrices(), self.min_views)
        return Reconstruction(poses)
