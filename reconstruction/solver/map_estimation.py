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
J^T J and J^T r are assembled block by block (3 x 3 per joint and per bone), never as a dense Jacobian;
the solver's arrays (:class:`PoseBatch`, :class:`Blocks`) keep the persons on their last axis.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from reconstruction.solver.sigma_kernels import sigmas_of_joints

ROBUST_LOSSES = ("none", "huber", "cauchy")
EPS_DEPTH = 1e-6  # m; projections of points behind a camera are clamped to this depth
BLOCK_DIAG = (np.arange(3), np.arange(3))  # diagonal entries of 3x3 blocks stored first: (3, 3, ...) -> (3, ...)
_SYM6 = np.array([0, 1, 2, 4, 5, 8])  # the distinct entries of a flat symmetric 3x3 matrix ...
_SYM9 = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])  # ... and back to all 9


@dataclass(frozen=True)
class PoseProblem:
    """The least-squares problem of P persons with J joints each (shapes in the field comments)."""

    proj: np.ndarray  # (V, 3, 4) projection matrices of undistorted pixels
    uv: np.ndarray  # (V, P, J, 2) observed undistorted pixels (anything where unseen)
    inv_sigma: np.ndarray  # (V, P, J) 1 / sigma (1/px), 0 where the joint is not seen
    bone_pairs: np.ndarray  # (L, 2) joint indices of each bone; L may be 0
    bone_ref: np.ndarray  # (L,) reference lengths (m), or (P, L): one table per person
    bone_weight: np.ndarray  # (L,) or (P, L) prior_weight / sigma_l (1/m); 0 switches a bone off
    anchor: np.ndarray  # (P, J, 3) Tikhonov anchor (m)
    anchor_weight: float = 1e-3
    robust: str = "none"
    robust_scale: float = 3.0

    def take(self, idx: np.ndarray) -> "PoseProblem":
        """The problem of a subset of persons: idx (b,) sorted -> PoseProblem with P = b."""
        if len(idx) == self.inv_sigma.shape[1] and (len(idx) == 0 or idx[-1] == len(idx) - 1):
            return self
        per_person = {k: getattr(self, k)[idx] for k in ("bone_ref", "bone_weight") if np.ndim(getattr(self, k)) == 2}
        return replace(
            self, uv=self.uv[:, idx], inv_sigma=self.inv_sigma[:, idx], anchor=self.anchor[idx], **per_person
        )

    @property
    def per_person_bones(self) -> bool:
        """Whether the bone tables are per person ((P, L)) rather than one (L,) for all."""
        return np.ndim(self.bone_ref) == 2 or np.ndim(self.bone_weight) == 2

    def joints(self, idx: np.ndarray) -> "PoseProblem":
        """The problem of a subset of joints, keeping the bones inside it: idx (j,) -> PoseProblem with J = j."""
        idx = np.asarray(idx, dtype=np.int64)
        new = np.full(self.inv_sigma.shape[2], -1)
        new[idx] = np.arange(len(idx))
        keep = np.all(new[self.bone_pairs] >= 0, axis=1) if len(self.bone_pairs) else np.zeros(0, bool)
        return replace(
            self,
            uv=self.uv[:, :, idx],
            inv_sigma=self.inv_sigma[:, :, idx],
            anchor=self.anchor[:, idx],
            bone_pairs=new[self.bone_pairs[keep]].reshape(-1, 2),
            bone_ref=self.bone_ref[keep],
            bone_weight=self.bone_weight[keep],
        )


def joint_sigma(
    poses2d: np.ndarray, bboxes: np.ndarray, c: float, sigma_min: float, sigma_px: float = 0.0, score_power: float = 1.0
) -> np.ndarray:
    """Pixel SD of every 2D joint, max(sigma_min, sqrt(sigma_px^2 + (c sqrt(w h))^2) / score^score_power):
    (V, P, J, 3), (V, P, 4) -> (V, P, J) (any leading shape).

    A box with no area falls back to the box of the person's keypoints in that view; unseen joints
    (score <= 0) get inf. The defaults of the configs are fitted to Shelf's OpenPose errors
    (benchmarks/fit_sigma_model.py).
    """
    poses2d = np.ascontiguousarray(poses2d, dtype=np.float64)
    bboxes = np.asarray(bboxes, dtype=np.float64)
    score = poses2d[..., 2]
    size = np.sqrt(np.clip(bboxes[..., 2], 0, None) * np.clip(bboxes[..., 3], 0, None))
    missing = ~(size > 0)
    if np.any(missing):
        seen = (score > 0) & np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
        if np.any(seen & missing[..., None]):  # (a box of no seen joint: its sigmas are inf)
            pts, ok = poses2d[missing][..., :2], seen[missing][..., None]
            lo = np.where(ok, pts, np.inf).min(axis=-2)
            hi = np.where(ok, pts, -np.inf).max(axis=-2)
            extent = np.where(np.any(ok, axis=-2), hi - lo, 0.0)
            size[missing] = np.sqrt(extent[..., 0] * extent[..., 1])
    spread = np.hypot(sigma_px, c * size)
    powed = np.where(score > 0, score, 1.0) ** score_power  # numpy's pow (an unseen joint's is not read)
    N, J = int(np.prod(poses2d.shape[:-2])), poses2d.shape[-2]
    sigma = sigmas_of_joints(poses2d.reshape(N, J, 3), spread.reshape(N), powed.reshape(N, J), float(sigma_min))
    return sigma.reshape(poses2d.shape[:-1])


def robust_rho(z: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rho(z), rho'(z), rho''(z) of a loss on squared residuals z (scipy's definitions): (...) -> 3 x (...)."""
    if kind == "none":
        return z, np.ones_like(z), np.zeros_like(z)
    if kind == "huber":
        small = z <= 1.0
        zz = np.where(small, 1.0, z)
        sq = np.sqrt(zz)
        return (
            np.where(small, z, 2.0 * sq - 1.0),
            np.where(small, 1.0, 1.0 / sq),
            np.where(small, 0.0, -0.5 / (sq * zz)),
        )
    if kind == "cauchy":
        return np.log1p(z), 1.0 / (1.0 + z), -1.0 / (1.0 + z) ** 2
    raise ValueError(f"robust loss must be one of {ROBUST_LOSSES}, got {kind!r}")


def _project_xy(X: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel x, y and clamped depth of 3D joints in every view: (P, J, 3), (V, 3, 4) -> 3 x (V, P, J)."""
    P, J, _ = X.shape
    hom = np.matmul(proj[:, :, :3], X.reshape(-1, 3).T) + proj[:, :, 3:]  # (V, 3, P*J)
    depth = np.maximum(hom[:, 2], EPS_DEPTH)
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


def _robust_scaling(r: np.ndarray, problem: "PoseProblem | SharedTerms") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust cost terms, residual scale and Jacobian scale of raw residuals: (...) -> 3 x (...)."""
    C2 = problem.robust_scale**2
    rho, d1, d2 = robust_rho(r**2 / C2, problem.robust)
    j_scale = np.sqrt(np.maximum(d1 + 2.0 * d2 * r**2 / C2, np.finfo(float).eps))
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
    return 0.5 * (
        lik.sum(axis=(0, 2)) + (_bone_geometry(X, problem)[2] ** 2).sum(axis=1) + (anchor**2).sum(axis=(1, 2))
    )


@dataclass(frozen=True)
class SharedTerms:
    """What a batch's persons share: view matrices, bones and loss settings (built once per problem)."""

    num_views: int
    proj_rows: np.ndarray  # (3V, 3) row k of view v's M at k V + v: proj_rows @ X + proj_t = (x, y, z) x V
    proj_t: np.ndarray  # (3V, 1) the matching translations
    H_mat: np.ndarray  # (6, 5V) 5 coefficients per view -> the 6 distinct entries of J^T J
    g_mat: np.ndarray  # (3, 3V) 3 coefficients per view -> J^T r
    bone_pairs: np.ndarray  # (L, 2)
    bone_ref: np.ndarray  # (L, 1)
    bone_weight: np.ndarray  # (L, 1)
    incidence: np.ndarray  # (J, L) 1 where joint j is an end of bone l
    signed: np.ndarray  # (J, L) +1 at the first end, -1 at the second
    anchor_weight: float
    robust: str
    robust_scale: float

    @classmethod
    def of(cls, problem: PoseProblem) -> "SharedTerms":
        """The shared terms of a problem."""
        V = len(problem.proj)
        M, t = problem.proj[:, :, :3], problem.proj[:, :, 3]
        m0, m1, m2 = M[:, 0], M[:, 1], M[:, 2]
        outer = lambda a, b: (a[:, :, None] * b[:, None, :]).reshape(V, 9)[:, _SYM6]  # noqa: E731
        # J^T J of view v = sum of 5 coefficients x [M0 M0^T, M1 M1^T, M0 M2^T + M2 M0^T, M1 M2^T + M2 M1^T, M2 M2^T]
        # and J^T r = 3 coefficients x the rows M0, M1, M2 (see _likelihood_terms); column k V + v
        H_mat = np.stack(
            [outer(m0, m0), outer(m1, m1), outer(m0, m2) + outer(m2, m0), outer(m1, m2) + outer(m2, m1), outer(m2, m2)]
        )  # (5, V, 6)
        pairs = np.asarray(problem.bone_pairs, dtype=np.int64).reshape(-1, 2)
        J, L = problem.inv_sigma.shape[2], len(pairs)
        incidence, signed = np.zeros((J, L)), np.zeros((J, L))
        incidence[pairs[:, 0], np.arange(L)] = incidence[pairs[:, 1], np.arange(L)] = 1.0
        signed[pairs[:, 0], np.arange(L)], signed[pairs[:, 1], np.arange(L)] = 1.0, -1.0
        return cls(
            V,
            np.ascontiguousarray(M.transpose(1, 0, 2).reshape(3 * V, 3)),
            np.ascontiguousarray(t.T.reshape(3 * V, 1)),
            np.ascontiguousarray(H_mat.reshape(5 * V, 6).T),
            np.ascontiguousarray(M.transpose(2, 1, 0).reshape(3, 3 * V)),
            pairs,
            np.asarray(problem.bone_ref, dtype=np.float64).reshape(L, 1),
            np.asarray(problem.bone_weight, dtype=np.float64).reshape(L, 1),
            incidence,
            signed,
            float(problem.anchor_weight),
            problem.robust,
            float(problem.robust_scale),
        )


@dataclass(frozen=True)
class PoseBatch:
    """A PoseProblem laid out batch-last for the solver: uv (2, V, J, P), w = 1/sigma (V, J, P), anchor (3, J, P).

    Every array of the solver keeps the persons (the batch) on its last axis, so that the arithmetic
    of the joints and bones of all persons runs on long contiguous rows.
    """

    uv: np.ndarray
    w: np.ndarray
    anchor: np.ndarray
    shared: SharedTerms

    @classmethod
    def of(cls, problem: PoseProblem, per_joint: bool = False) -> "PoseBatch":
        """The batch of a problem; per_joint: every joint its own unit, P*J units of 1 joint (persons first)."""
        V, P, J = problem.inv_sigma.shape
        uv, w = np.asarray(problem.uv, dtype=np.float64), np.asarray(problem.inv_sigma, dtype=np.float64)
        anchor, shared = np.asarray(problem.anchor, dtype=np.float64), SharedTerms.of(problem)
        if per_joint:
            return cls(
                uv.transpose(3, 0, 1, 2).reshape(2, V, 1, P * J),
                w.reshape(V, 1, P * J),
                anchor.reshape(P * J, 3).T.reshape(3, 1, P * J),
                shared,
            )
        return cls(
            np.ascontiguousarray(uv.transpose(3, 0, 2, 1)),
            np.ascontiguousarray(w.transpose(0, 2, 1)),
            np.ascontiguousarray(anchor.transpose(2, 1, 0)),
            shared,
        )

    def take(self, idx: np.ndarray) -> "PoseBatch":
        """The batch of a subset of persons: idx (b,) -> PoseBatch with P = b."""
        return replace(self, uv=self.uv[..., idx], w=self.w[..., idx], anchor=self.anchor[..., idx])


@dataclass(frozen=True)
class Blocks:
    """Costs and the normal equations of a batch in 3x3 blocks, batch last (see :func:`linear_blocks`)."""

    joint_cost: np.ndarray  # (J, P) likelihood and anchor cost of each joint
    bone_cost: np.ndarray  # (L, P) prior cost of each bone
    g: np.ndarray  # (3, J, P) gradient J^T r
    diag: np.ndarray  # (3, 3, J, P) diagonal blocks of the safe H
    K: np.ndarray  # (3, 3, L, P) bone blocks of the safe H: +K on both ends' diagonal blocks, -K between
    K_rest: np.ndarray  # (3, 3, L, P) exact minus safe bone blocks (0 where the prior is locally convex)

    def take(self, idx: np.ndarray) -> "Blocks":
        """The blocks of a subset of the batch (indices or a mask)."""
        return Blocks(*(getattr(self, f.name)[..., idx] for f in fields(self)))


def _likelihood_terms(X: np.ndarray, batch: PoseBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Likelihood + anchor cost (J, P), J^T J blocks (3, 3, J, P) and J^T r (3, J, P) at X (3, J, P).

    Per view, with s = w / z (times the robust Jacobian scale), p the projection and e = -s r:
    J^T J = s_x^2 (M0 - p_x M2)(M0 - p_x M2)^T + s_y^2 (M1 - p_y M2)(...)^T and J^T r = e_x M0 + e_y M1 -
    (e . p) M2, i.e. 5 + 3 coefficients per view against constant matrices: two matrix products for all
    joints (the 6 distinct entries of the symmetric J^T J, then the 3 of J^T r).
    """
    _, J, P = X.shape
    sh = batch.shared
    V, n = sh.num_views, J * P
    hom = (sh.proj_rows @ X.reshape(3, n) + sh.proj_t).reshape(3, V, n)
    inv_depth = 1.0 / np.maximum(hom[2], EPS_DEPTH)
    p = hom[:2] * inv_depth  # (2, V, n)
    w = batch.w.reshape(V, n)
    r = (batch.uv.reshape(2, V, n) - p) * w
    s = w * inv_depth
    coef_H, coef_g = np.empty((5, V, n)), np.empty((3, V, n))
    if sh.robust == "none":
        cost = 0.5 * np.einsum("ij,ij->j", r.reshape(2 * V, n), r.reshape(2 * V, n))
        a = np.multiply(s, s, out=coef_H[0])
        coef_H[1] = a
        ap = np.multiply(p, -a, out=coef_H[2:4])
    else:
        terms, r_scale, j_scale = _robust_scaling(r, sh)
        cost = 0.5 * terms.sum(axis=(0, 1))
        s = s * j_scale
        r = r * r_scale
        a = np.multiply(s, s, out=coef_H[:2])
        ap = np.multiply(p, -a, out=coef_H[2:4])
    coef_H[4] = -(ap[0] * p[0] + ap[1] * p[1])
    e = np.multiply(r, -s, out=coef_g[:2])
    coef_g[2] = -(e[0] * p[0] + e[1] * p[1])
    H = (sh.H_mat @ coef_H.reshape(5 * V, n))[_SYM9].reshape(3, 3, J, P)
    tau2 = sh.anchor_weight**2
    H[BLOCK_DIAG] += tau2
    dx = X - batch.anchor
    return (
        cost.reshape(J, P) + 0.5 * tau2 * np.einsum("kjp,kjp->jp", dx, dx),
        H,
        (sh.g_mat @ coef_g.reshape(3 * V, n)).reshape(3, J, P) + tau2 * dx,
    )


def _bone_terms(X: np.ndarray, sh: SharedTerms) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cost (L, P), gradient on the first end (3, L, P), u u^T (3, 3, L, P) and curvature (L, P) of the bones.

    The second-order term of bone l is curv_l (I - u u^T) with curv_l = w_l^2 (1 - b_ref_l / n_l).
    """
    d = X[:, sh.bone_pairs[:, 0]] - X[:, sh.bone_pairs[:, 1]]  # (3, L, P)
    n = np.sqrt(np.einsum("klp,klp->lp", d, d))
    safe_n = np.maximum(n, 1e-12)
    u = d / safe_n
    degenerate = n <= 1e-12
    if np.any(degenerate):
        u[:, degenerate] = np.array([0.0, 0.0, 1.0])[:, None]
    r = sh.bone_weight * (sh.bone_ref - n)
    return (
        0.5 * r * r,
        (-sh.bone_weight * r) * u,
        u[:, None] * u[None],
        sh.bone_weight**2 * (1.0 - sh.bone_ref / safe_n),
    )


def linear_blocks(X: np.ndarray, batch: PoseBatch) -> Blocks:
    """Costs and safe / exact normal equations at X (3, J, P) in 3x3 blocks (see :func:`linearize`)."""
    joint_cost, diag, g = _likelihood_terms(X, batch)
    sh = batch.shared
    _, J, P = X.shape
    L = len(sh.bone_pairs)
    if L == 0:
        empty = np.zeros((3, 3, 0, P))
        return Blocks(joint_cost, np.zeros((0, P)), g, diag, empty, empty)
    bone_cost, grad, uu, curv = _bone_terms(X, sh)
    g += sh.signed @ grad
    # K = w^2 u u^T + max(curv, 0) (I - u u^T), K_rest = min(curv, 0) (I - u u^T)
    positive, negative = np.maximum(curv, 0.0), np.minimum(curv, 0.0)
    K = (sh.bone_weight**2 - positive) * uu
    K[BLOCK_DIAG] += positive
    K_rest = -negative * uu
    K_rest[BLOCK_DIAG] += negative
    diag += (sh.incidence @ K.reshape(9, L, P)).reshape(3, 3, J, P)
    return Blocks(joint_cost, bone_cost, g, diag, K, K_rest)


def block_index(rows: np.ndarray, cols: np.ndarray, J: int) -> np.ndarray:
    """Flat positions in a (3J, 3J) matrix of the 3x3 blocks (rows[k], cols[k]): (K,), (K,) -> (K * 9,)."""
    r = 3 * np.asarray(rows)[:, None, None] + np.arange(3)[None, :, None]
    c = 3 * np.asarray(cols)[:, None, None] + np.arange(3)[None, None, :]
    return (r * 3 * J + c).reshape(-1)


def assemble(diag: np.ndarray, K: np.ndarray, bone_pairs: np.ndarray) -> np.ndarray:
    """Dense H from diagonal blocks (3, 3, J, P) and -K (3, 3, L, P) between the ends of each bone: -> (P, 3J, 3J)."""
    J, P = diag.shape[2:]
    out = np.zeros((P, 9 * J * J))
    out[:, block_index(np.arange(J), np.arange(J), J)] = diag.transpose(3, 2, 0, 1).reshape(P, -1)
    if len(bone_pairs):
        a, b = bone_pairs[:, 0], bone_pairs[:, 1]
        # a joint pair joined by two bones would need a sum here; bone tables have one bone per pair
        out[:, block_index(np.concatenate([a, b]), np.concatenate([b, a]), J)] = (
            -np.concatenate([K, K], axis=2).transpose(3, 2, 0, 1).reshape(P, -1)
        )
    return out.reshape(P, 3 * J, 3 * J)


def exact_blocks(blocks: Blocks, sh: SharedTerms) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal blocks (3, 3, J, P) and bone blocks (3, 3, L, P) of the exact H."""
    _, _, J, P = blocks.diag.shape
    extra = (sh.incidence @ blocks.K_rest.reshape(9, -1, P)).reshape(3, 3, J, P)
    return blocks.diag + extra, blocks.K + blocks.K_rest


def batch_last(X: np.ndarray) -> np.ndarray:
    """Joints (P, J, 3) in the solver's layout (3, J, P)."""
    return np.ascontiguousarray(np.asarray(X, dtype=np.float64).transpose(2, 1, 0))


def linearize(X: np.ndarray, problem: PoseProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Cost (P,), safe H (P, 3J, 3J), g = J^T r (P, 3J) and exact H (P, 3J, 3J) or None without bones.

    Both H are J^T J plus a second-order term of the bone prior, per bone
    r_l d^2 r_l / dQ^2 = w_l^2 (1 - b_ref_l / n_l) (I - u u^T) on [[+, -], [-, +]]. The exact H has it
    for every bone (the exact Hessian of the prior; Gauss-Newton alone converges only linearly here,
    because the prior residuals are large, 1-3 sigma, and strongly curved: short bones, 1 cm sigma).
    It is negative for a bone shorter than its reference (the prior is not convex), so the safe H
    keeps only the positive terms and stays positive semi-definite.
    """
    batch = PoseBatch.of(problem)
    blocks = linear_blocks(batch_last(X), batch)
    P, J, _ = X.shape
    f = blocks.joint_cost.sum(axis=0) + blocks.bone_cost.sum(axis=0)
    pairs = batch.shared.bone_pairs
    H_safe = assemble(blocks.diag, blocks.K, pairs)
    H_exact = assemble(*exact_blocks(blocks, batch.shared), pairs) if len(pairs) else None
    return f, H_safe, blocks.g.transpose(2, 1, 0).reshape(P, 3 * J), H_exact


def normal_equations(
    X: np.ndarray, problem: PoseProblem, model: str = "gauss_newton"
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
    batch = PoseBatch.of(problem)
    sh = batch.shared
    Xs = batch_last(X)
    _, diag, _ = _likelihood_terms(Xs, batch)
    _, J, P = Xs.shape
    if len(sh.bone_pairs) == 0:
        return assemble(diag, np.zeros((3, 3, 0, P)), sh.bone_pairs)
    K = sh.bone_weight**2 * _bone_terms(Xs, sh)[2]
    diag = diag + (sh.incidence @ K.reshape(9, -1, P)).reshape(3, 3, J, P)
    return assemble(diag, K, sh.bone_pairs)


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
