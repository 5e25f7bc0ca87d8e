"""Residuals, costs and analytic normal equations of the MLE / MAP 3D pose problems (paper Sec. 3.3).

Per person p, with Q_pj the 3D joints (m):

- likelihood (Eq. 6), per joint j, view v with score > 0: r = (q_pjv - pi_v(Q_pj)) / sigma_pjv, two
  scalars, q in undistorted pixels and pi_v the (3, 4) projection matrix; optionally robustified;
- bone prior (Eq. 7), per bone l = (a, b): r = w_l (b_ref_l - |Q_a - Q_b|), w_l = prior_weight / sigma_l;
- anchor (Tikhonov), per joint: r = tau (Q_pj - A_pj), A the initial pose. tau (1/m, default 1e-3)
  is far below the curvature of an observed joint (~1e1-1e4 per m^2), so it moves the optimum by
  ~1e-7 or less of the error there, but it fixes the directions nothing else determines (the depth
  of a joint seen in one view without a prior, the rotation of an unseen joint about its bone),
  which would otherwise leave the normal equations singular.

The robust loss follows scipy.optimize.least_squares: rho is applied to each scalar likelihood
residual, cost = 0.5 C^2 rho(r^2 / C^2) with C = robust_scale, and residuals and Jacobian rows are
rescaled (Triggs et al. correction) so the solver stays least squares. Bone and anchor residuals are
never robustified.

The Jacobian of a likelihood residual is dr/dQ = -(w / z) (M_k - uv_k M_3) (M = P[:, :3], z the depth,
uv the projection), that of a bone residual is -/+ w_l u^T on Q_a / Q_b (u the unit bone direction).
J^T J and J^T r are assembled block by block (3 x 3 per joint and per bone), never as a dense Jacobian.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

ROBUST_LOSSES = ("none", "huber", "cauchy")
_EPS_DEPTH = 1e-6  # m; projections of points behind a camera are clamped to this depth


@dataclass(frozen=True)
class PoseProblem:
    """The least-squares problem of P persons with J joints each (shapes in the field comments)."""

    proj: np.ndarray          # (V, 3, 4) projection matrices of undistorted pixels
    uv: np.ndarray            # (V, P, J, 2) observed undistorted pixels (anything where unseen)
    inv_sigma: np.ndarray     # (V, P, J) 1 / sigma (1/px), 0 where the joint is not seen
    bone_pairs: np.ndarray    # (L, 2) joint indices of each bone; L may be 0
    bone_ref: np.ndarray      # (L,) reference lengths (m)
    bone_weight: np.ndarray   # (L,) prior_weight / sigma_l (1/m); 0 switches a bone off
    anchor: np.ndarray        # (P, J, 3) Tikhonov anchor (m)
    anchor_weight: float = 1e-3
    robust: str = "none"
    robust_scale: float = 3.0

    def take(self, idx: np.ndarray) -> "PoseProblem":
        """The problem of a subset of persons: idx (b,) sorted -> PoseProblem with P = b."""
        if len(idx) == self.inv_sigma.shape[1] and (len(idx) == 0 or idx[-1] == len(idx) - 1):
            return self
        return replace(self, uv=self.uv[:, idx], inv_sigma=self.inv_sigma[:, idx], anchor=self.anchor[idx])

    def joints(self, idx: np.ndarray) -> "PoseProblem":
        """The problem of a subset of joints, keeping the bones inside it: idx (j,) -> PoseProblem with J = j."""
        idx = np.asarray(idx, dtype=np.int64)
        new = np.full(self.inv_sigma.shape[2], -1)
        new[idx] = np.arange(len(idx))
        keep = np.all(new[self.bone_pairs] >= 0, axis=1) if len(self.bone_pairs) else np.zeros(0, bool)
        return replace(self, uv=self.uv[:, :, idx], inv_sigma=self.inv_sigma[:, :, idx], anchor=self.anchor[:, idx],
                       bone_pairs=new[self.bone_pairs[keep]].reshape(-1, 2), bone_ref=self.bone_ref[keep],
                       bone_weight=self.bone_weight[keep])

    def per_joint(self) -> "PoseProblem":
        """Without bones every joint is its own problem: P persons of J joints -> P*J persons of 1 joint."""
        V, P, J = self.inv_sigma.shape
        return replace(self, uv=self.uv.reshape(V, P * J, 1, 2), inv_sigma=self.inv_sigma.reshape(V, P * J, 1),
                       anchor=self.anchor.reshape(P * J, 1, 3), bone_pairs=np.zeros((0, 2), np.int64),
                       bone_ref=np.zeros(0), bone_weight=np.zeros(0))


def joint_sigma(poses2d: np.ndarray, bboxes: np.ndarray, c: float, sigma_min: float) -> np.ndarray:
    """Pixel SD of every 2D joint, max(sigma_min, c sqrt(w h) / score): (V, P, J, 3), (V, P, 4) -> (V, P, J).

    A box with no area falls back to the box of the person's keypoints in that view; unseen joints
    (score <= 0) get inf.
    """
    poses2d = np.asarray(poses2d, dtype=np.float64)
    bboxes = np.asarray(bboxes, dtype=np.float64)
    score = poses2d[..., 2]
    seen = (score > 0) & np.all(np.isfinite(poses2d[..., :2]), axis=-1)
    size = np.sqrt(np.clip(bboxes[..., 2], 0, None) * np.clip(bboxes[..., 3], 0, None))
    lo = np.where(seen[..., None], poses2d[..., :2], np.inf).min(axis=-2)
    hi = np.where(seen[..., None], poses2d[..., :2], -np.inf).max(axis=-2)
    extent = np.where(np.any(seen, axis=-1)[..., None], hi - lo, 0.0)
    size = np.where(size > 0, size, np.sqrt(extent[..., 0] * extent[..., 1]))
    sigma = np.maximum(sigma_min, c * size[..., None] / np.where(seen, score, 1.0))
    return np.where(seen, sigma, np.inf)


def robust_rho(z: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rho(z), rho'(z), rho''(z) of a loss on squared residuals z (scipy's definitions): (...) -> 3 x (...)."""
    if kind == "none":
        return z, np.ones_like(z), np.zeros_like(z)
    if kind == "huber":
        small = z <= 1.0
        zz = np.where(small, 1.0, z)
        sq = np.sqrt(zz)
        return (np.where(small, z, 2.0 * sq - 1.0), np.where(small, 1.0, 1.0 / sq),
                np.where(small, 0.0, -0.5 / (sq * zz)))
    if kind == "cauchy":
        return np.log1p(z), 1.0 / (1.0 + z), -1.0 / (1.0 + z) ** 2
    raise ValueError(f"robust loss must be one of {ROBUST_LOSSES}, got {kind!r}")


def _project_xy(X: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel x, y and clamped depth of 3D joints in every view: (P, J, 3), (V, 3, 4) -> 3 x (V, P, J)."""
    P, J, _ = X.shape
    hom = np.matmul(proj[:, :, :3], X.reshape(-1, 3).T) + proj[:, :, 3:]                     # (V, 3, P*J)
    depth = np.maximum(hom[:, 2], _EPS_DEPTH)
    shape = (len(proj), P, J)
    return (hom[:, 0] / depth).reshape(shape), (hom[:, 1] / depth).reshape(shape), depth.reshape(shape)


def likelihood_residuals(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """Raw (not robustified) reprojection residuals in sigma units: (P, J, 3) -> (V, P, J, 2), 0 where unseen."""
    x, y, _ = _project_xy(X, problem.proj)
    uv = np.stack([x, y], axis=-1)
    return np.where(problem.inv_sigma[..., None] > 0, problem.uv - uv, 0.0) * problem.inv_sigma[..., None]


def _bone_geometry(X: np.ndarray, problem: PoseProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lengths n (P, L), unit directions u (P, L, 3) (z where degenerate) and residuals r (P, L) of the bones."""
    d = X[:, problem.bone_pairs[:, 0]] - X[:, problem.bone_pairs[:, 1]]
    n = np.linalg.norm(d, axis=-1)
    u = np.where(n[..., None] > 1e-12, d / np.maximum(n, 1e-12)[..., None], [0.0, 0.0, 1.0])
    return n, u, problem.bone_weight * (problem.bone_ref - n)


def residual_vector(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """All raw residuals of each person, likelihood then bones then anchor: (P, J, 3) -> (P, 2VJ + L + 3J)."""
    lik = likelihood_residuals(X, problem).transpose(1, 0, 2, 3).reshape(len(X), -1)
    anchor = problem.anchor_weight * (X - problem.anchor)
    return np.concatenate([lik, _bone_geometry(X, problem)[2], anchor.reshape(len(X), -1)], axis=1)


def _robust_scaling(r: np.ndarray, problem: PoseProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust cost terms, residual scale and Jacobian scale of raw residuals: (...) -> 3 x (...)."""
    C2 = problem.robust_scale ** 2
    rho, d1, d2 = robust_rho(r ** 2 / C2, problem.robust)
    j_scale = np.sqrt(np.maximum(d1 + 2.0 * d2 * r ** 2 / C2, np.finfo(float).eps))
    return C2 * rho, d1 / j_scale, j_scale


def cost(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """Total cost of each person, 0.5 (sum rho(lik^2) + |bones|^2 + |anchor|^2): (P, J, 3) -> (P,)."""
    x, y, _ = _project_xy(X, problem.proj)
    w = problem.inv_sigma
    seen = w > 0
    r = [np.where(seen, problem.uv[..., 0] - x, 0.0) * w, np.where(seen, problem.uv[..., 1] - y, 0.0) * w]
    if problem.robust == "none":
        lik = r[0] ** 2 + r[1] ** 2
    else:
        lik = _robust_scaling(r[0], problem)[0] + _robust_scaling(r[1], problem)[0]
    anchor = problem.anchor_weight * (X - problem.anchor)
    return 0.5 * (lik.sum(axis=(0, 2)) + (_bone_geometry(X, problem)[2] ** 2).sum(axis=1)
                  + (anchor ** 2).sum(axis=(1, 2)))


def _likelihood_blocks(X: np.ndarray, problem: PoseProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost (P,), J^T J blocks (P, J, 3, 3) and J^T r (P, J, 3) of the likelihood terms."""
    x, y, depth = _project_xy(X, problem.proj)
    w = problem.inv_sigma
    seen = w > 0
    r = [np.where(seen, problem.uv[..., 0] - x, 0.0) * w, np.where(seen, problem.uv[..., 1] - y, 0.0) * w]
    M = problem.proj[:, :, :3, None, None]                                                   # (V, 3, 3, 1, 1)
    scale = -w / depth
    # rows[k][i] = d r_k / d Q_i = -(w / z) (M[k, i] - uv_k M[2, i]), each (V, P, J)
    rows = [[scale * (M[:, k, i] - proj_k * M[:, 2, i]) for i in range(3)] for k, proj_k in ((0, x), (1, y))]
    if problem.robust == "none":
        terms = r[0] ** 2 + r[1] ** 2
    else:
        scaled = [_robust_scaling(rk, problem) for rk in r]
        terms = scaled[0][0] + scaled[1][0]
        r = [rk * sc[1] for rk, sc in zip(r, scaled)]
        rows = [[row * sc[2] for row in rows_k] for rows_k, sc in zip(rows, scaled)]
    H = np.empty(X.shape[:2] + (3, 3))
    for i in range(3):
        for k in range(i, 3):
            H[..., i, k] = H[..., k, i] = (rows[0][i] * rows[0][k] + rows[1][i] * rows[1][k]).sum(axis=0)
    g = np.stack([(rows[0][i] * r[0] + rows[1][i] * r[1]).sum(axis=0) for i in range(3)], axis=-1)
    return 0.5 * terms.sum(axis=(0, 2)), H, g


def _incidence(problem: PoseProblem, J: int) -> np.ndarray:
    """Joint-bone incidence, 1 where joint j is an end of bone l: -> (J, L)."""
    L = len(problem.bone_pairs)
    out = np.zeros((J, L))
    out[problem.bone_pairs[:, 0], np.arange(L)] = 1.0
    out[problem.bone_pairs[:, 1], np.arange(L)] = 1.0
    return out


def _block_index(rows: np.ndarray, cols: np.ndarray, J: int) -> np.ndarray:
    """Flat positions in a (3J, 3J) matrix of the 3x3 blocks (rows[k], cols[k]): (K,), (K,) -> (K * 9,)."""
    r = 3 * np.asarray(rows)[:, None, None] + np.arange(3)[None, :, None]
    c = 3 * np.asarray(cols)[:, None, None] + np.arange(3)[None, None, :]
    return (r * 3 * J + c).reshape(-1)


def _assemble(diag: np.ndarray, K: np.ndarray, problem: PoseProblem, H: np.ndarray | None = None) -> np.ndarray:
    """Dense H from joint blocks (P, J, 3, 3) and bone blocks K (P, L, 3, 3) as [[K, -K], [-K, K]]: -> (P, 3J, 3J).

    With H given, the blocks are added to a copy of it instead of to zeros.
    """
    P, J = diag.shape[:2]
    a, b = problem.bone_pairs[:, 0], problem.bone_pairs[:, 1]
    jj = np.arange(J)
    out = np.zeros((P, 9 * J * J)) if H is None else H.reshape(P, -1).copy()
    if len(a):
        diag = diag + np.matmul(_incidence(problem, J), K.reshape(P, -1, 9)).reshape(P, J, 3, 3)
        off = _block_index(np.concatenate([a, b]), np.concatenate([b, a]), J)
        out[:, off] -= np.concatenate([K, K], axis=1).reshape(P, -1)
    out[:, _block_index(jj, jj, J)] += diag.reshape(P, -1)
    return out.reshape(P, 3 * J, 3 * J)


def linearize(X: np.ndarray, problem: PoseProblem
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Cost (P,), safe H (P, 3J, 3J), g = J^T r (P, 3J) and exact H (P, 3J, 3J) or None without bones.

    Both H are J^T J plus a second-order term of the bone prior, per bone
    r_l d^2 r_l / dQ^2 = w_l^2 (1 - b_ref_l / n_l) (I - u u^T) on [[+, -], [-, +]]. The exact H has it
    for every bone (the exact Hessian of the prior; Gauss-Newton alone converges only linearly here,
    because the prior residuals are large, 1-3 sigma, and strongly curved: short bones, 1 cm sigma).
    It is negative for a bone shorter than its reference (the prior is not convex), so the safe H
    keeps only the positive terms and stays positive semi-definite.
    """
    f, diag, g = _likelihood_blocks(X, problem)
    tau2 = problem.anchor_weight ** 2
    diag = diag + tau2 * np.eye(3)
    g = g + tau2 * (X - problem.anchor)
    f = f + 0.5 * tau2 * ((X - problem.anchor) ** 2).sum(axis=(1, 2))
    P, J, _ = X.shape
    if len(problem.bone_pairs) == 0:
        return f, _assemble(diag, np.zeros((P, 0, 3, 3)), problem), g.reshape(P, 3 * J), None
    n, u, r = _bone_geometry(X, problem)
    f = f + 0.5 * (r ** 2).sum(axis=1)
    signed = _incidence(problem, J)
    signed[problem.bone_pairs[:, 1], np.arange(len(problem.bone_pairs))] = -1.0
    grad = -problem.bone_weight[:, None] * u * r[..., None]                                  # dcost/dQ_a
    g = g + np.matmul(signed, grad)
    uu = u[..., :, None] * u[..., None, :]
    w2 = problem.bone_weight ** 2
    curv = w2 * (1.0 - problem.bone_ref / np.maximum(n, 1e-12))                              # (P, L)
    perp = np.eye(3) - uu
    K_safe = w2[:, None, None] * uu + np.maximum(curv, 0.0)[..., None, None] * perp
    H_safe = _assemble(diag, K_safe, problem)
    if np.all(curv >= 0):
        return f, H_safe, g.reshape(P, 3 * J), H_safe
    K_rest = np.minimum(curv, 0.0)[..., None, None] * perp
    return f, H_safe, g.reshape(P, 3 * J), _assemble(np.zeros_like(diag), K_rest, problem, H_safe)


def normal_equations(X: np.ndarray, problem: PoseProblem, model: str = "gauss_newton"
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost (P,), H (P, 3J, 3J) and g = J^T r (P, 3J) at X (P, J, 3); model "gauss_newton" (H = J^T J),
    "safe" or "exact" (see :func:`linearize`)."""
    if model not in ("gauss_newton", "safe", "exact"):
        raise ValueError(f"model must be gauss_newton, safe or exact, got {model!r}")
    f, H_safe, g, H_exact = linearize(X, problem)
    if model == "gauss_newton":
        return f, _gauss_newton_H(X, problem), g
    return f, (H_exact if model == "exact" and H_exact is not None else H_safe), g


def _gauss_newton_H(X: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """J^T J of all terms (no second-order bone term): (P, J, 3) -> (P, 3J, 3J)."""
    _, diag, _ = _likelihood_blocks(X, problem)
    diag = diag + problem.anchor_weight ** 2 * np.eye(3)
    _, u, _ = _bone_geometry(X, problem)
    K = (problem.bone_weight ** 2)[:, None, None] * u[..., :, None] * u[..., None, :]
    return _assemble(diag, K, problem)


def numeric_jacobian(X: np.ndarray, problem: PoseProblem, step: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of the raw residual vector of one person: (1, J, 3) -> (R, 3J)."""
    x0 = np.asarray(X, dtype=np.float64).reshape(-1)
    cols = []
    for i in range(len(x0)):
        e = np.zeros_like(x0)
        e[i] = step
        hi = residual_vector((x0 + e).reshape(X.shape), problem)[0]
        lo = residual_vector((x0 - e).reshape(X.shape), problem)[0]
        cols.append((hi - lo) / (2 * step))
    return np.stack(cols, axis=1)
