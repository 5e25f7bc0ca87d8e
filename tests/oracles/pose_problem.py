"""The MLE / MAP least-squares residuals in plain numpy (the solver's problem, written independently of its kernels)."""

from __future__ import annotations

import numpy as np

from reconstruction.solver.compiled_solver import PoseProblem

EPS_DEPTH = 1e-6


def _rho(z: np.ndarray, kind: str) -> np.ndarray:
    """scipy.optimize.least_squares' rho of squared residuals z."""
    if kind == "huber":
        return np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    return np.log1p(z) if kind == "cauchy" else z


def residual_vector(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """Raw residuals of each person, likelihood then bones then anchor: (P, J, 3) -> (P, 2VJ + L + 3J)."""
    proj = problem.proj
    hom = np.einsum("vab,pjb->vpja", proj[:, :, :3], X) + proj[:, None, None, :, 3]
    xy = hom[..., :2] / np.maximum(hom[..., 2:], EPS_DEPTH)
    w = problem.inv_sigma[..., None]
    lik = (np.where(w > 0, problem.uv - xy, 0.0) * w).transpose(1, 0, 2, 3).reshape(len(X), -1)
    pairs = np.asarray(problem.bone_pairs).reshape(-1, 2)
    bones = problem.bone_weight * (problem.bone_ref - np.linalg.norm(X[:, pairs[:, 0]] - X[:, pairs[:, 1]], axis=-1))
    anchor = problem.anchor_weight * (X - problem.anchor)
    return np.concatenate([lik, bones.reshape(len(X), -1), anchor.reshape(len(X), -1)], axis=1)


def cost(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """Each person's cost 0.5 (sum C^2 rho(r^2 / C^2) over the likelihood + |bones|^2 + |anchor|^2): -> (P,)."""
    r = residual_vector(X, problem)
    n = 2 * problem.inv_sigma.shape[0] * X.shape[1]
    C2 = problem.robust_scale**2
    return 0.5 * ((C2 * _rho(r[:, :n] ** 2 / C2, problem.robust)).sum(axis=1) + (r[:, n:] ** 2).sum(axis=1))
