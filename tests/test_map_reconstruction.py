"""MLE / MAP reconstruction (paper Sec. 3.3): bone table, residuals and Jacobians, the batched solver, stages."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from data.bone_lengths import (
    BONE_MEAN,
    BONE_NAMES,
    BONE_PAIRS,
    BONE_STD,
    MEAN_POSE,
    bone_lengths,
    estimate_bone_table,
    resolve_bone_table,
)
from data.geometry.triangulation import smallest_eigenvectors, triangulate_dlt
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.body import mean_body, pose_joints
from data.synthetic.observe import bbox_from_keypoints
from data.synthetic.rigs import ring_rig
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import gather_views
from reconstruction.reconstructors import VanillaTriangulation
from reconstruction.solver import map_estimation as me
from reconstruction.solver import map_solver, pose_kernels
from reconstruction.solver.block_solver import _assemble, elimination_plan, inverse_3x3, solve_blocks, solve_dense
from reconstruction.solver.compiled_solver import plan_arrays, solve_poses_compiled, solver_plan
from reconstruction.solver.lm_solver import levenberg_marquardt
from reconstruction.solver.map_solver import (
    MAPReconstruction,
    MLEMAPReconstruction,
    MLEReconstruction,
    bone_components,
    solve_poses,
)
from reconstruction.solver.pose_init import initial_poses, reinitialise_outliers
from reconstruction.solver.sigma_kernels import sigmas_of_joints

STAGES = {
    "vanilla": VanillaTriangulation,
    "mle": MLEReconstruction,
    "map": MAPReconstruction,
    "mle_map": MLEMAPReconstruction,
}


def _rig(num: int = 5):
    return ring_rig(num, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))


def _persons(num: int = 3, walking: bool = True) -> np.ndarray:
    """Mean-body persons (identical bone lengths) at different places, headings and gait phases: (P, 23, 3)."""
    spots = [(-1.5, 0.5, 0.3), (1.0, -1.0, 2.0), (0.3, 1.5, -1.2), (-0.5, -1.8, 4.0)]
    return np.stack(
        [pose_joints(mean_body(), x, y, t, 0.17 * i, walking and i % 2 == 0) for i, (x, y, t) in enumerate(spots[:num])]
    )


def _observe(rig, X: np.ndarray, noise_px: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Detections of world persons in every view: (P, J, 3) -> poses2d (V, P, J, 3), bboxes (V, P, 4)."""
    rng = np.random.default_rng(seed)
    uv = rig.project(X) + rng.normal(0.0, noise_px, (len(rig),) + X.shape[:2] + (2,))
    poses2d = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
    boxes = np.stack([bbox_from_keypoints(p, cam.size) for p, cam in zip(poses2d, rig)])
    return poses2d, boxes


def _table(lengths: np.ndarray) -> dict:
    return {"bones": {n: {"mean": float(m), "std": float(s)} for n, m, s in zip(BONE_NAMES, lengths, BONE_STD)}}


# --- bone table -----------------------------------------------------------------------------------
def test_default_table_is_the_synthetic_mean_body_and_covers_every_bone():
    standing = pose_joints(mean_body(), 0.0, 0.0, 0.0)
    assert len(BONE_NAMES) == len(BONE_PAIRS) == len(BONE_MEAN) == len(BONE_STD) == 24
    np.testing.assert_allclose(BONE_MEAN, bone_lengths(standing), atol=1e-4)
    np.testing.assert_allclose(bone_lengths(MEAN_POSE), BONE_MEAN, atol=2e-3)
    assert np.all(BONE_STD > 0.01) and np.all(BONE_STD < 0.2 * BONE_MEAN + 0.011)
    with pytest.raises(ValueError):
        BONE_MEAN[0] = 1.0  # read-only constants


def test_estimate_bone_table_uses_valid_joints_only():
    X = np.concatenate([_persons(4), np.ones((4, 23, 1))], axis=-1)
    X[1, 9, :3] = 100.0
    X[1, 9, 3] = 0.0  # invalid wrist: its bone is skipped
    mean, std, count = estimate_bone_table(X)
    np.testing.assert_allclose(mean, bone_lengths(_persons(1))[0], atol=1e-9)
    assert count[BONE_NAMES.index("left_forearm")] == 3 and count[0] == 4
    assert np.all(std < 1e-9)
    mean, std, count = estimate_bone_table(X[:1, :, :] * np.array([1, 1, 1, 0]))
    assert np.all(np.isnan(mean)) and np.all(count == 0)


def test_bone_table_json_round_trip_keeps_defaults_and_rejects_bad_entries(tmp_path):
    path = tmp_path / "bones.json"
    path.write_text(json.dumps({"bones": {"hips": {"mean": 0.22, "std": 0.02}}}))
    mean, std = resolve_bone_table(path)
    i = BONE_NAMES.index("hips")
    assert mean[i] == 0.22 and std[i] == 0.02
    np.testing.assert_array_equal(np.delete(mean, i), np.delete(BONE_MEAN, i))
    with pytest.raises(ValueError, match="unknown bone 'tail'"):
        resolve_bone_table({"bones": {"tail": {"mean": 0.3, "std": 0.1}}})
    with pytest.raises(ValueError, match="'hips'"):
        resolve_bone_table({"bones": {"hips": {"mean": -1, "std": 0.1}}})


def test_fit_bone_lengths_on_shelf_writes_a_loadable_table(shared_data, tmp_path, capsys):
    from benchmarks.fit_bone_lengths import main

    out = tmp_path / "shelf.json"
    main(["--shelf", str(shared_data / "shelf/4d_association/gt.txt"), "--output", str(out)])
    assert "left_thigh" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert len(doc["bones"]) == 12 and "left_toes" not in doc["bones"]  # Shelf-14 has no feet or face
    mean, _ = resolve_bone_table(out)
    assert 0.3 < mean[BONE_NAMES.index("left_thigh")] < 0.5


# --- residuals and Jacobians ----------------------------------------------------------------------
def _random_problem(P: int = 2, seed: int = 0, robust: str = "none", prior: float = 1.0) -> tuple:
    rng = np.random.default_rng(seed)
    rig = _rig(4)
    X = _persons(P) + rng.normal(0, 0.03, (P, 23, 3))
    uv = rig.project(X) + rng.normal(0, 3.0, (4, P, 23, 2))
    inv_sigma = rng.uniform(0.1, 0.5, (4, P, 23)) * (rng.random((4, P, 23)) > 0.25)
    problem = me.PoseProblem(
        rig.projection_matrices(),
        uv,
        inv_sigma,
        BONE_PAIRS,
        BONE_MEAN,
        prior / BONE_STD,
        X + rng.normal(0, 0.01, X.shape),
        1e-3,
        robust,
        1.0,
    )
    return problem, X + rng.normal(0, 0.02, X.shape)


def test_analytic_jacobian_equals_finite_differences():
    problem, X = _random_problem()
    for p in range(len(X)):
        one = problem.take(np.array([p]))
        jac = me.numeric_jacobian(X[p : p + 1], one)
        r = me.residual_vector(X[p : p + 1], one)[0]
        f, H, g = me.normal_equations(X[p : p + 1], one, "gauss_newton")
        np.testing.assert_allclose(H[0], jac.T @ jac, atol=1e-6 * np.abs(H).max())
        np.testing.assert_allclose(g[0], jac.T @ r, atol=1e-6 * np.abs(g).max())
        np.testing.assert_allclose(f[0], 0.5 * r @ r, rtol=1e-12)


@pytest.mark.parametrize("robust", ["none", "huber", "cauchy"])
def test_gradient_and_exact_prior_hessian_match_finite_differences(robust):
    problem, X = _random_problem(1, seed=3, robust=robust)
    f, H_safe, g, H_exact = me.linearize(X, problem)
    x0, h = X.reshape(-1), 1e-6
    cost = lambda x: me.cost(x.reshape(X.shape), problem)[0]
    num_g = np.array([(cost(x0 + h * e) - cost(x0 - h * e)) / (2 * h) for e in np.eye(69)])
    np.testing.assert_allclose(g[0], num_g, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(f, me.cost(X, problem), rtol=1e-12)
    assert np.linalg.eigvalsh(H_safe[0]).min() > -1e-9
    prior_only = me.PoseProblem(
        problem.proj, problem.uv, 0 * problem.inv_sigma, BONE_PAIRS, BONE_MEAN, 1 / BONE_STD, problem.anchor, 0.0
    )
    grad = lambda x: me.linearize(x.reshape(X.shape), prior_only)[2][0]
    num_H = np.stack([(grad(x0 + 1e-5 * e) - grad(x0 - 1e-5 * e)) / 2e-5 for e in np.eye(69)])
    exact = me.linearize(X, prior_only)[3][0]
    np.testing.assert_allclose(exact, num_H, atol=1e-4 * np.abs(exact).max())


# --- the batched solver ---------------------------------------------------------------------------
def test_levenberg_marquardt_solves_a_batch_of_rosenbrock_problems():
    a = np.array([1.0, 2.0, -0.5])

    def residuals(x, idx):
        return np.stack([10 * (x[:, 1] - x[:, 0] ** 2), a[idx] - x[:, 0]], axis=1)

    def linearize(x, idx):
        r = residuals(x, idx)
        jac = np.zeros((len(x), 2, 2))
        jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0] = -20 * x[:, 0], 10.0, -1.0
        return 0.5 * (r**2).sum(1), jac.transpose(0, 2, 1) @ jac, np.einsum("bri,br->bi", jac, r)

    result = levenberg_marquardt(
        np.array([[-1.2, 1.0]] * 3),
        linearize,
        lambda x, idx: 0.5 * (residuals(x, idx) ** 2).sum(1),
        max_iterations=200,
        xtol=1e-12,
        ftol=0.0,
    )
    np.testing.assert_allclose(result.x, np.stack([a, a**2], axis=1), atol=1e-8)


def _scipy_optimum(problem: me.PoseProblem, X0: np.ndarray, loss: str = "linear") -> np.ndarray:
    out = []
    for p in range(len(X0)):
        one = problem.take(np.array([p]))
        fun = lambda x: me.residual_vector(x.reshape(1, -1, 3), one)[0]
        res = least_squares(
            fun,
            X0[p].ravel(),
            method="trf",
            jac="2-point",
            loss=loss,
            f_scale=problem.robust_scale,
            ftol=1e-12,
            xtol=1e-12,
            gtol=1e-12,
            max_nfev=2000,
        )
        out.append(res.x.reshape(-1, 3))
    return np.stack(out)


@pytest.mark.parametrize(
    "prior,robust,linear,bones",
    [
        (1.0, "none", "dense", "all"),
        (1.0, "none", "blocks", "all"),
        (1.0, "none", "compiled", "all"),
        (0.0, "none", "dense", "all"),
        (0.0, "none", "compiled", "all"),
        (0.0, "huber", "dense", "all"),
        (0.0, "huber", "blocks", "all"),
        (0.0, "huber", "compiled", "all"),
        (1.0, "none", "dense", "arms"),
        (1.0, "none", "blocks", "arms"),
        (1.0, "none", "compiled", "arms"),
    ],
)
def test_batched_solver_reaches_the_scipy_trf_optimum(prior, robust, linear, bones, monkeypatch):
    """Same residual function, per-person scipy TRF with a numerical Jacobian, both tightly converged.

    Without the prior a joint seen in one view has its depth fixed only by the 1e-3 anchor, a cost
    change of ~1e-12 per mm, below scipy's tolerances; there only the costs are compared. linear:
    the numpy solver's damped systems solved densely (LAPACK) or by the block elimination of
    many-person batches, or the compiled solver (numba, block Cholesky).
    bones "arms": only the arm and left-foot bones (components interleaved with bone-free joints).
    """
    monkeypatch.setattr(map_solver, "DENSE_MAX_UNITS", 100 if linear == "dense" else 0)
    rig, X = _rig(5), _persons(3)
    poses2d, boxes = _observe(rig, X, noise_px=4.0, seed=7)
    rng = np.random.default_rng(7)
    single = rng.random(X.shape[:2]) < 0.15  # ~15 % of the joints in one view only
    keep = rng.integers(0, 5, X.shape[:2])
    poses2d[..., 2] *= np.where(single[None], np.arange(5)[:, None, None] == keep[None], 1.0)
    poses2d[rng.random(poses2d.shape[:-1]) < 0.1] = 0.0  # and a few more missing 2D joints
    stage = MAPReconstruction(prior_weight=prior, robust=robust, robust_scale=1.0)
    und, proj = rig.undistort(poses2d), rig.projection_matrices()
    X0, placed = initial_poses(triangulate_dlt(und, proj), und, proj)
    assert placed.all()
    problem = stage.problem(und, boxes, proj, X0, prior > 0)
    boned = np.ones(23, dtype=bool)
    if bones == "arms":
        on = np.isin(
            np.array(BONE_NAMES),
            [
                "left_upper_arm",
                "right_upper_arm",
                "left_forearm",
                "right_forearm",
                "left_ankle_heel",
                "left_ankle_big_toe",
                "left_toes",
                "left_heel_big_toe",
            ],
        )
        problem = replace(problem, bone_weight=problem.bone_weight * on)
        boned = np.isin(np.arange(23), BONE_PAIRS[on])
    solve = solve_poses_compiled if linear == "compiled" else solve_poses
    ours, _ = solve(problem, X0, max_iterations=300, xtol=1e-12, ftol=0.0)
    theirs = _scipy_optimum(problem, X0, "linear" if robust == "none" else robust)
    np.testing.assert_array_less(me.cost(ours, problem), me.cost(theirs, problem) * (1 + 1e-9) + 1e-9)
    determined = (poses2d[..., 2] > 0).sum(axis=0) >= np.where(boned & (prior > 0), 1, 2)
    assert determined.sum() > 50 and (~determined).sum() >= (0 if prior > 0 else 5)
    np.testing.assert_allclose(ours[determined], theirs[determined], atol=1e-4)


def test_compiled_and_numpy_solvers_agree_on_a_noisy_crowd():
    """Same problems, damping and stopping rules: the same iterates up to rounding, with the default tolerances."""
    seq = generate_sequence(
        SyntheticConfig(seed=3, num_frames=1, num_persons=25, density=0.5, num_cameras=6, noise_px=5.0)
    )
    frame = seq.frames[0]
    poses2d, boxes = gather_views(frame.views, OracleMatcher()(frame.views, seq.rig).assignment)
    outs = [MLEMAPReconstruction(solver=s, robust="huber")(poses2d, boxes, seq.rig) for s in ("compiled", "numpy")]
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-6)
    with pytest.raises(ValueError, match="solver"):
        MAPReconstruction(solver="fortran")


@pytest.mark.parametrize("graph", ["coco", "cycles"])
def test_compiled_block_cholesky_matches_numpy_and_detects_indefinite_systems(graph):
    edges = np.asarray(
        BONE_PAIRS
        if graph == "coco"
        else [[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [4, 5], [5, 6], [6, 4], [7, 8], [8, 9], [9, 7], [1, 3]]
    )
    J = 23 if graph == "coco" else 11
    diag, off, rhs, damping, A = _block_system(edges, J, 9, seed=2, shift=6.0)
    plan = solver_plan(J, tuple(map(tuple, edges.tolist())))
    definite = np.linalg.eigvalsh(A).min(axis=1) > 0
    assert 0 < definite.sum() < 9
    pos = plan.pos_joint
    for b in range(9):
        D = (diag[:, :, pos, b] + damping[pos, b] * np.eye(3)[..., None]).transpose(2, 0, 1).copy()
        K = -off[..., b].transpose(2, 0, 1).copy()  # solve_component puts -K off the diagonal
        g = -rhs[:, pos, b].T.copy()
        h = np.zeros((J, 3))
        B = np.empty((plan.slot.max() + 1, 3, 3))
        arrays = plan_arrays(plan)
        ok = all(
            pose_kernels.solve_component(c, D, K, np.zeros_like(K), g, 0.0, False, arrays, B, h)
            for c in range(len(plan.comp_start) - 1)
        )
        assert ok == definite[b]
        if ok:
            x = np.zeros((J, 3))
            x[pos] = h
            np.testing.assert_allclose(x.ravel(), np.linalg.solve(A[b], rhs[:, :, b].T.ravel()), atol=1e-10)


def test_bone_graph_splits_into_face_and_body():
    comps = bone_components(23, BONE_PAIRS)
    assert sorted(len(c) for c in comps) == [5, 18]


def _block_system(edges: np.ndarray, J: int, b: int, seed: int, shift: float = 8.0) -> tuple:
    """Random symmetric block systems on a joint graph: diag (3, 3, J, b), off (3, 3, E, b), rhs (3, J, b), dense."""
    rng = np.random.default_rng(seed)
    off = rng.normal(size=(3, 3, len(edges), b))
    off = off + off.transpose(1, 0, 2, 3)
    diag = rng.normal(size=(3, 3, J, b))
    diag = np.einsum("ijkb,ljkb->ilkb", diag, diag) + shift * np.eye(3)[..., None, None]
    rhs = rng.normal(size=(3, J, b))
    damping = rng.random((J, b))
    damped = diag.copy()
    damped[[0, 1, 2], [0, 1, 2]] += damping
    return diag, off, rhs, damping, _assemble(damped, off, edges)


@pytest.mark.parametrize("graph", ["coco", "cycles"])
def test_block_elimination_and_dense_solves_match_numpy(graph):
    edges = (
        BONE_PAIRS
        if graph == "coco"
        else np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [4, 5], [5, 6], [6, 4], [7, 8], [8, 9], [9, 7], [1, 3]])
    )
    J = 23 if graph == "coco" else 11  # joint 10 has no edge
    edges = np.asarray(edges)
    diag, off, rhs, damping, A = _block_system(edges, J, 9, seed=2, shift=6.0)
    ref = np.linalg.solve(A, rhs.transpose(2, 1, 0).reshape(9, -1)[..., None])[..., 0]
    plan = elimination_plan(J, tuple(map(tuple, edges.tolist())))
    eliminated = np.concatenate([lv.pivots for lv in plan.levels])
    np.testing.assert_array_equal(np.sort(eliminated), np.arange(J))  # every joint once
    x, pd = solve_blocks(plan, diag, off, rhs, damping)
    definite = np.linalg.eigvalsh(A).min(axis=1) > 0
    np.testing.assert_array_equal(pd.all(axis=0), definite)
    assert 0 < definite.sum() < 9  # the shift leaves some indefinite
    np.testing.assert_allclose(x.transpose(2, 1, 0).reshape(9, -1)[definite], ref[definite], atol=1e-10)
    comps = bone_components(J, edges)
    ranges = [(int(c[0]), int(c[-1]) + 1) for c in comps]
    assert all(len(c) == e - s for c, (s, e) in zip(comps, ranges))  # contiguous here
    run = np.ones((9, len(comps)), dtype=bool)
    run[0, 0] = False
    xd, pdd = solve_dense(diag, off, edges, rhs, ranges, run, damping)
    solved = np.repeat(run[:, np.repeat(np.arange(len(comps)), [len(c) for c in comps])], 3, axis=1)
    check = solved & definite[:, None]
    np.testing.assert_allclose(xd.transpose(2, 1, 0).reshape(9, -1)[check], ref[check], atol=1e-10)
    assert np.all(xd.transpose(2, 1, 0).reshape(9, -1)[~solved] == 0)
    for c, (s, e) in enumerate(ranges):
        np.testing.assert_array_equal(pdd[run[:, c], c], pd[s:e].all(axis=0)[run[:, c]])


def test_inverse_3x3_and_smallest_eigenvectors_match_lapack():
    rng = np.random.default_rng(4)
    M = rng.normal(size=(500, 3, 3))
    A = M @ M.transpose(0, 2, 1) + 0.01 * np.eye(3)
    A[0] = -A[0]  # one not positive definite
    inv, pd = inverse_3x3(A.transpose(1, 2, 0))
    np.testing.assert_allclose(inv.transpose(2, 0, 1), np.linalg.inv(A), rtol=1e-8, atol=1e-8)
    assert not pd[0] and pd[1:].all()
    # DLT-like normal matrices: many rows nearly through one homogeneous point, some degenerate
    rows = rng.normal(size=(600, 8, 4))
    point = np.concatenate([rng.normal(size=(600, 3)), np.ones((600, 1))], axis=1)
    rows -= (rows @ point[..., None]) * point[:, None, :] / (point * point).sum(1)[:, None, None]
    rows += rng.normal(0, 1e-3, rows.shape) * (rng.random((600, 1, 1)) < 0.8) + rng.normal(0, 0.3, rows.shape) * (
        rng.random((600, 1, 1)) < 0.1
    )
    N = rows.transpose(0, 2, 1) @ rows
    ours, ref = smallest_eigenvectors(N), np.linalg.eigh(N)[1][..., 0]
    cos = np.abs((ours * ref).sum(axis=1))
    assert np.all(1 - cos < 1e-12)
    np.testing.assert_allclose((ours * ours).sum(axis=1), 1.0, rtol=1e-14)
    scaled = smallest_eigenvectors(N[:50] * 1e12)  # the stopping rule is relative: any scale
    assert np.all(1 - np.abs((scaled * ref[:50]).sum(axis=1)) < 1e-12)


# --- stages -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(STAGES))
def test_noise_free_input_is_reconstructed_exactly(name):
    """Every stage returns the truth on exact detections.

    For MAP the truth is the optimum only when the reference bone lengths are the person's own (all
    likelihood and prior residuals are then zero); with any other table the optimum trades pixels for
    bone lengths and moves off the truth (see the next test). All test persons share the mean body.
    """
    rig, X = _rig(), _persons(3)
    poses2d, boxes = _observe(rig, X)
    kwargs = {"bone_table": _table(bone_lengths(X[0]))} if "map" in name else {}
    out = STAGES[name](**kwargs)(poses2d, boxes, rig)
    assert out.shape == (3, 23, 4)
    np.testing.assert_allclose(out[..., :3], X, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 0.9)


def test_map_with_a_wrong_reference_is_biased_but_a_weak_or_adaptive_prior_is_not():
    rig, X = _rig(), _persons(3)
    poses2d, boxes = _observe(rig, X)
    table = _table(bone_lengths(X[0]) * 1.1)  # everyone 10 % taller than the table
    paper = dict(bone_table=table, bone_prior="population", noise_scale="model")
    biased = MAPReconstruction(**paper)(poses2d, boxes, rig)
    weak = MAPReconstruction(**paper, prior_weight=1e-4)(poses2d, boxes, rig)
    adaptive = MAPReconstruction(bone_table=table)(poses2d, boxes, rig)
    err = np.linalg.norm(biased[..., :3] - X, axis=-1)
    assert 1e-4 < err.mean() < 0.02
    np.testing.assert_allclose(weak[..., :3], X, atol=1e-5)
    np.testing.assert_allclose(adaptive[..., :3], X, atol=5e-4)  # exact 2D: the triangulated points (0.5 mm)


def test_map_moves_bone_lengths_towards_the_reference():
    rig, X = _rig(), _persons(4)
    poses2d, boxes = _observe(rig, X, noise_px=6.0, seed=3)
    ref = bone_lengths(X[0])
    table = _table(ref)
    mle = MLEReconstruction()(poses2d, boxes, rig)
    mapped = MAPReconstruction(bone_table=table)(poses2d, boxes, rig)
    dev = lambda out: np.mean(np.abs(bone_lengths(out) - ref))
    assert dev(mapped) < 0.7 * dev(mle)
    assert np.linalg.norm(mapped[..., :3] - X, axis=-1).mean() < np.linalg.norm(mle[..., :3] - X, axis=-1).mean()


def test_joints_seen_in_one_view_or_none_get_a_position_near_the_truth():
    rig, X = _rig(), _persons(2, walking=False)
    poses2d, boxes = _observe(rig, X, noise_px=1.0, seed=5)
    poses2d[1:, 0, 9] = 0.0  # person 0's left wrist: only view 0
    poses2d[:, 0, 7] = 0.0  # person 0's left elbow: no view
    poses2d[:, 1, 18] = 0.0  # person 1's left small toe: no view
    vanilla = VanillaTriangulation()(poses2d, boxes, rig)
    assert vanilla[0, 9, 3] == 0 and vanilla[0, 7, 3] == 0
    for stage in (MAPReconstruction(), MLEMAPReconstruction()):
        out = stage(poses2d, boxes, rig)
        assert np.all(np.isfinite(out))
        err = np.linalg.norm(out[..., :3] - X, axis=-1)
        assert err[0, 9] < 0.10 and err[0, 7] < 0.10 and err[1, 18] < 0.10
        np.testing.assert_allclose(out[0, 9, 3], 0.5 * 0.9)
        assert out[0, 7, 3] == pytest.approx(0.1) and out[1, 18, 3] == pytest.approx(0.1)
    mle = MLEReconstruction()(poses2d, boxes, rig)
    assert mle[0, 9, 3] == 0 and mle[0, 7, 3] == 0 and np.all(mle[0, 7, :3] == 0)


def test_stages_take_no_person_and_do_not_touch_their_input():
    rig = _rig()
    assert MLEMAPReconstruction()(np.zeros((5, 0, 23, 3)), np.zeros((5, 0, 4)), rig).shape == (0, 23, 4)
    poses2d, boxes = _observe(rig, _persons(2), noise_px=3.0)
    before = poses2d.copy(), boxes.copy()
    MLEMAPReconstruction(robust="cauchy")(poses2d, boxes, rig)
    np.testing.assert_array_equal(poses2d, before[0])
    np.testing.assert_array_equal(boxes, before[1])
    with pytest.raises(ValueError, match="robust"):
        MAPReconstruction(robust="l1")


def test_configs_instantiate_the_stages():
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    for name, cls in (("mle", MLEReconstruction), ("map", MAPReconstruction), ("mle_map", MLEMAPReconstruction)):
        stage = instantiate(OmegaConf.load(f"configs/reconstruction/{name}.yaml"))
        assert type(stage) is cls


def test_mle_map_beats_vanilla_on_a_noisy_synthetic_crowd():
    seq = generate_sequence(SyntheticConfig(noise_px=5, num_frames=3, seed=0))
    errors = {"vanilla": [], "mle_map": []}
    stages = {"vanilla": VanillaTriangulation(), "mle_map": MLEMAPReconstruction()}
    for frame in seq.frames:
        assignment = OracleMatcher()(frame.views, seq.rig).assignment
        poses2d, boxes = gather_views(frame.views, assignment)
        ids = [
            frame.views[v].person_ids[assignment[p, v]]
            for p, v in zip(range(len(assignment)), np.argmax(assignment >= 0, axis=1))
        ]
        gt = frame.gt_poses[[list(frame.gt_ids).index(i) for i in ids]]
        outs = {k: s(poses2d, boxes, seq.rig) for k, s in stages.items()}
        both = (outs["vanilla"][..., 3] > 0) & (outs["mle_map"][..., 3] > 0)
        for k, out in outs.items():
            errors[k].append(np.linalg.norm(out[..., :3] - gt[..., :3], axis=-1)[both])
    vanilla, ours = (np.mean(np.concatenate(errors[k])) for k in ("vanilla", "mle_map"))
    assert ours < 0.85 * vanilla, (vanilla, ours)


def test_outliers_of_a_solved_pose_are_reset_onto_their_ray_near_the_body():
    rig = _rig()
    X = _persons(2, walking=False)
    poses2d, _ = _observe(rig, X)
    und = rig.undistort(poses2d)
    proj = rig.projection_matrices()
    solved = X.copy()
    wrist = 9
    solved[0, wrist] += [3.0, -2.0, 0.5]  # an MLE joint that slid metres along nearly parallel rays
    out = reinitialise_outliers(solved, und, proj)
    assert np.linalg.norm(out[0, wrist] - X[0, wrist]) < 0.75  # back near the body ...
    x, y, z = proj[0] @ np.append(out[0, wrist], 1.0)
    np.testing.assert_allclose([x / z, y / z], und[0, 0, wrist, :2], atol=1e-6)  # ... on its best view's ray
    keep = np.ones(X.shape[:2], dtype=bool)
    keep[0, wrist] = False
    np.testing.assert_array_equal(out[keep], solved[keep])
    assert solved[0, wrist, 0] == X[0, wrist, 0] + 3.0  # the input is not modified


def test_mean_body_fit_is_the_scipy_kabsch_rotation_and_falls_back_to_yaw():
    from scipy.spatial.transform import Rotation

    from reconstruction.solver.pose_init import fit_mean_body

    rng = np.random.default_rng(5)
    mean = np.array(MEAN_POSE)  # a writable copy for scipy
    R_true = Rotation.from_euler("zyx", [40, 8, -5], degrees=True)
    pts = R_true.apply(mean) + [1.0, -2.0, 0.1] + rng.normal(0, 0.02, MEAN_POSE.shape)
    known = rng.random(23) < 0.7
    body, placed = fit_mean_body(pts[None], known[None])
    src, dst = mean[known] - mean[known].mean(0), pts[known] - pts[known].mean(0)
    R_ref, _ = Rotation.align_vectors(dst, src)
    np.testing.assert_allclose(body[0], R_ref.apply(mean - mean[known].mean(0)) + pts[known].mean(0), atol=1e-9)
    assert placed[0]
    few = np.zeros(23, dtype=bool)
    few[[15, 16]] = True  # two ankles: a rotation about z only
    body, placed = fit_mean_body(pts[None], few[None])
    assert placed[0] and np.allclose(body[0, 15:17, 2] - MEAN_POSE[15:17, 2], body[0, 15, 2] - MEAN_POSE[15, 2])
    _, placed = fit_mean_body(pts[None], np.zeros((1, 23), dtype=bool))
    assert not placed[0]


@pytest.mark.parametrize("robust", [0, 1, 2])  # none, huber, cauchy
def test_the_cost_alone_is_the_linearisations_cost_bit_for_bit(robust):
    # the solver computes a solve's last trial by _cost (_joint_terms without derivatives for one joint): it must be
    # the very number linearize (_joint_terms with them) gives, or the stopping decisions would differ
    from numba import njit

    @njit
    def costs(x, data, tau2, robust, C2, plan, lin, k, p):
        D, g, K, Kr = lin
        proj, uv, w, anchor = data[0], data[1], data[2], data[3]
        j = plan[0][k]
        X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
        point = pose_kernels._joint_terms(0.0, X0, X1, X2, p, j, proj, uv, w, anchor, tau2, robust, C2, False)
        terms = pose_kernels._joint_terms(0.0, X0, X1, X2, p, j, proj, uv, w, anchor, tau2, robust, C2, True)
        whole = [(pose_kernels._cost(x, c, p, data, tau2, robust, C2, plan), 0.0) for c in range(len(plan[1]) - 1)]
        for c in range(len(plan[1]) - 1):
            whole[c] = (whole[c][0], pose_kernels.linearize(x, c, p, data, tau2, robust, C2, plan, D, g, K, Kr))
        return point[0], terms[0], whole

    rng = np.random.default_rng(robust)
    rig = ring_rig(5, 5.0, 2.5)
    P, J, L = 3, len(MEAN_POSE), len(BONE_PAIRS)
    X = MEAN_POSE[None] + rng.normal(0, 0.3, (P, 1, 3)) + rng.normal(0, 0.05, (P, J, 3))
    uv = rig.project(X) + rng.normal(0, 4.0, (5, P, J, 2))
    w = np.where(rng.random((5, P, J)) < 0.3, 0.0, rng.uniform(0.05, 0.3, (5, P, J)))
    data = (
        rig.projection_matrices(),
        uv,
        w,
        X + 0.01,
        BONE_MEAN + rng.normal(0, 0.02, (P, L)),
        rng.uniform(1, 30, (P, L)),
    )
    plan = plan_arrays(solver_plan(J, tuple(map(tuple, BONE_PAIRS.tolist()))))
    lin = (np.empty((J, 3, 3)), np.empty((J, 3)), np.empty((L, 3, 3)), np.empty((L, 3, 3)))
    for p in range(P):
        x = (X[p] + rng.normal(0, 0.02, (J, 3)))[plan[0]]
        for k in range(J):
            point, terms, whole = costs(x, data, 1e-6, robust, 9.0, plan, lin, k, p)
            assert point == terms
        assert all(alone == full for alone, full in whole)


def _numpy_joint_sigma(poses2d, bboxes, c, sigma_min, sigma_px, score_power):
    """The sigma model in numpy, as joint_sigma computed it before its compiled pass (boxes with an area)."""
    score = poses2d[..., 2]
    seen = (score > 0) & np.isfinite(poses2d[..., 0]) & np.isfinite(poses2d[..., 1])
    size = np.sqrt(np.clip(bboxes[..., 2], 0, None) * np.clip(bboxes[..., 3], 0, None))
    spread = np.hypot(sigma_px, c * size)[..., None]
    return np.where(seen, np.maximum(sigma_min, spread / np.where(seen, score, 1.0) ** score_power), np.inf)


def test_the_compiled_sigma_and_observation_passes_equal_numpys_formulas():
    rng = np.random.default_rng(5)
    poses2d = np.concatenate([rng.uniform(-50, 2000, (4, 9, 23, 2)), rng.uniform(-0.2, 1.0, (4, 9, 23, 1))], axis=-1)
    odd = rng.random(poses2d.shape[:3]) < 0.15
    poses2d[odd, rng.integers(0, 3)] = rng.choice([np.nan, np.inf, -np.inf, 0.0], size=odd.sum())
    poses2d[0, 0, :, 2] = 1e-300  # tiny scores: sigmas overflow to inf
    bboxes = rng.uniform(1, 400, (4, 9, 4))
    for model in ((0.016, 1.0, 5.2, 1.27), (0.05, 30.0, 0.0, 1.0)):
        ours = me.joint_sigma(poses2d, bboxes, *model)
        with np.errstate(divide="ignore"):
            np.testing.assert_array_equal(ours, _numpy_joint_sigma(poses2d, bboxes, *model))
    spread = np.array([np.nan, 3.0])  # a NaN spread gives NaN sigmas, as np.maximum does
    points = np.ones((2, 1, 3))
    np.testing.assert_array_equal(sigmas_of_joints(points, spread, np.ones((2, 1)), 1.0), [[np.nan], [3.0]])
    stage = map_solver.MAPReconstruction()
    uv, inv_sigma = stage._observations(poses2d, bboxes)
    sigma = me.joint_sigma(poses2d, bboxes, stage.c, stage.sigma_min, stage.sigma_px, stage.score_power)
    np.testing.assert_array_equal(uv, np.nan_to_num(poses2d[..., :2]))
    np.testing.assert_array_equal(inv_sigma, np.where(np.isfinite(sigma), 1.0 / sigma, 0.0))
    assert np.isinf(sigma).any() and (inv_sigma == 0).any() and not np.isfinite(poses2d).all()
