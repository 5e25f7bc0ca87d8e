"""MLE and MAP 3D crowd pose reconstruction (paper Sec. 3.3): ``stage(poses2d, bboxes, rig) -> Reconstruction``.

poses2d (V, P, J, 3) distorted px + score, bboxes (V, P, 4) x y w h. Start: the DLT and a fitted mean body
(pose_init.py); then Levenberg-Marquardt of every person (compiled_solver.py) on the likelihood of Eq. 6 with 2D
sigmas from the :class:`NoiseModel` and, for the MAP, the bone prior of Eq. 7 (person_prior.py adapts it to each
person after an MLE pass). Output score: the DLT's where it triangulated, single_view_score x the 2D score for a
joint seen in fewer views, unseen_score for one placed by the prior; 0 below output_min_views views.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np

from data.bone_lengths import ABSOLUTE_SD_M, BONE_MEAN, BONE_PAIRS, MEAN_POSE, resolve_bone_table
from data.geometry.camera import Rig
from data.geometry.triangulation import triangulate_dlt
from reconstruction.noise_model import AnyNoiseModel, NoiseModel
from reconstruction.results import Reconstruction, SkeletonPrior
from reconstruction.solver.compiled_solver import ROBUST_LOSSES, PoseProblem, solve_poses
from reconstruction.solver.person_prior import (
    bone_groups,
    bone_variances,
    joint_information,
    noise_scale,
    person_bone_lengths,
    proportion_sds,
    view_matmul,
)
from reconstruction.solver.pose_init import initial_poses, reinitialise_outliers
from reconstruction.solver.side_labels import chain_sides, consistent_sides, facing_sides
from reconstruction.solver.side_swaps import apply_swaps, find_swaps

BONE_PRIORS = ("adaptive", "population")  # each person's own bone lengths (person_prior.py) | the table's means
NOISE_SCALES = ("estimate", "model")  # 2D sigma = model x the person's estimated scale | the model alone
BONE_GROUPS = bone_groups()


class FirstPass(NamedTuple):
    """A frame after the DLT and the first solve: poses (P', J, 4) of the P' placed persons (the solve's x, y, z and
    1.0 where seen in >= 2 views), what the tracker's skeleton prior is asked with; the rest is finish()'s input."""

    poses: np.ndarray
    und: np.ndarray  # (V, P, J, 3) undistorted px + score as detected
    proj: np.ndarray  # (V, 3, 4)
    dlt: np.ndarray  # (P, J, 4)
    start: np.ndarray  # (P, J, 3) start poses (the fitted body where nothing is placed)
    placed: np.ndarray  # (P,) bool
    fixed: np.ndarray  # (V, P', J, 3) the placed persons' 2D after side / swap repair
    uv: np.ndarray  # (V, P', J, 2) their pixels (0 unseen)
    inv_sigma: np.ndarray  # (V, P', J) 1 / sigma (0 unseen)


def combine_estimates(
    mean: np.ndarray, sd: np.ndarray, other: np.ndarray, other_sd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Precision-weighted mean and SD of two estimates, either ignored where NaN / inf: (P, L) x4 -> (P, L) x2."""
    first = np.isfinite(mean) & np.isfinite(sd) & (sd > 0)
    use = np.isfinite(other) & np.isfinite(other_sd) & (other_sd > 0)
    w1 = np.where(first, 1.0 / np.where(first, sd, 1.0) ** 2, 0.0)
    w2 = np.where(use, 1.0 / np.where(use, other_sd, 1.0) ** 2, 0.0)
    w = w1 + w2
    with np.errstate(divide="ignore", invalid="ignore"):
        combined = (w1 * np.where(first, mean, 0.0) + w2 * np.where(use, other, 0.0)) / w
        return np.where(w > 0, combined, mean), np.where(w > 0, 1.0 / np.sqrt(w), np.inf)


def seen_views(poses2d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Views that saw each joint (P, J) int and its clipped 2D scores (V, P, J) (0 where the pixel is not finite)."""
    finite = np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
    score = np.where(finite, np.maximum(poses2d[..., 2], 0.0), 0.0)  # np.maximum: np.clip's dispatch is slow
    return (score > 0).sum(axis=0), score


def mean_variances(info: np.ndarray, tie: np.ndarray) -> np.ndarray:
    """A third of the trace of (info + tie I)^-1 per joint: (P, J, 3, 3), (P, J) -> (P, J); the diagonal cofactors over
    the determinant, as data.geometry.linalg.inverse_3x3 (inf / NaN where singular)."""
    a = lambda i, j: info[..., i, j]  # noqa: E731
    a00, a11, a22 = a(0, 0) + tie, a(1, 1) + tie, a(2, 2) + tie
    c00, c11, c22 = a11 * a22 - a(1, 2) * a(2, 1), a22 * a00 - a(2, 0) * a(0, 2), a00 * a11 - a(0, 1) * a(1, 0)
    det = a00 * c00 + a(0, 1) * (a(1, 2) * a(2, 0) - a(1, 0) * a22) + a(0, 2) * (a(1, 0) * a(2, 1) - a11 * a(2, 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return (c00 / det + c11 / det + c22 / det) / 3


def output_confidence(
    dlt_conf: np.ndarray,
    views: np.ndarray,
    score: np.ndarray,
    placed: np.ndarray,
    output_min_views: int,
    single_view_score: float,
    unseen_score: float,
) -> np.ndarray:
    """Score of each reconstructed joint (module docstring): (P, J), seen_views' (P, J) and (V, P, J), (P,) -> (P, J)."""
    mean_score = score.sum(axis=0) / np.maximum(views, 1)
    conf = np.where(dlt_conf > 0, dlt_conf, np.where(views > 0, single_view_score * mean_score, unseen_score))
    return np.where((views >= output_min_views) & placed[:, None], conf, 0.0)


def _tiny_problem() -> tuple[np.ndarray, np.ndarray]:
    """The mean pose seen by two views facing each other and one beside: poses2d (3, 1, J, 3), proj (3, 3, 4)."""
    J = len(MEAN_POSE)
    M = np.hstack([np.eye(3), [[0.0], [0.0], [5.0]]])
    side = np.array([[0.0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]])
    proj = np.stack([M, M @ np.diag([1.0, -1.0, -1.0, 1.0]), M @ side])
    hom = np.einsum("vab,jb->vja", proj, np.hstack([MEAN_POSE, np.ones((J, 1))]))[:, None]
    return np.concatenate([hom[..., :2] / hom[..., 2:], np.ones(hom.shape[:-1] + (1,))], axis=-1), proj


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel of the stages once per process, on a tiny problem."""
    poses2d, proj = _tiny_problem()
    X, _ = initial_poses(triangulate_dlt(poses2d, proj), poses2d, proj)
    reinitialise_outliers(X, poses2d, proj)
    find_swaps(poses2d, poses2d[..., 2], proj)
    X = np.array(MEAN_POSE, dtype=np.float64)[None]
    for weight in (np.zeros(len(BONE_PAIRS)), np.ones(len(BONE_PAIRS))):
        for robust in ROBUST_LOSSES:
            problem = PoseProblem(
                proj, poses2d[..., :2], poses2d[..., 2], BONE_PAIRS, BONE_MEAN, weight, X, robust=robust
            )
            solve_poses(problem, X, max_iterations=2)
    w = poses2d[..., 2]
    lengths, variances = bone_variances(X, joint_information(X, proj, w), BONE_PAIRS, w.sum(axis=0) >= 2)
    noise_scale(X, poses2d[..., :2], w, proj)
    person_bone_lengths(lengths, variances, BONE_MEAN, np.full(len(BONE_PAIRS), 0.02), 0.01, BONE_GROUPS)


def _check(settings: dict[str, Any]) -> None:
    """Raise ValueError for a bad setting of MAPReconstruction (a one-line message naming the key)."""
    if settings["robust"] not in ROBUST_LOSSES:
        raise ValueError(f"robust must be one of {ROBUST_LOSSES}, got {settings['robust']!r}")
    for key in ("robust_scale", "max_iterations", "bone_tie_sd_m", "min_noise_scale"):
        if not settings[key] > 0:
            raise ValueError(f"{key} must be > 0, got {settings[key]}")
    for key in ("prior_weight", "anchor_weight"):
        if not settings[key] >= 0:
            raise ValueError(f"{key} must be >= 0, got {settings[key]}")
    if settings["bone_prior"] not in BONE_PRIORS or settings["noise_scale"] not in NOISE_SCALES:
        raise ValueError(
            f"bone_prior must be one of {BONE_PRIORS} and noise_scale one of {NOISE_SCALES}, "
            f"got {settings['bone_prior']!r}, {settings['noise_scale']!r}"
        )
    if not hasattr(settings["noise_model"], "sigma"):
        raise ValueError(
            f"noise_model must have sigma() (NoiseModel, CalibratedNoiseModel), got {type(settings['noise_model']).__name__}"
        )


class MAPReconstruction:
    """DLT, then the MAP of Eq. 6 likelihood x Eq. 7 bone prior (mle_first: an MLE solve first); keys as in
    configs/reconstruction/map.yaml, the 2D sigmas from ``noise_model``."""

    takes_skeleton_prior: bool = False  # True where finish() uses a tracker's SkeletonPrior (the adaptive prior)

    def __init__(
        self,
        noise_model: AnyNoiseModel | None = None,
        prior_weight: float = 1.0,
        bone_table: str | Path | Mapping | None = None,
        bone_prior: str = "adaptive",
        noise_scale: str = "estimate",
        bone_tie_sd_m: float = 0.03,
        min_noise_scale: float = 0.01,
        robust: str = "none",
        robust_scale: float = 3.0,
        anchor_weight: float = 1e-3,
        max_iterations: int = 15,
        xtol: float = 1e-4,
        ftol: float = 1e-10,
        min_views: int = 2,
        output_min_views: int = 0,
        single_view_score: float = 0.5,
        unseen_score: float = 0.1,
        mle_first: bool = False,
        fix_swaps: bool = True,
        fix_sides: bool = False,
    ) -> None:
        noise_model = NoiseModel() if noise_model is None else noise_model
        _check(locals())
        self.noise_model, self.bone_prior, self.noise_scale = noise_model, bone_prior, noise_scale
        self.prior_weight, self.bone_tie_sd_m = float(prior_weight), float(bone_tie_sd_m)
        self.min_noise_scale = float(min_noise_scale)
        self.robust, self.robust_scale, self.anchor_weight = robust, float(robust_scale), float(anchor_weight)
        self.max_iterations, self.xtol, self.ftol = int(max_iterations), float(xtol), float(ftol)
        self.min_views, self.output_min_views = int(min_views), int(output_min_views)
        self.single_view_score, self.unseen_score = float(single_view_score), float(unseen_score)
        self.mle_first, self.fix_swaps, self.fix_sides = bool(mle_first), bool(fix_swaps), bool(fix_sides)
        self.bone_mean, self.bone_std = resolve_bone_table(bone_table)
        self.proportion_sd = proportion_sds(self.bone_mean, self.bone_std, ABSOLUTE_SD_M)
        self.takes_skeleton_prior = self.bone_prior == "adaptive" and self.stages() == (False, True)

    def stages(self) -> tuple[bool, ...]:
        """The solves after the DLT (True = with the bone prior); an adaptive prior or noise scale needs the MLE first."""
        adaptive = self.bone_prior == "adaptive" or self.noise_scale == "estimate"
        return (False, True) if self.mle_first or (adaptive and self.prior_weight > 0) else (True,)

    def problem(
        self, poses2d_und: np.ndarray, bboxes: np.ndarray, proj: np.ndarray, anchor: np.ndarray, prior: bool
    ) -> PoseProblem:
        """The problem of undistorted poses: (V, P, J, 3), (V, P, 4), (V, 3, 4), anchor (P, J, 3) -> PoseProblem."""
        return self._problem(*self._observations(poses2d_und, bboxes), proj, anchor, prior)

    def _observations(self, poses2d_und: np.ndarray, bboxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (V, P, J, 2) (np.nan_to_num) and 1 / sigma (V, P, J) (0 where unseen) of undistorted poses."""
        sigma = self.noise_model.sigma(poses2d_und, bboxes, np.arange(len(poses2d_und))[:, None])
        with np.errstate(divide="ignore"):
            inv_sigma = np.where(np.isfinite(sigma), 1.0 / sigma, 0.0)
        return np.nan_to_num(np.asarray(poses2d_und, dtype=np.float64)[..., :2]), inv_sigma

    def _problem(
        self, uv: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray, anchor: np.ndarray, prior: bool, **bones: Any
    ) -> PoseProblem:
        """The problem of observations anchored at (P, J, 3): the table's prior, or none, or ``bones`` (ref, weight)."""
        weight = self.prior_weight / self.bone_std if prior else np.zeros(len(BONE_PAIRS))
        table = {"bone_ref": self.bone_mean, "bone_weight": weight, **bones}
        settings = {"anchor_weight": self.anchor_weight, "robust": self.robust, "robust_scale": self.robust_scale}
        return PoseProblem(proj, uv, inv_sigma, BONE_PAIRS, anchor=anchor, **table, **settings)

    def _repaired(self, und: np.ndarray, proj: np.ndarray, bboxes: np.ndarray) -> tuple[np.ndarray, ...]:
        """2D after side / swap repair, its DLT (P, J, 4), pixels and 1 / sigma of undistorted poses (V, P, J, 3)."""
        if self.fix_sides:  # pairs labelled at random per view: made consistent across views
            und = consistent_sides(und, proj)
        dlt = triangulate_dlt(und, proj, self.min_views)
        if self.fix_sides:  # ... and with the body (limb pairs the wrong way round for their parents)
            und, dlt = chain_sides(*facing_sides(und, dlt))
        uv, inv_sigma = self._observations(und, bboxes)
        swaps = find_swaps(und, inv_sigma, proj, dlt if self.min_views == 2 else None) if self.fix_swaps else []
        if swaps:  # left / right swaps of the detector, undone
            und = apply_swaps(und, swaps)
            uv, inv_sigma = apply_swaps(uv, swaps), apply_swaps(inv_sigma[..., None], swaps)[..., 0]
            redo = sorted({p for _, p, _, _ in swaps})
            dlt = dlt.copy()
            dlt[redo] = triangulate_dlt(und[:, redo], proj, self.min_views)
        return und, dlt, uv, inv_sigma

    def _solve(self, problem: PoseProblem, X0: np.ndarray) -> np.ndarray:
        """The problem's optimum from X0 (P, J, 3) -> (P, J, 3)."""
        return solve_poses(problem, X0, self.max_iterations, self.xtol, self.ftol)[0]

    def first_pass(self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> FirstPass:
        """Repair, DLT, start poses and the first solve: (V, P, J, 3), (V, P, 4) -> FirstPass."""
        und, proj = rig.undistort(poses2d), rig.projection_matrices()
        fixed, dlt, uv, inv_sigma = self._repaired(und, proj, np.asarray(bboxes, dtype=np.float64))
        start, placed = initial_poses(dlt, fixed, proj)
        idx = np.flatnonzero(placed)
        fixed, uv, inv_sigma = fixed[:, idx], uv[:, idx], inv_sigma[:, idx]
        X = self._solve(self._problem(uv, inv_sigma, proj, start[idx], self.stages()[0]), start[idx])
        measured = ((inv_sigma > 0).sum(axis=0) >= 2)[..., None]
        return FirstPass(np.concatenate([X, measured], axis=-1), und, proj, dlt, start, placed, fixed, uv, inv_sigma)

    def finish(self, first: FirstPass, prior: SkeletonPrior | None = None) -> Reconstruction:
        """The MAP solve after an MLE first pass (with the tracker's ``prior`` where given) and the outputs."""
        X, idx, proj = first.start.copy(), np.flatnonzero(first.placed), first.proj
        P, J = X.shape[:2]
        Xp, info, bones = first.poses[..., :3], None, np.full((P, len(BONE_PAIRS)), np.nan)
        if len(idx) and len(self.stages()) == 2:
            mle, Xp = Xp, reinitialise_outliers(Xp, first.fixed, proj)
            problem, info, bones[idx] = self._person_problem(first, Xp, mle, prior)
            Xp = self._solve(problem, Xp)
        X[idx] = Xp
        variance = np.full((P, J), np.inf)
        if len(idx):
            variance[idx] = self._joint_variance(Xp, first.uv, first.inv_sigma, proj, info)
        views, score = seen_views(first.und)
        settings = (self.output_min_views, self.single_view_score, self.unseen_score)
        conf = output_confidence(first.dlt[..., 3], views, score, first.placed, *settings)
        poses = np.concatenate([np.where(conf[..., None] > 0, X, 0.0), conf[..., None]], axis=-1)
        return Reconstruction(poses, variance, bones)

    def __call__(self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> Reconstruction:
        """Reconstruct matched persons: (V, P, J, 3), (V, P, 4) -> Reconstruction (poses (P, J, 4))."""
        return self.finish(self.first_pass(poses2d, bboxes, rig), None)

    def _joint_variance(
        self, X: np.ndarray, uv: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray, info: np.ndarray | None
    ) -> np.ndarray:
        """Per-axis variance (m^2, a third of the covariance's trace) of every joint: (P, J, 3), (V, P, J, 2),
        (V, P, J), (V, 3, 4), the MLE's information (P, J, 3, 3) or None -> (P, J); a 1-view joint gets the bone
        tie along every axis (the prior fixes its depth); inf for a joint no view sees."""
        if info is None:
            scale = self._noise_scales(X, uv, inv_sigma, proj)
            info = joint_information(X, proj, inv_sigma / scale[None, :, None])
        views = (inv_sigma > 0).sum(axis=0)
        tie = np.where(views == 1, 1.0 / self.bone_tie_sd_m**2, 0.0) if self.prior_weight > 0 else 0.0 * views
        var = mean_variances(info, tie)
        return np.where((views >= 1 + (tie == 0)) & np.isfinite(var) & (var > 0), var, np.inf)

    def _noise_scales(
        self, X: np.ndarray, uv: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray, hom: np.ndarray | None = None
    ) -> np.ndarray:
        """Each person's noise over the model (P,): estimated from the residuals at X (P, J, 3), or 1."""
        if self.noise_scale == "estimate":
            return noise_scale(X, uv, inv_sigma, proj, self.min_noise_scale, hom)
        return np.ones(len(X))

    def _person_problem(
        self, first: FirstPass, anchor: np.ndarray, mle: np.ndarray, prior: SkeletonPrior | None
    ) -> tuple[PoseProblem, np.ndarray | None, np.ndarray]:
        """The MAP problem after the MLE (P, J, 3) with each person's noise scale and bone table (person_prior.py),
        the joints' information (None for the population prior) and the bones measured (P, L) (NaN unmeasured).
        With ``prior`` (earlier frames' lengths and SEs) each bone's measurement is combined with it by precision."""
        hom = view_matmul(mle, first.proj)
        inv_sigma = first.inv_sigma / self._noise_scales(mle, first.uv, first.inv_sigma, first.proj, hom)[None, :, None]
        if self.bone_prior == "population":
            return self._problem(first.uv, inv_sigma, first.proj, anchor, True), None, np.nan
        info = joint_information(mle, first.proj, inv_sigma, hom)
        lengths, variances = bone_variances(mle, info, BONE_PAIRS, first.poses[..., 3] > 0)
        measured = np.where(np.isfinite(variances), lengths, np.nan)
        if prior is not None:  # this frame's measurement and the earlier frames' as one
            lengths, sd = combine_estimates(lengths, np.sqrt(variances), prior.lengths, prior.standard_errors)
            variances = sd**2
        mean, sd = person_bone_lengths(
            lengths, variances, self.bone_mean, self.proportion_sd, self.bone_tie_sd_m, BONE_GROUPS
        )
        weight = self.prior_weight / np.sqrt(sd**2 + self.bone_tie_sd_m**2)
        problem = self._problem(first.uv, inv_sigma, first.proj, anchor, True, bone_ref=mean, bone_weight=weight)
        return problem, info, measured


class MLEMAPReconstruction(MAPReconstruction):
    """The paper's full method: DLT -> MLE (likelihood only) -> MAP (likelihood x bone prior)."""

    def __init__(self, **kwargs: Any) -> None:
        """The keys of :class:`MAPReconstruction`, mle_first True by default."""
        super().__init__(**{"mle_first": True, **kwargs})


class MLEReconstruction(MAPReconstruction):
    """The MAP with prior_weight 0 (Eq. 6 alone: every joint its own problem), joints seen in >= 2 views output."""

    def __init__(self, **kwargs: Any) -> None:
        """The keys of :class:`MAPReconstruction`, prior_weight 0 and output_min_views 2 by default."""
        super().__init__(**{"prior_weight": 0.0, "output_min_views": 2, **kwargs})
