"""MLE and MAP 3D crowd pose reconstruction (paper Sec. 3.3) behind the stage interface.

``stage(poses2d (V, P, J, 3) distorted px + score, bboxes (V, P, 4) x y w h, rig) -> (P, J, 4)``.

All persons of a frame are solved by Levenberg-Marquardt with analytic normal equations, either in
compiled loops (``solver="compiled"``, the default: :mod:`reconstruction.solver.compiled_solver`) or by the
batched numpy solver of :mod:`reconstruction.solver.lm_solver` with :mod:`reconstruction.solver.map_estimation`
(``solver="numpy"``, the reference; same iterates), initialised by the vanilla triangulation (DLT)
and a fitted mean body for the joints it cannot triangulate (:mod:`reconstruction.solver.pose_init`). The
cost separates over persons and over the connected components of the bone graph, so the MLE is
solved as P*J independent 3-variable problems and the MAP as P problems per component (COCO-23: the
5 face joints and the 18 body and foot joints), each with its own damping, step acceptance and
stopping test (the numpy solver steps them all together in one loop; a person's face and body share
its linear solve of an iteration, nothing else). The MAP uses the exact Hessian of the bone prior
once a person is near its optimum (see :func:`reconstruction.solver.map_estimation.linearize`); the
solution is the same least-squares optimum as scipy's trust-region least_squares on the same
residuals (tests/test_map_reconstruction.py).

Sigma of a 2D joint: max(sigma_min, sqrt(sigma_px^2 + (c sqrt(box_w box_h))^2) / score^score_power)
pixels: a part in image pixels (a bottom-up detector's quantisation and blur), a part that grows
with the person (a top-down detector localises joints to a fraction of the box it resizes; COCO's
OKS models the same), both less certain at a lower heatmap score. The defaults (5.2 px, 0.016, 1.27)
are fitted to the errors of Shelf's real OpenPose detections against the projected ground truth
(benchmarks/fit_sigma_model.py). With noise_scale="estimate" (the default) the model only sets the
relative weights: each person's scale is estimated from the MLE residuals (person_prior.py).
sigma_min stops near-zero boxes or scores from making a joint infinitely certain.

Output confidence: a joint triangulated by the DLT (seen in >= min_views views) keeps the DLT
confidence (mean score of its views); a joint seen in fewer views but at least one gets
single_view_score x the mean score of its views; an unseen joint placed by the prior and the fitted
body gets unseen_score; joints seen in fewer than output_min_views views are output as 0 (x, y, z and
score), as the DLT does. A person without a single usable triangulated joint is output as all 0.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from data.bone_lengths import ABSOLUTE_SD_M, BONE_MEAN, BONE_PAIRS, MEAN_POSE, resolve_bone_table
from data.geometry.camera import Rig
from data.geometry.triangulation import triangulate_dlt
from reconstruction.solver.block_solver import (
    EliminationPlan,
    elimination_plan,
    graph_components,
    solve_blocks,
    solve_dense,
)
from reconstruction.solver.compiled_solver import solve_poses_compiled
from reconstruction.solver.lm_solver import LMResult, minimize
from reconstruction.solver.map_estimation import (
    BLOCK_DIAG,
    ROBUST_LOSSES,
    Blocks,
    PoseBatch,
    PoseProblem,
    joint_sigma,
    linear_blocks,
)
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
from reconstruction.solver.prior_kernels import mean_variances
from reconstruction.solver.side_labels import chain_sides, consistent_sides, facing_sides
from reconstruction.solver.side_swaps import apply_swaps, find_swaps
from reconstruction.solver.sigma_kernels import observations

SOLVERS = ("compiled", "numpy")
BONE_PRIORS = ("adaptive", "population")  # each person's own bone lengths (person_prior.py) | the table's means
NOISE_SCALES = ("estimate", "model")  # 2D sigma = model x the person's estimated scale | the model alone
BONE_GROUPS = bone_groups()
# MLE poses (P, J, 4) -> each person's bone lengths from earlier frames (P, L) m and their standard errors (P, L)
Skeletons = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
DENSE_MAX_UNITS = 16  # from this many persons the block elimination beats one dense LAPACK solve per person


def bone_components(num_joints: int, bone_pairs: np.ndarray) -> list[np.ndarray]:
    """Joint sets connected by bones (singletons included), each sorted: J, (L, 2) -> list of (j,) arrays."""
    pairs = np.asarray(bone_pairs, dtype=np.int64).reshape(-1, 2)
    return [c.copy() for c in graph_components(int(num_joints), tuple(map(tuple, pairs.tolist())))]


@dataclass(frozen=True)
class GraphLayout:
    """The solver's view of a bone graph: joints reordered so that every component is contiguous."""

    order: np.ndarray  # (J,) original joint at each solver position (components by first joint)
    starts: np.ndarray  # (C,) first solver position of each component
    ranges: list  # [(first, end)] solver positions of each component
    pairs: np.ndarray  # (L, 2) bones in solver positions, in the input order
    joint_comp: np.ndarray  # (J,) component of each solver position
    var_comp: np.ndarray  # (3J,) component of each variable
    bone_comp: np.ndarray  # (L,) component of each bone
    has_bones: np.ndarray  # (C,) bool
    bone_onehot: np.ndarray  # (L, C)
    plan: EliminationPlan


@lru_cache(maxsize=32)
def graph_layout(num_joints: int, pairs: tuple[tuple[int, int], ...]) -> GraphLayout:
    """Layout of the bone graph of J joints with bones (a, b): computed once per graph."""
    comps = graph_components(num_joints, pairs)
    order = np.concatenate(comps)
    position = np.argsort(order)
    sizes = np.array([len(c) for c in comps])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    joint_comp = np.repeat(np.arange(len(comps)), sizes)
    solver_pairs = position[np.array(pairs, dtype=np.int64).reshape(-1, 2)]
    bone_comp = joint_comp[solver_pairs[:, 0]]
    onehot = np.zeros((len(bone_comp), len(comps)))
    onehot[np.arange(len(bone_comp)), bone_comp] = 1.0
    return GraphLayout(
        order,
        starts,
        [(int(s), int(s + n)) for s, n in zip(starts, sizes)],
        solver_pairs,
        joint_comp,
        np.repeat(joint_comp, 3),
        bone_comp,
        np.bincount(bone_comp, minlength=len(comps)) > 0,
        onehot,
        elimination_plan(num_joints, tuple(map(tuple, solver_pairs.tolist()))),
    )


@dataclass
class _PoseLin:
    """A linearisation of the active persons: cost per component (b, C), g (b, 3J) and the blocks (batch last)."""

    cost: np.ndarray
    g: np.ndarray
    blocks: Blocks


class PoseModel:
    """The :class:`reconstruction.solver.lm_solver.Model` of a PoseBatch: one unit per person, one problem per component.

    Trial points are fully linearised (the cost is most of the work and most steps are accepted).
    Systems of fewer than DENSE_MAX_UNITS persons are solved densely, larger batches by block elimination.
    """

    def __init__(self, batch: PoseBatch, layout: GraphLayout) -> None:
        self.batch, self.layout = batch, layout
        self.starts = 3 * layout.starts
        self.has_exact = layout.has_bones
        self._idx: np.ndarray | None = None
        self._sub = batch

    def _take_batch(self, idx: np.ndarray) -> PoseBatch:
        """The batch of the units idx, cached for the solver's current active set."""
        if idx is not self._idx:
            full = len(idx) == self.batch.w.shape[-1] and (len(idx) == 0 or idx[-1] == len(idx) - 1)
            self._idx, self._sub = idx, self.batch if full else self.batch.take(idx)
        return self._sub

    def linearize(self, x: np.ndarray, idx: np.ndarray) -> _PoseLin:
        """Blocks and component costs of the persons idx at x (b, 3J)."""
        b = len(x)
        blocks = linear_blocks(x.reshape(b, -1, 3).transpose(2, 1, 0), self._take_batch(idx))
        cost = np.add.reduceat(blocks.joint_cost, self.layout.starts, axis=0)
        if len(blocks.bone_cost):
            cost += self.layout.bone_onehot.T @ blocks.bone_cost
        return _PoseLin(cost.T, blocks.g.transpose(2, 1, 0).reshape(b, -1), blocks)

    trial = linearize

    def accept(self, lin: _PoseLin, trial: _PoseLin, x: np.ndarray, idx: np.ndarray, ok: np.ndarray) -> _PoseLin:
        """The trial's blocks for the accepted components, the old ones elsewhere."""
        if ok.all():
            return trial
        joint, bone = ok.T[self.layout.joint_comp], ok.T[self.layout.bone_comp]  # (J, b), (L, b)
        old, new = lin.blocks, trial.blocks
        blocks = Blocks(
            np.where(joint, new.joint_cost, old.joint_cost),
            np.where(bone, new.bone_cost, old.bone_cost),
            np.where(joint, new.g, old.g),
            np.where(joint, new.diag, old.diag),
            np.where(bone, new.K, old.K),
            np.where(bone, new.K_rest, old.K_rest),
        )
        return _PoseLin(
            np.where(ok, trial.cost, lin.cost), np.where(ok[:, self.layout.var_comp], trial.g, lin.g), blocks
        )

    def take(self, lin: _PoseLin, keep: np.ndarray) -> _PoseLin:
        """The persons where keep (bool mask or indices)."""
        return _PoseLin(lin.cost[keep], lin.g[keep], lin.blocks.take(keep))

    def max_diagonal(self, lin: _PoseLin) -> np.ndarray:
        """max diag(H) per component, (b, C)."""
        d = lin.blocks.diag[BLOCK_DIAG].max(axis=0)  # (J, b)
        return np.maximum.reduceat(d, self.layout.starts, axis=0).T

    def step(self, lin: _PoseLin, mu: np.ndarray, exact: np.ndarray, run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Damped steps (b, 3J) and whether each problem used the exact model (b, C)."""
        h, pd = self._solve(lin.blocks, mu, exact, run)
        fail = exact & ~pd
        if fail.any():  # exact model not positive definite: the safe one
            rows = np.flatnonzero(fail.any(axis=1))
            exact = exact & ~fail
            h_rows, pd_rows = self._solve(lin.blocks.take(rows), mu[rows], exact[rows], fail[rows])
            redo = fail[rows][:, self.layout.joint_comp].T  # (J, r)
            h[:, :, rows] = np.where(redo, h_rows, h[:, :, rows])
            pd[rows] = np.where(fail[rows], pd_rows, pd[rows])
        h = h.transpose(2, 1, 0).reshape(len(mu), -1)
        h[(run & ~pd)[:, self.layout.var_comp]] = np.nan
        return h, exact

    def _solve(
        self, blocks: Blocks, mu: np.ndarray, exact: np.ndarray, run: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(M + mu I) h = -g per problem -> h (3, J, b) (0 where not run), positive definite (b, C)."""
        lay = self.layout
        diag, K = blocks.diag, blocks.K
        if exact.any():
            K_rest = np.where(exact.T[lay.bone_comp], blocks.K_rest, 0.0)
            diag = diag + (self.batch.shared.incidence @ K_rest.reshape(9, len(lay.pairs), -1)).reshape(diag.shape)
            K = K + K_rest
        damping = mu.T[lay.joint_comp]
        if len(mu) < DENSE_MAX_UNITS and len(lay.pairs):
            return solve_dense(diag, -K, lay.pairs, -blocks.g, lay.ranges, run, damping)
        h, pd = solve_blocks(lay.plan, diag, -K, -blocks.g, damping, check=bool(exact.any()))
        h[:, ~run.T[lay.joint_comp]] = 0.0
        return h, np.logical_and.reduceat(pd, lay.starts, axis=0).T


def solve_poses(
    problem: PoseProblem, X0: np.ndarray, max_iterations: int = 15, xtol: float = 1e-6, ftol: float = 1e-10
) -> tuple[np.ndarray, list[LMResult]]:
    """Minimise the problem's cost from X0 (P, J, 3) -> (P, J, 3) and the LMResult (problems per person and component).

    The cost separates over persons and over the connected components of the bone graph (COCO-23:
    the face, the body with the feet); each (person, component) is its own Levenberg-Marquardt
    problem, all stepped together, and without any bone every joint is its own problem (P*J units
    of 3 variables). Same optimum as one problem per person, smaller linear systems.
    """
    X0 = np.asarray(X0, dtype=np.float64)
    P, J, _ = X0.shape
    if P == 0:
        return X0.copy(), []
    if problem.per_person_bones:  # the batched reference solver shares one table: one person at a time
        L = len(problem.bone_pairs)
        problem = replace(
            problem,
            bone_ref=np.broadcast_to(problem.bone_ref, (P, L)),
            bone_weight=np.broadcast_to(problem.bone_weight, (P, L)),
        )
        parts = [solve_poses(_person_problem(problem, p), X0[p : p + 1], max_iterations, xtol, ftol) for p in range(P)]
        return np.concatenate([x for x, _ in parts]), [r for _, rs in parts for r in rs]
    on = problem.bone_weight > 0
    pairs = problem.bone_pairs[on].reshape(-1, 2)
    problem = replace(problem, bone_pairs=pairs, bone_ref=problem.bone_ref[on], bone_weight=problem.bone_weight[on])
    if len(pairs) == 0:
        model = PoseModel(PoseBatch.of(problem, per_joint=True), graph_layout(1, ()))
        result = minimize(X0.reshape(P * J, 3), model, max_iterations, xtol, ftol)
        return result.x.reshape(P, J, 3), [result]
    layout = graph_layout(J, tuple(map(tuple, pairs.tolist())))
    ordered = np.array_equal(layout.order, np.arange(J))
    if not ordered:
        problem = problem.joints(layout.order)
    result = minimize(
        X0[:, layout.order].reshape(P, 3 * J), PoseModel(PoseBatch.of(problem), layout), max_iterations, xtol, ftol
    )
    X = result.x.reshape(P, J, 3)
    return (X if ordered else X[:, np.argsort(layout.order)]), [result]


def _person_problem(problem: PoseProblem, p: int) -> PoseProblem:
    """The problem of person p alone, with its own (L,) bone table."""
    return replace(
        problem.take(np.array([p])),
        bone_ref=np.asarray(problem.bone_ref[p]),
        bone_weight=np.asarray(problem.bone_weight[p]),
    )


def combine_estimates(
    mean: np.ndarray, sd: np.ndarray, other: np.ndarray, other_sd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Precision-weighted combination of two independent estimates, either ignored where its value or SD is
    NaN / inf: (P, L) x4 -> mean (P, L), SD (P, L) (the first mean and SD inf where neither has any)."""
    first = np.isfinite(mean) & np.isfinite(sd) & (sd > 0)
    use = np.isfinite(other) & np.isfinite(other_sd) & (other_sd > 0)
    w1 = np.where(first, 1.0 / np.where(first, sd, 1.0) ** 2, 0.0)
    w2 = np.where(use, 1.0 / np.where(use, other_sd, 1.0) ** 2, 0.0)
    w = w1 + w2
    with np.errstate(divide="ignore", invalid="ignore"):
        combined = (w1 * np.where(first, mean, 0.0) + w2 * np.where(use, other, 0.0)) / w
        return np.where(w > 0, combined, mean), np.where(w > 0, 1.0 / np.sqrt(w), np.inf)


def output_confidence(
    dlt_conf: np.ndarray,
    poses2d: np.ndarray,
    placed: np.ndarray,
    output_min_views: int,
    single_view_score: float,
    unseen_score: float,
) -> np.ndarray:
    """Confidence of each reconstructed joint (see the module docstring): (P, J), (V, P, J, 3), (P,) -> (P, J)."""
    finite = np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
    score = np.where(finite, np.clip(poses2d[..., 2], 0, None), 0.0)
    views = (score > 0).sum(axis=0)
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


def _warm_up_solves() -> None:
    """Compile (or load) the solver's and the prior's kernels on a tiny problem started at the mean pose."""
    poses2d, proj = _tiny_problem()
    X = np.array(MEAN_POSE, dtype=np.float64)[None]
    for weight in (np.zeros(len(BONE_PAIRS)), np.ones(len(BONE_PAIRS))):
        for robust in ROBUST_LOSSES:
            solve_poses_compiled(
                PoseProblem(proj, poses2d[..., :2], poses2d[..., 2], BONE_PAIRS, BONE_MEAN, weight, X, robust=robust),
                X,
                max_iterations=2,
            )
    w = poses2d[..., 2]  # the prior's kernels (prior_kernels.py)
    info = joint_information(X, proj, w)
    noise_scale(X, poses2d[..., :2], w, proj)
    lengths, variances = bone_variances(X, info, BONE_PAIRS, w.sum(axis=0) >= 2)
    person_bone_lengths(lengths, variances, BONE_MEAN, np.full(len(BONE_PAIRS), 0.02), 0.01, BONE_GROUPS)
    mean_variances(info, np.zeros(X.shape[:2]), np.empty(X.shape[:2]))


@lru_cache(maxsize=1)
def warm_up() -> None:
    """Compile the numba kernels (or load them from numba's on-disk cache) once per process, on a tiny problem.

    Called when a stage is built, so that the first frame's time is the solve's, not the compiler's: the DLT's,
    start poses', swap test's, solver's and prior's kernels.
    """
    poses2d, proj = _tiny_problem()
    X, _ = initial_poses(triangulate_dlt(poses2d, proj), poses2d, proj)
    reinitialise_outliers(X, poses2d, proj)
    sigma = joint_sigma(poses2d, np.ones((len(poses2d), 1, 4)), 0.016, 1.0)
    observations(poses2d.reshape(-1, poses2d.shape[2], 3), sigma.reshape(-1, poses2d.shape[2]))
    find_swaps(poses2d, poses2d[..., 2], proj)
    _warm_up_solves()


class MAPReconstruction:
    """DLT initialisation, then the MAP of Eq. 6 likelihood x Eq. 7 bone prior (mle_first: an MLE step first).

    Keys: c, sigma_min, sigma_px, score_power (2D joint sigma, see the module docstring); noise_scale
    ("estimate": the sigma model times each person's scale from the MLE residuals, "model": the model
    alone), min_noise_scale; bone_prior ("adaptive": each person's own bone lengths with the table as
    their hierarchical prior, reconstruction/solver/person_prior.py, tie bone_tie_sd_m; "population": the
    table's means, the paper); fix_swaps (undo left / right swaps, reconstruction/solver/side_swaps.py); fix_sides (left / right labels consistent
    across views and with the body, reconstruction/solver/side_labels.py);
    prior_weight (w on every bone residual, 0 = plain MLE); bone_table (None = data/bone_lengths.py
    defaults, a JSON path or a {"bones": {name: {mean, std}}} mapping); robust ("none", "huber", "cauchy") and robust_scale (in
    sigma units) on the likelihood; anchor_weight (Tikhonov tau, 1/m); max_iterations, xtol (m),
    ftol (relative) of the solver; solver ("compiled": numba kernels, reconstruction/solver/compiled_solver.py;
    "numpy": the batched numpy solver, same optimum, kept as the reference); min_views (DLT);
    output_min_views, single_view_score, unseen_score (output confidence).
    """

    def __init__(
        self,
        c: float = 0.016,
        sigma_min: float = 1.0,
        prior_weight: float = 1.0,
        bone_table: str | Path | Mapping | None = None,
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
        solver: str = "compiled",
        bone_prior: str = "adaptive",
        noise_scale: str = "estimate",
        bone_tie_sd_m: float = 0.03,
        min_noise_scale: float = 0.01,
        sigma_px: float = 5.2,
        score_power: float = 1.27,
        fix_swaps: bool = True,
        fix_sides: bool = False,
    ) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if robust not in ROBUST_LOSSES:
            raise ValueError(f"robust must be one of {ROBUST_LOSSES}, got {robust!r}")
        for key, value in (("robust_scale", robust_scale), ("max_iterations", max_iterations)):
            if not value > 0:
                raise ValueError(f"{key} must be > 0, got {value}")
        for key, value in (
            ("c", c),
            ("sigma_min", sigma_min),
            ("prior_weight", prior_weight),
            ("anchor_weight", anchor_weight),
        ):
            if not value >= 0:
                raise ValueError(f"{key} must be >= 0, got {value}")
        if sigma_min == 0 and c == 0 and sigma_px == 0:
            raise ValueError("c, sigma_px and sigma_min cannot all be 0")
        if bone_prior not in BONE_PRIORS or noise_scale not in NOISE_SCALES:
            raise ValueError(
                f"bone_prior must be one of {BONE_PRIORS} and noise_scale one of {NOISE_SCALES}, "
                f"got {bone_prior!r}, {noise_scale!r}"
            )
        if not bone_tie_sd_m > 0 or not min_noise_scale > 0:
            raise ValueError(f"bone_tie_sd_m and min_noise_scale must be > 0, got {bone_tie_sd_m}, {min_noise_scale}")
        self.bone_prior, self.noise_scale = bone_prior, noise_scale
        self.bone_tie_sd_m, self.min_noise_scale = float(bone_tie_sd_m), float(min_noise_scale)
        self.c, self.sigma_min, self.prior_weight = float(c), float(sigma_min), float(prior_weight)
        if not sigma_px >= 0 or not score_power >= 0:
            raise ValueError(f"sigma_px and score_power must be >= 0, got {sigma_px}, {score_power}")
        self.sigma_px, self.score_power = float(sigma_px), float(score_power)
        self.fix_swaps, self.last_swaps = bool(fix_swaps), 0
        self.fix_sides = bool(fix_sides)
        self._variance_inputs: tuple = ((0, 0), None)  # what last_joint_variance is computed from, on demand
        self._variance: np.ndarray | None = None
        self.takes_skeletons = self.bone_prior == "adaptive"  # the tracker's bone lengths refine the prior
        self.last_bone_lengths = np.zeros((0, len(BONE_PAIRS)))  # (P, L) m measured by the last MLE, NaN unmeasured
        self._bone_measurements: np.ndarray | None = None
        self._mle_information: np.ndarray | None = None
        self.bone_mean, self.bone_std = resolve_bone_table(bone_table)
        self.proportion_sd = proportion_sds(self.bone_mean, self.bone_std, ABSOLUTE_SD_M)
        self.robust, self.robust_scale = robust, float(robust_scale)
        self.anchor_weight = float(anchor_weight)
        self.max_iterations, self.xtol, self.ftol = int(max_iterations), float(xtol), float(ftol)
        self.min_views, self.output_min_views = int(min_views), int(output_min_views)
        self.single_view_score, self.unseen_score = float(single_view_score), float(unseen_score)
        self.mle_first = bool(mle_first)
        self.solver = solver

    def problem(
        self, poses2d_und: np.ndarray, bboxes: np.ndarray, proj: np.ndarray, anchor: np.ndarray, prior: bool
    ) -> PoseProblem:
        """The least-squares problem of undistorted poses: (V, P, J, 3), (V, P, 4), (V, 3, 4), (P, J, 3) -> PoseProblem."""
        return self._problem(*self._observations(poses2d_und, bboxes), proj, anchor, prior)

    def _observations(self, poses2d_und: np.ndarray, bboxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (V, P, J, 2) (0 where unseen) and 1 / sigma (V, P, J) (0 where unseen) of undistorted poses."""
        sigma = joint_sigma(poses2d_und, bboxes, self.c, self.sigma_min, self.sigma_px, self.score_power)
        V, P, J = sigma.shape
        uv, inv_sigma = observations(np.ascontiguousarray(poses2d_und).reshape(V * P, J, 3), sigma.reshape(V * P, J))
        return uv.reshape(V, P, J, 2), inv_sigma.reshape(V, P, J)

    def _problem(
        self, uv: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray, anchor: np.ndarray, prior: bool
    ) -> PoseProblem:
        """The problem of observations (see _observations) anchored at (P, J, 3), with or without the prior."""
        weight = self.prior_weight / self.bone_std if prior else np.zeros(len(BONE_PAIRS))
        return PoseProblem(
            proj,
            uv,
            inv_sigma,
            BONE_PAIRS,
            self.bone_mean,
            weight,
            anchor,
            self.anchor_weight,
            self.robust,
            self.robust_scale,
        )

    def solve(
        self,
        poses2d_und: np.ndarray,
        bboxes: np.ndarray,
        proj: np.ndarray,
        stages: tuple[bool, ...],
        skeletons: Skeletons | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Swaps undone (fix_swaps), DLT, then one solve per stage (True = with the prior): -> X (P, J, 3),
        DLT (P, J, 4), placed (P,). ``skeletons``: the persons' own bone lengths from earlier frames (a
        tracker's), asked with the MLE poses (see :meth:`_person_problem`)."""
        bboxes = np.asarray(bboxes, dtype=np.float64)
        if self.fix_sides:  # pairs labelled at random per view: made consistent across views
            poses2d_und = consistent_sides(poses2d_und, proj)
        dlt = triangulate_dlt(poses2d_und, proj, self.min_views)
        if self.fix_sides:  # ... and with the body (limb pairs the wrong way round for their parents)
            poses2d_und, dlt = chain_sides(*facing_sides(poses2d_und, dlt))
        uv, inv_sigma = self._observations(poses2d_und, bboxes)
        if self.fix_swaps:  # left / right swaps of the detector, undone
            swaps = find_swaps(poses2d_und, inv_sigma, proj, dlt if self.min_views == 2 else None)
            self.last_swaps = len(swaps)
            if swaps:
                poses2d_und = apply_swaps(poses2d_und, swaps)
                uv, inv_sigma = apply_swaps(uv, swaps), apply_swaps(inv_sigma[..., None], swaps)[..., 0]
                redo = sorted({p for _, p, _, _ in swaps})
                dlt = dlt.copy()
                dlt[redo] = triangulate_dlt(poses2d_und[:, redo], proj, self.min_views)
        X, placed = initial_poses(dlt, poses2d_und, proj)
        idx = np.flatnonzero(placed)
        if len(idx) == 0:
            self._variance_inputs = (X.shape[:2], None)
            self._variance = None
            self.last_bone_lengths = np.full((len(X), len(BONE_PAIRS)), np.nan)
            return X, dlt, placed
        und, uv, inv_sigma = poses2d_und[:, idx], uv[:, idx], inv_sigma[:, idx]
        Xp = X[idx]
        self._bone_measurements = self._mle_information = None
        solve_fn = solve_poses_compiled if self.solver == "compiled" else solve_poses
        for k, prior in enumerate(stages):
            if k == 0:
                problem = self._problem(uv, inv_sigma, proj, Xp, prior)
            else:  # after the MLE: outliers re-initialised, the person's prior
                mle, Xp = Xp, reinitialise_outliers(Xp, und, proj)
                problem = (
                    self._person_problem(uv, inv_sigma, proj, Xp, mle, skeletons)
                    if prior
                    else self._problem(uv, inv_sigma, proj, Xp, False)
                )
            Xp, _ = solve_fn(problem, Xp, self.max_iterations, self.xtol, self.ftol)
        X = X.copy()
        X[idx] = Xp
        self._variance_inputs = (X.shape[:2], (idx, Xp, uv, inv_sigma, proj))
        self._variance = None
        self.last_bone_lengths = np.full((len(X), len(BONE_PAIRS)), np.nan)
        if self._bone_measurements is not None:
            self.last_bone_lengths[idx] = self._bone_measurements
        return X, dlt, placed

    @property
    def last_joint_variance(self) -> np.ndarray:
        """Per-axis variance (P, J) m^2 of every joint of the last call (see :meth:`_joint_variance`; inf for a
        person not placed), computed when asked (a tracker's measurement noise) and kept."""
        shape, inputs = self._variance_inputs
        if self._variance is None:
            self._variance = np.full(shape, np.inf)
            if inputs is not None:
                idx, X, uv, inv_sigma, proj = inputs
                self._variance[idx] = self._joint_variance(X, uv, inv_sigma, proj)
        return self._variance

    def _joint_variance(self, X: np.ndarray, uv: np.ndarray, inv_sigma: np.ndarray, proj: np.ndarray) -> np.ndarray:
        """Per-axis variance (m^2, a third of the covariance's trace) of every joint, at each person's noise scale:
        (P, J, 3), (V, P, J, 2), (V, P, J), (V, 3, 4) -> (P, J). The likelihood's information (at the MLE poses
        where the MAP had them), plus for a joint seen in one view the bone tie along every axis (the prior fixes its depth); inf for a joint no view sees."""
        info = self._mle_information  # at the MLE poses, with the person's noise scale (the MAP is close)
        if info is None or len(info) != len(X):
            scale = (
                noise_scale(X, uv, inv_sigma, proj, self.min_noise_scale)
                if self.noise_scale == "estimate"
                else np.ones(len(X))
            )
            info = joint_information(X, proj, inv_sigma / scale[None, :, None])
        views = (inv_sigma > 0).sum(axis=0)
        tie = np.where(views == 1, 1.0 / self.bone_tie_sd_m**2, 0.0) if self.prior_weight > 0 else 0.0 * views
        var = np.empty(views.shape)
        mean_variances(np.ascontiguousarray(info), np.ascontiguousarray(tie, dtype=np.float64), var)
        return np.where((views >= 1 + (tie == 0)) & np.isfinite(var) & (var > 0), var, np.inf)

    def _person_problem(
        self,
        uv: np.ndarray,
        inv_sigma: np.ndarray,
        proj: np.ndarray,
        anchor: np.ndarray,
        mle: np.ndarray,
        skeletons: Skeletons | None = None,
    ) -> PoseProblem:
        """The MAP problem after an MLE solve (P, J, 3): each person's noise scale and bone table (person_prior.py).

        With ``skeletons`` (MLE poses (P, J, 4) -> the person's bone lengths (P, L) measured in earlier frames and
        their standard errors (P, L), NaN / inf where unknown), each bone's measurement in this frame is combined
        with the earlier frames' by precision before the population prior is applied, once: a person followed
        for a while is fitted with their own skeleton."""
        hom = view_matmul(mle, proj)
        scale = (
            noise_scale(mle, uv, inv_sigma, proj, self.min_noise_scale, hom)
            if self.noise_scale == "estimate"
            else np.ones(len(mle))
        )
        inv_sigma = inv_sigma / scale[None, :, None]
        if self.bone_prior == "population":
            return self._problem(uv, inv_sigma, proj, anchor, True)
        info = joint_information(mle, proj, inv_sigma, hom)
        self._mle_information = info  # the joints' information, kept for last_joint_variance
        measured = (inv_sigma > 0).sum(axis=0) >= 2
        lengths, variances = bone_variances(mle, info, BONE_PAIRS, measured)
        self._bone_measurements = np.where(np.isfinite(variances), lengths, np.nan)
        if skeletons is not None:  # this frame's measurement and the earlier frames' as one
            own, se = skeletons(np.concatenate([mle, measured[..., None].astype(np.float64)], axis=-1))
            lengths, sd = combine_estimates(lengths, np.sqrt(variances), own, se)
            variances = sd**2
        mean, sd = person_bone_lengths(
            lengths, variances, self.bone_mean, self.proportion_sd, self.bone_tie_sd_m, BONE_GROUPS
        )
        weight = self.prior_weight / np.sqrt(sd**2 + self.bone_tie_sd_m**2)
        return PoseProblem(
            proj, uv, inv_sigma, BONE_PAIRS, mean, weight, anchor, self.anchor_weight, self.robust, self.robust_scale
        )

    def stages(self) -> tuple[bool, ...]:
        """The solves this reconstruction runs after the DLT (True = with the bone prior). A person-adaptive
        prior or an estimated noise scale needs the MLE first."""
        adaptive = self.bone_prior == "adaptive" or self.noise_scale == "estimate"
        return (False, True) if self.mle_first or (adaptive and self.prior_weight > 0) else (True,)

    def __call__(
        self, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig, skeletons: Skeletons | None = None
    ) -> np.ndarray:
        """Reconstruct matched persons: (V, P, J, 3), (V, P, 4) -> (P, J, 4); skeletons: see :meth:`solve`."""
        und = rig.undistort(poses2d)
        P, J = und.shape[1:3]
        if P == 0:
            self._variance_inputs = ((0, J), None)
            self._variance = None
            self.last_bone_lengths = np.zeros((0, len(BONE_PAIRS)))
            return np.zeros((0, J, 4))
        X, dlt, placed = self.solve(und, bboxes, rig.projection_matrices(), self.stages(), skeletons)
        conf = output_confidence(
            dlt[..., 3], und, placed, self.output_min_views, self.single_view_score, self.unseen_score
        )
        return np.concatenate([np.where(conf[..., None] > 0, X, 0.0), conf[..., None]], axis=-1)


class MLEMAPReconstruction(MAPReconstruction):
    """The paper's full method: DLT -> MLE (likelihood only) -> MAP (likelihood x bone prior)."""

    def __init__(self, **kwargs: Any) -> None:
        """The keys of :class:`MAPReconstruction`, with mle_first = True."""
        kwargs.setdefault("mle_first", True)
        super().__init__(**kwargs)


class MLEReconstruction(MAPReconstruction):
    """DLT, then the maximum-likelihood refinement of Eq. 6 alone (no prior; joints stay independent)."""

    def __init__(
        self,
        c: float = 0.016,
        sigma_min: float = 1.0,
        robust: str = "none",
        robust_scale: float = 3.0,
        anchor_weight: float = 1e-3,
        max_iterations: int = 15,
        xtol: float = 1e-4,
        ftol: float = 1e-10,
        min_views: int = 2,
        output_min_views: int = 2,
        single_view_score: float = 0.5,
        unseen_score: float = 0.1,
        solver: str = "compiled",
        sigma_px: float = 5.2,
        score_power: float = 1.27,
        fix_swaps: bool = True,
        fix_sides: bool = False,
    ) -> None:
        super().__init__(
            c=c,
            sigma_min=sigma_min,
            sigma_px=sigma_px,
            score_power=score_power,
            prior_weight=0.0,
            fix_swaps=fix_swaps,
            fix_sides=fix_sides,
            robust=robust,
            robust_scale=robust_scale,
            anchor_weight=anchor_weight,
            max_iterations=max_iterations,
            xtol=xtol,
            ftol=ftol,
            min_views=min_views,
            output_min_views=output_min_views,
            single_view_score=single_view_score,
            unseen_score=unseen_score,
            solver=solver,
        )

    def stages(self) -> tuple[bool, ...]:
        """One solve without the prior."""
        return (False,)
