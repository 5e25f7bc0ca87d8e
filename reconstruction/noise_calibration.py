"""A 2D noise model that calibrates itself on the run's detections (``noise_model=calibrated``): log sigma^2 = base +
camera + joint type + score rank + box size, solved from the residuals of the first frames' joints seen in >= 3
views (docs/design.md). The score enters by its rank only, so any detector's score scale gets the same model."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.special import gammaincinv

from data.geometry.triangulation import triangulate_dlt
from data.keypoints import COCO23_NAMES
from reconstruction.noise_model import NoiseModel, box_size

MAX_EFFECT = math.log(16.0)  # one factor moves sigma by 4x at most from the mean: few residuals cannot pin a view
SWEEPS = 20  # factor-by-factor solves of the moment equations (camera and box size are correlated: many)


_SIDELESS = [n.removeprefix("left_").removeprefix("right_") for n in COCO23_NAMES]
JOINT_TYPES = tuple(sorted(set(_SIDELESS), key=_SIDELESS.index))  # COCO-23's joints, left and right as one


@lru_cache(maxsize=8)
def joint_types(J: int) -> np.ndarray:
    """Joint type per joint (J,): COCO-23's into JOINT_TYPES; another layout, one per joint."""
    return np.array([JOINT_TYPES.index(n) for n in _SIDELESS]) if J == len(COCO23_NAMES) else np.arange(J)


@dataclass(frozen=True)
class NoiseTable:
    """Fitted effects: base (log px^2), effects per factor (levels,), bin edges of score and box size (bins - 1,)."""

    base: float
    effects: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # camera, joint type, score rank, box size
    rank_edges: np.ndarray
    box_edges: np.ndarray
    residuals: int  # joint residuals the fit used

    def log_variance(self, score: np.ndarray, box: np.ndarray, views: np.ndarray | None) -> np.ndarray:
        """log sigma^2 of joints: scores (..., J), box sizes (...,), view indices (...,) or None (camera effect 0)."""
        types = joint_types(score.shape[-1])  # a type (or a camera) the calibration never saw: effect 0
        out = self.base + np.append(self.effects[1], np.zeros(len(types)))[types]
        out = out + self.effects[2][np.searchsorted(self.rank_edges, score, side="right")]
        per_person = self.effects[3][np.searchsorted(self.box_edges, box, side="right")]
        if views is not None:
            cam, views = self.effects[0], np.asarray(views)
            per_person = per_person + np.where(
                (views >= 0) & (views < len(cam)), cam[np.clip(views, 0, len(cam) - 1)], 0
            )
        return out + per_person[..., None]


@dataclass(frozen=True)
class CalibratedNoiseModel:
    """The start model until fitted, then the table; keys as configs/noise_model/calibrated.yaml."""

    start: NoiseModel = NoiseModel()
    frames: int = 30  # the first frames whose matched persons calibrate the model
    iterations: int = 2  # match, fit; match again with the fitted model, fit again ...
    min_views: int = 3  # a joint's residuals count where it is seen in this many views
    rank_bins: int = 5
    box_bins: int = 4
    min_count: int = 30  # a level with fewer residuals keeps effect 0 (the average)
    max_joints: int = 5000  # the calibration's joints at most, spread evenly over its frames (a crowd's time)
    table: NoiseTable | None = None

    def __post_init__(self) -> None:
        for name in ("frames", "iterations", "rank_bins", "box_bins", "min_count", "max_joints"):
            if isinstance(getattr(self, name), bool) or not int(getattr(self, name)) >= 1:
                raise ValueError(f"noise_model.{name}={getattr(self, name)!r}: must be an integer >= 1")
        if not int(self.min_views) >= 3:
            raise ValueError(f"noise_model.min_views={self.min_views!r}: must be >= 3 (2 views leave no residual)")
        if not isinstance(self.start, NoiseModel):
            object.__setattr__(self, "start", NoiseModel(**dict(self.start)))

    def sigma(self, poses2d: np.ndarray, bboxes: np.ndarray, views: np.ndarray | None = None) -> np.ndarray:
        """Pixel SD of every joint: (..., J, 3), boxes (..., 4), view index (...,) or None -> (..., J); inf unseen."""
        if self.table is None:
            return self.start.sigma(poses2d, bboxes, views)
        poses2d = np.asarray(poses2d, dtype=np.float64)
        score = poses2d[..., 2]
        seen = (score > 0) & np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
        box = box_size(poses2d, np.asarray(bboxes, np.float64), seen)
        log_var = self.table.log_variance(score, box, views)
        return np.where(seen, np.maximum(np.exp(0.5 * log_var), self.start.sigma_min), np.inf)

    def fitted(self, table: NoiseTable | None) -> CalibratedNoiseModel:
        """This model with a fitted table (None: the start model again)."""
        return replace(self, table=table)


def residual_blocks(
    poses2d_und: np.ndarray, bboxes: np.ndarray, proj: np.ndarray, sigma: np.ndarray, min_views: int = 3, most: int = 0
) -> dict[str, np.ndarray]:
    """Joints seen in >= min_views views (at most ``most``): (V, P, J, 3), (V, P, 4), (V, 3, 4), (V, P, J) -> blocks."""
    V, P, J, _ = poses2d_und.shape
    finite = np.isfinite(sigma) & (poses2d_und[..., 2] > 0) & np.isfinite(poses2d_und[..., :2]).all(axis=-1)
    p, j = np.nonzero(finite.sum(axis=0) >= min_views)
    if 0 < most < len(p):
        p, j = (a[np.linspace(0, len(p) - 1, most).astype(int)] for a in (p, j))
    obs = np.where(finite[..., None], poses2d_und, 0.0)[:, p, j]  # (V, K, 3)
    w = np.where(finite, 1.0 / np.where(finite, sigma, 1.0) ** 2, 0.0)[:, p, j].T  # (K, V)
    X = triangulate_dlt(obs[:, :, None], proj)[:, 0, :3]
    uv = obs[..., :2].transpose(1, 0, 2)
    for _ in range(3):  # Gauss-Newton on the weighted reprojection error from the DLT
        r, jac, depth = _linearised(X, uv, proj)
        info, ok = _information(w * (depth > 0), jac)
        grad = (np.nan_to_num(jac) * (w * (depth > 0))[..., None, None] * np.nan_to_num(r)[..., None]).sum(axis=(1, 2))
        X = X + np.where(ok[:, None], np.linalg.solve(info, grad[..., None])[..., 0], 0.0)
    r, jac, depth = _linearised(X, uv, proj)
    seen = (w > 0) & (depth > 0) & np.isfinite(r).all(axis=-1) & np.isfinite(jac).all(axis=(2, 3))
    info, ok = _information(w * seen, np.where(seen[..., None, None], jac, 0.0))
    k = np.flatnonzero(ok & (seen.sum(axis=1) >= min_views))
    seen, w, jac, r, cov = seen[k], (w * seen)[k], jac[k].reshape(len(k), 2 * V, 3), r[k], np.linalg.inv(info[k])
    hat = (jac @ cov) @ (jac * np.repeat(w, 2, axis=1)[..., None]).transpose(0, 2, 1)  # (K, 2V, 2V)
    mix = ((np.eye(2 * V) - hat) ** 2).reshape(len(k), V, 2, V, 2).sum(axis=(2, 4))  # |(I - H)_vc|_F^2
    r2 = np.where(seen, (np.nan_to_num(r) ** 2).sum(axis=-1), 0.0)
    box = box_size(poses2d_und, np.asarray(bboxes, np.float64), poses2d_und[..., 2] > 0)[:, p[k]].T
    seen2 = seen[:, :, None] * seen[:, None, :]  # blocks: (K, V) r2, seen, score, box; (K, V, V) mix; (K,) the rest
    out = dict(r2=r2, mix=mix * seen2, seen=seen, chi2=(w * r2).sum(axis=1), dof=2 * seen.sum(axis=1) - 3)
    return out | dict(joint=joint_types(J)[j[k]], score=obs[:, k, 2].T, box=box)


def _information(w: np.ndarray, jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sum_v w J^T J: (K, V), (K, V, 2, 3) -> (K, 3, 3) (identity where not finite or singular), usable (K,)."""
    J = np.nan_to_num(jac).reshape(len(w), 2 * w.shape[1], 3)
    info = (J * np.repeat(w, 2, axis=1)[..., None]).transpose(0, 2, 1) @ J
    info = np.where(np.isfinite(info), info, 0.0)
    ok = np.linalg.det(info) > 1e-12 * (np.trace(info, axis1=1, axis2=2) / 3.0) ** 3  # well-conditioned enough
    return np.where(ok[:, None, None], info, np.eye(3)), ok


def _linearised(X: np.ndarray, uv: np.ndarray, proj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals uv - projection (K, V, 2) of points (K, 3), the projection's Jacobian (K, V, 2, 3), depth (K, V)."""
    hom = np.einsum("vab,kb->kva", proj[:, :, :3], X) + proj[:, :, 3]
    depth = hom[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = hom[..., :2] / depth[..., None]
        jac = (proj[None, :, :2, :3] - pix[..., None] * proj[None, :, 2:3, :3]) / depth[..., None, None]
    return uv - pix, jac, depth


def block_codes(blocks: dict[str, np.ndarray], rank_edges: np.ndarray, box_edges: np.ndarray) -> list[np.ndarray]:
    """Level of every factor for each joint's views: -> 4 x (K, V) int."""
    K, V = blocks["seen"].shape
    camera, joint = np.broadcast_to(np.arange(V), (K, V)), np.broadcast_to(blocks["joint"][:, None], (K, V))
    rank = np.searchsorted(rank_edges, blocks["score"], side="right")
    return [camera, joint, rank, np.searchsorted(box_edges, blocks["box"], side="right")]


def fit_table(blocks: dict[str, np.ndarray], rank_bins: int, box_bins: int, min_count: int) -> NoiseTable | None:
    """The factors solved one at a time from sum r2 = sum mix sigma^2 per level, outlier joints out; None: too few."""
    blocks = {k: a[inliers(blocks["chi2"], blocks["dof"])] for k, a in blocks.items()}
    seen = blocks["seen"]
    if np.count_nonzero(seen) < 4 * min_count:
        return None
    rank_edges = np.quantile(blocks["score"][seen], np.arange(1, rank_bins) / rank_bins)
    box_edges = np.quantile(blocks["box"][seen], np.arange(1, box_bins) / box_bins)
    codes = block_codes(blocks, rank_edges, box_edges)
    k, v, c = np.nonzero(blocks["mix"] > 0)  # the view pairs both seen: flat (k, v), (k, c) indices and mix
    V = seen.shape[1]
    blocks["pairs"] = (k * V + v, k * V + c, blocks["mix"][k, v, c])
    base = math.log(max(float(blocks["r2"][seen].sum() / blocks["mix"].sum()), 1e-12))
    # every level a code can take, unseen views' included (a view's score or box can fall in a level no seen one has)
    effects = [np.zeros(n) for n in (V, int(codes[1].max()) + 1, rank_bins, box_bins)]
    var = np.full(seen.shape, math.exp(base))
    for _ in range(SWEEPS):
        for f, code in enumerate(codes):
            factor = _level_factors(blocks, code, var, len(effects[f]), min_count)
            effects[f] += np.log(factor)
            var = var * factor[code]
    for f, code in enumerate(codes):  # each factor's observation-weighted mean effect into the base, then bounded
        shift = float(np.mean(effects[f][code[seen]]))
        effects[f] = np.clip(effects[f] - shift, -MAX_EFFECT, MAX_EFFECT)
        base += shift
    return NoiseTable(base, tuple(effects), rank_edges, box_edges, int(np.count_nonzero(seen)))


def _level_factors(blocks: dict[str, np.ndarray], code: np.ndarray, var: np.ndarray, L: int, min_count: int):
    """Multipliers (L,) of the levels' variances solving sum r2 = sum mix var per level (1 under min_count)."""
    seen, (kv, kc, mix) = blocks["seen"], blocks["pairs"]
    flat = code.ravel()
    A = np.bincount(flat[kv] * L + flat[kc], mix * var.ravel()[kc], L * L).reshape(L, L)
    b = np.bincount(code[seen], blocks["r2"][seen], L)
    free = np.bincount(code[seen], minlength=L) >= min_count
    factor = np.ones(L)
    if np.any(free):
        rhs = b[free] - A[np.ix_(free, ~free)].sum(axis=1)
        factor[free] = np.linalg.lstsq(A[np.ix_(free, free)], rhs, rcond=None)[0]
    return np.clip(factor, 1e-2, 1e2)


def inliers(chi2: np.ndarray, dof: np.ndarray, rate: float = 1e-3) -> np.ndarray:
    """Joints whose chi^2 (K,), over the median scale, passes the test at ``rate`` for its dof (K,) -> (K,) bool."""
    if not len(chi2):
        return np.zeros(0, dtype=bool)
    dofs, index = np.unique(dof, return_inverse=True)  # a few small integers: scipy once per value
    median, limit = (2.0 * gammaincinv(dofs / 2.0, q)[index] for q in (0.5, 1.0 - rate))
    return chi2 <= float(np.median(chi2 / median)) * limit


def calibrate(
    model: CalibratedNoiseModel, gathered: list[tuple[np.ndarray, np.ndarray]], proj: np.ndarray, rounds: int = 3
) -> tuple[CalibratedNoiseModel, dict[str, np.ndarray] | None]:
    """The model fitted to frames' poses (V, P, J, 3) and boxes (V, P, 4), ``rounds`` times -> model, its blocks."""
    fitted, blocks = model, None
    views, most = np.arange(len(proj))[:, None], -(-model.max_joints // max(len(gathered), 1))
    for _ in range(rounds):
        found = [residual_blocks(u, b, proj, _weights(fitted, u, b, views), model.min_views, most) for u, b in gathered]
        blocks = {k: np.concatenate([f[k] for f in found]) for k in found[0]} if found else None
        table = fit_table(blocks, model.rank_bins, model.box_bins, model.min_count) if blocks else None
        if table is None:
            return model.fitted(None), blocks
        fitted = model.fitted(table)
    return fitted, blocks


def _weights(model: CalibratedNoiseModel, poses2d: np.ndarray, bboxes: np.ndarray, views: np.ndarray) -> np.ndarray:
    """Weights' SDs (V, P, J): the fit's, or the start model's at score 1, floored at half their median (design.md)."""
    if model.table is None:
        poses2d = np.concatenate([poses2d[..., :2], (poses2d[..., 2:] > 0).astype(float)], axis=-1)
    sigma = model.sigma(poses2d, bboxes, views)
    finite = np.isfinite(sigma)
    return np.sqrt(sigma**2 + (0.5 * np.median(sigma[finite])) ** 2) if finite.any() else sigma


def describe(model: CalibratedNoiseModel, names: list[str], blocks: dict[str, np.ndarray] | None, frames: int) -> str:
    """The report's line on the fitted model: per camera the median sigma of its calibration joints, the factors."""
    table = model.table
    if table is None:
        found, need = 0 if blocks is None else int(np.count_nonzero(blocks["seen"])), 4 * model.min_count
        where = f"persons seen in >= {model.min_views} views of the first {frames} frames"
        return f"2D noise model: not calibrated ({found} joint residuals from {where}, need {need}); the start model"
    codes = block_codes(blocks, table.rank_edges, table.box_edges)
    sigma = np.exp(0.5 * (table.base + sum(effect[code] for effect, code in zip(table.effects, codes))))
    seen = blocks["seen"]
    cams = ", ".join(f"{n} {np.median(sigma[:, v][seen[:, v]]):.1f}" for v, n in enumerate(names) if seen[:, v].any())
    factor = lambda e: " ".join(f"{math.exp(0.5 * x):.2f}" for x in e)
    types = JOINT_TYPES if len(table.effects[1]) == len(JOINT_TYPES) else range(len(table.effects[1]))
    joints = ", ".join(f"{t} {math.exp(0.5 * e):.2f}" for t, e in zip(types, table.effects[1]))
    return (
        f"2D noise model: self-calibrated on {table.residuals} joint residuals of persons seen in >= "
        f"{model.min_views} views (first {frames} frames). Median sigma (px) by camera: {cams}; "
        f"factor by score rank, lowest to highest: {factor(table.effects[2])}; by box size, smallest to largest: "
        f"{factor(table.effects[3])}; by joint type: {joints}"
    )
