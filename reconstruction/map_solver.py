"""MLE and MAP 3D crowd pose reconstruction (paper Sec. 3.3) behind the stage interface.

``stage(poses2d (V, P, J, 3) distorted px + score, bboxes (V, P, 4) x y w h, rig) -> (P, J, 4)``.

All persons of a frame are solved at once by the batched Levenberg-Marquardt of
:mod:`reconstruction.lm_solver` with the analytic normal equations of :mod:`reconstruction.map_estimation`,
initialised by the vanilla triangulation (DLT) and a fitted mean body for the joints it cannot
triangulate (:mod:`reconstruction.pose_init`). The cost separates over persons and over the connected
components of the bone graph, so the MLE is solved as P*J independent 3-variable problems and the MAP
as P problems per component (COCO-23: the 5 face joints and the 18 body and foot joints). The MAP uses
the exact Hessian of the bone prior once a person is near its optimum (see
:func:`reconstruction.map_estimation.linearize`); the solution is the same least-squares optimum as
scipy's trust-region least_squares on the same residuals (tests/test_map_reconstruction.py).

Sigma of a 2D joint: max(sigma_min, c sqrt(box_w box_h) / score) pixels. A top-down detector localises
joints to a fraction of the person's size (the box is resized to a fixed network input, so one
heatmap cell is ~box/64; COCO's OKS models the same error as a fraction of object scale), and a lower
heatmap score means a flatter, less certain peak, hence the 1/score. c = 0.02 gives ~6 px for a
300 px-tall person at score 1 (about 1.5 heatmap cells at 48 x 64 output), the typical error of
HRNet-class detectors; sigma_min = 1 px stops near-zero boxes or scores from making a joint infinitely
certain (the detector's own pixel quantisation). c = 0 gives a constant sigma_min for every joint.

Output confidence: a joint triangulated by the DLT (seen in >= min_views views) keeps the DLT
confidence (mean score of its views); a joint seen in fewer views but at least one gets
single_view_score x the mean score of its views; an unseen joint placed by the prior and the fitted
body gets unseen_score; joints seen in fewer than output_min_views views are output as 0 (x, y, z and
score), as the DLT does. A person without a single usable triangulated joint is output as all 0.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from data.bone_lengths import BONE_PAIRS, resolve_bone_table
from reconstruction.camera import Rig
from reconstruction.lm_solver import LMResult, levenberg_marquardt
from reconstruction.map_estimation import ROBUST_LOSSES, PoseProblem, cost, joint_sigma, linearize
from reconstruction.pose_init import initial_poses, reinitialise_outliers
from reconstruction.triangulation import triangulate_dlt


def bone_components(num_joints: int, bone_pairs: np.ndarray) -> list[np.ndarray]:
    """Joint sets connected by bones (singletons included), each sorted: J, (L, 2) -> list of (j,) arrays."""
    pairs = np.asarray(bone_pairs, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num_joints, num_joints))
    _, label = connected_components(graph, directed=False)
    return [np.flatnonzero(label == k) for k in np.unique(label)]


def solve_poses(problem: PoseProblem, X0: np.ndarray, max_iterations: int = 15, xtol: float = 1e-6,
                ftol: float = 1e-10) -> tuple[np.ndarray, list[LMResult]]:
    """Minimise the problem's cost from X0 (P, J, 3) -> (P, J, 3), one LMResult per independent block.

    The cost separates over persons and over the connected components of the bone graph (COCO-23:
    the face, the body with the feet); each component is a batch of P problems of 3j variables, and
    joints without a bone are P*j problems of 3 variables. Same optimum, smaller linear systems.
    """
    X0 = np.asarray(X0, dtype=np.float64)
    P, J, _ = X0.shape
    on = problem.bone_weight > 0
    problem = replace(problem, bone_pairs=problem.bone_pairs[on].reshape(-1, 2), bone_ref=problem.bone_ref[on],
                      bone_weight=problem.bone_weight[on])
    comps = bone_components(J, problem.bone_pairs)
    singles = np.concatenate([c for c in comps if len(c) == 1] or [np.zeros(0, np.int64)])
    X, results = X0.copy(), []
    for joints in [c for c in comps if len(c) > 1] + ([singles] if len(singles) else []):
        sub = problem.joints(joints)
        if len(sub.bone_pairs) == 0:
            sub = sub.per_joint()
        n = sub.inv_sigma.shape[2]
        x0 = X0[:, joints].reshape(-1, 3 * n)

        def lin(x: np.ndarray, idx: np.ndarray, sub: PoseProblem = sub, n: int = n) -> tuple:
            """Normal equations of the problems idx at x (b, 3n)."""
            return linearize(x.reshape(len(x), n, 3), sub.take(idx))

        def cst(x: np.ndarray, idx: np.ndarray, sub: PoseProblem = sub, n: int = n) -> np.ndarray:
            """Costs (b,) of the problems idx at x (b, 3n)."""
            return cost(x.reshape(len(x), n, 3), sub.take(idx))

        result = levenberg_marquardt(x0, lin, cst, max_iterations, xtol, ftol)
        X[:, joints] = result.x.reshape(P, len(joints), 3)
        results.append(result)
    return X, results


def output_confidence(dlt_conf: np.ndarray, poses2d: np.ndarray, placed: np.ndarray, output_min_views: int,
                      single_view_score: float, unseen_score: float) -> np.ndarray:
    """Confidence of each reconstructed joint (see the module docstring): (P, J), (V, P, J, 3), (P,) -> (P, J)."""
    score = np.where(np.all(np.isfinite(poses2d[..., :2]), axis=-1), np.clip(poses2d[..., 2], 0, None), 0.0)
    views = (score > 0).sum(axis=0)
    mean_score = score.sum(axis=0) / np.maximum(views, 1)
    conf = np.where(dlt_conf > 0, dlt_conf,
                    np.where(views > 0, single_view_score * mean_score, unseen_score))
    return np.where((views >= output_min_views) & placed[:, None], conf, 0.0)


class MAPReconstruction:
    """DLT initialisation, then the MAP of Eq. 6 likelihood x Eq. 7 bone prior (mle_first: an MLE step first).

    Keys: c, sigma_min (2D joint sigma, see the module docstring); prior_weight (w on every bone
    residual, 0 = plain MLE); bone_table (None = data/bone_lengths.py defaults, a JSON path or a
    {"bones": {name: {mean, std}}} mapping); robust ("none", "huber", "cauchy") and robust_scale (in
    sigma units) on the likelihood; anchor_weight (Tikhonov tau, 1/m); max_iterations, xtol (m),
    ftol (relative) of the solver; min_views (DLT); output_min_views, single_view_score, unseen_score
    (output confidence).
    """

    def __init__(self, c: float = 0.02, sigma_min: float = 1.0, prior_weight: float = 1.0,
                 bone_table: str | Path | Mapping | None = None, robust: str = "none", robust_scale: float = 3.0,
                 anchor_weight: float = 1e-3, max_iterations: int = 15, xtol: float = 1e-6, ftol: float = 1e-10,
                 min_views: int = 2, output_min_views: int = 0, single_view_score: float = 0.5,
                 unseen_score: float = 0.1, mle_first: bool = False) -> None:
        if robust not in ROBUST_LOSSES:
            raise ValueError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
        for key, value in (("robust_scale", robust_scale), ("max_iterations", max_iterations)):
            if not value > 0:
                raise ValueError(f"{key} must be > 0, got {value}")
        for key, value in (("c", c), ("sigma_min", sigma_min), ("prior_weight", prior_weight),
                           ("anchor_weight", anchor_weight)):
            if not value >= 0:
                raise ValueError(f"{key} must be >= 0, got {value}")
        if sigma_min == 0 and c == 0:
            raise ValueError("c and sigma_min cannot both be 0")
        self.c, self.sigma_min, self.prior_weight = float(c), float(sigma_min), float(prior_weight)
        self.bone_mean, self.bone_std = resolve_bone_table(bone_table)
        self.robust, self.robust_scale = robust, float(robust_scale)
        self.anchor_weight = float(anchor_weight)
        self.max_iterations, self.xtol, self.ftol = int(max_iterations), float(xtol), float(ftol)
        self.min_views, self.output_min_views = int(min_views), int(output_min_views)
        self.single_view_score, self.unseen_score = float(single_view_score), float(unseen_score)
        self.mle_first = bool(mle_first)

    def problem(self, poses2d_und: np.ndarray, bboxes: np.ndarray, proj: np.ndarray, anchor: np.ndarray,
                prior: bool) -> PoseProblem:
        """The least-squares problem of undistorted poses: (V, P, J, 3), (V, P, 4), (V, 3, 4), (P, J, 3) -> PoseProblem."""
        sigma = joint_sigma(poses2d_und, bboxes, self.c, self.sigma_min)
        inv_sigma = np.where(np.isfinite(sigma), 1.0 / sigma, 0.0)
        weight = self.prior_weight / self.bone_std if prior else np.zeros(len(BONE_PAIRS))
        return PoseProblem(proj, np.nan_to_num(poses2d_und[..., :2]), inv_sigma, BONE_PAIRS, self.bone_mean,
                           weight, anchor, self.anchor_weight, self.robust, self.robust_scale)

    def solve(self, poses2d_und: np.ndarray, bboxes: np.ndarray, proj: np.ndarray,
              stages: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """DLT, then one solve per stage (True = with the prior): -> X (P, J, 3), DLT (P, J, 4), placed (P,)."""
        dlt = triangulate_dlt(poses2d_und, proj, self.min_views)
        X, placed = initial_poses(dlt, poses2d_und, proj)
        idx = np.flatnonzero(placed)
        if len(idx) == 0:
            return X, dlt, placed
        und, boxes = poses2d_und[:, idx], np.asarray(bboxes, dtype=np.float64)[:, idx]
        Xp = X[idx]
        for k, prior in enumerate(stages):
            if k > 0:
                Xp = reinitialise_outliers(Xp, und, proj)
            Xp, _ = solve_poses(self.problem(und, boxes, proj, Xp, prior), Xp, self.max_iterations,
                                self.xtol, self.ftol)
        X = X.copy()
        X[idx] = Xp
        return X, dlt, placed

    def stages(self) -> tuple[bool, ...]:
        """The solves this reconstruction runs after the DLT (True = with the bone prior)."""
        return (False, True) if self.mle_first else (True,)

    def __call__(self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> np.ndarray:
        """Reconstruct matched persons: (V, P, J, 3), (V, P, 4) -> (P, J, 4)."""
        und = rig.undistort(poses2d)
        P, J = und.shape[1:3]
        if P == 0:
            return np.zeros((0, J, 4))
        X, dlt, placed = self.solve(und, bboxes, rig.projection_matrices(), self.stages())
        conf = output_confidence(dlt[..., 3], und, placed, self.output_min_views, self.single_view_score,
                                 self.unseen_score)
        return np.concatenate([np.where(conf[..., None] > 0, X, 0.0), conf[..., None]], axis=-1)


class MLEMAPReconstruction(MAPReconstruction):
    """The paper's full method: DLT -> MLE (likelihood only) -> MAP (likelihood x bone prior)."""

    def __init__(self, **kwargs: Any) -> None:
        """The keys of :class:`MAPReconstruction`, with mle_first = True."""
        kwargs.setdefault("mle_first", True)
        super().__init__(**kwargs)


class MLEReconstruction(MAPReconstruction):
    """DLT, then the maximum-likelihood refinement of Eq. 6 alone (no prior; joints stay independent)."""

    def __init__(self, c: float = 0.02, sigma_min: float = 1.0, robust: str = "none", robust_scale: float = 3.0,
                 anchor_weight: float = 1e-3, max_iterations: int = 15, xtol: float = 1e-6, ftol: float = 1e-10,
                 min_views: int = 2, output_min_views: int = 2, single_view_score: float = 0.5,
                 unseen_score: float = 0.1) -> None:
        super().__init__(c=c, sigma_min=sigma_min, prior_weight=0.0, robust=robust, robust_scale=robust_scale,
                         anchor_weight=anchor_weight, max_iterations=max_iterations, xtol=xtol, ftol=ftol,
                         min_views=min_views, output_min_views=output_min_views,
                         single_view_score=single_view_score, unseen_score=unseen_score)

    def stages(self) -> tuple[bool, ...]:
        """One solve without the prior."""
        return (False,)
