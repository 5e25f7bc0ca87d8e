"""MLE / MAP reconstruction (paper Sec. 3.3): bone table, the compiled solver against scipy, the stages."""

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
from data.geometry.linalg import inverse_3x3
from data.geometry.triangulation import smallest_eigenvectors, triangulate_dlt
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.body import mean_body, pose_joints
from data.synthetic.observe import bbox_from_keypoints
from data.synthetic.rigs import ring_rig
from reconstruction.matching import OracleMatcher
from reconstruction.noise_model import NoiseModel
from reconstruction.pipeline import gather_views
from reconstruction.reconstructors import VanillaTriangulation
from reconstruction.solver import pose_kernels
from reconstruction.solver.compiled_solver import graph_components, solve_poses, solver_plan
from reconstruction.solver.map_solver import MAPReconstruction, MLEMAPReconstruction, MLEReconstruction
from reconstruction.solver.pose_init import initial_poses, reinitialise_outliers
from tests.oracles.pose_problem import cost, residual_vector

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


# --- the solver against scipy -------------------------------------------------------------------------
def _scipy_optimum(problem, X0: np.ndarray, loss: str = "linear") -> np.ndarray:
    out = []
    for p in range(len(X0)):
        one = problem.take(np.array([p]))
        fun = lambda x: residual_vector(x.reshape(1, -1, 3), one)[0]
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
    "prior,robust,bones",
    [(1.0, "none", "all"), (0.0, "none", "all"), (0.0, "huber", "all"), (1.0, "none", "arms")],
)
def test_the_solver_reaches_the_scipy_trf_optimum(prior, robust, bones):
    """The oracle's residuals, per-person scipy TRF with a numerical Jacobian, both tightly converged. Without the
    prior a joint seen in one view has its depth fixed only by the 1e-3 anchor (below scipy's tolerances): there
    only the costs are compared. bones "arms": the arm and left-foot bones (components among bone-free joints)."""
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
    ours, _ = solve_poses(problem, X0, max_iterations=300, xtol=1e-12, ftol=0.0)
    theirs = _scipy_optimum(problem, X0, "linear" if robust == "none" else robust)
    np.testing.assert_array_less(cost(ours, problem), cost(theirs, problem) * (1 + 1e-9) + 1e-9)
    determined = (poses2d[..., 2] > 0).sum(axis=0) >= np.where(boned & (prior > 0), 1, 2)
    assert determined.sum() > 50 and (~determined).sum() >= (0 if prior > 0 else 5)
    np.testing.assert_allclose(ours[determined], theirs[determined], atol=1e-4)


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
        lin = pose_kernels.Linearisation(D=D, g=g, K=K, Kr=np.zeros_like(K))
        ok = all(pose_kernels.solve_component(c, lin, 0.0, False, plan, B, h) for c in range(len(plan.comp_start) - 1))
        assert ok == definite[b]
        if ok:
            x = np.zeros((J, 3))
            x[pos] = h
            np.testing.assert_allclose(x.ravel(), np.linalg.solve(A[b], rhs[:, :, b].T.ravel()), atol=1e-10)


def test_bone_graph_splits_into_face_and_body():
    comps = graph_components(23, tuple(map(tuple, BONE_PAIRS.tolist())))
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
    dense = np.zeros((b, 3 * J, 3 * J))
    for j in range(J):
        dense[:, 3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = damped[:, :, j].transpose(2, 0, 1)
    for e, (i, j) in enumerate(edges):
        dense[:, 3 * i : 3 * i + 3, 3 * j : 3 * j + 3] = off[:, :, e].transpose(2, 0, 1)
        dense[:, 3 * j : 3 * j + 3, 3 * i : 3 * i + 3] = off[:, :, e].transpose(2, 1, 0)
    return diag, off, rhs, damping, dense


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
    out = STAGES[name](**kwargs)(poses2d, boxes, rig).poses
    assert out.shape == (3, 23, 4)
    np.testing.assert_allclose(out[..., :3], X, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 0.9)


def test_map_with_a_wrong_reference_is_biased_but_a_weak_or_adaptive_prior_is_not():
    rig, X = _rig(), _persons(3)
    poses2d, boxes = _observe(rig, X)
    table = _table(bone_lengths(X[0]) * 1.1)  # everyone 10 % taller than the table
    paper = dict(bone_table=table, bone_prior="population", noise_scale="model")
    biased = MAPReconstruction(**paper)(poses2d, boxes, rig).poses
    weak = MAPReconstruction(**paper, prior_weight=1e-4)(poses2d, boxes, rig).poses
    adaptive = MAPReconstruction(bone_table=table)(poses2d, boxes, rig).poses
    err = np.linalg.norm(biased[..., :3] - X, axis=-1)
    assert 1e-4 < err.mean() < 0.02
    np.testing.assert_allclose(weak[..., :3], X, atol=1e-5)
    np.testing.assert_allclose(adaptive[..., :3], X, atol=5e-4)  # exact 2D: the triangulated points (0.5 mm)


def test_map_moves_bone_lengths_towards_the_reference():
    rig, X = _rig(), _persons(4)
    poses2d, boxes = _observe(rig, X, noise_px=6.0, seed=3)
    ref = bone_lengths(X[0])
    table = _table(ref)
    mle = MLEReconstruction()(poses2d, boxes, rig).poses
    mapped = MAPReconstruction(bone_table=table)(poses2d, boxes, rig).poses
    dev = lambda out: np.mean(np.abs(bone_lengths(out) - ref))
    assert dev(mapped) < 0.7 * dev(mle)
    assert np.linalg.norm(mapped[..., :3] - X, axis=-1).mean() < np.linalg.norm(mle[..., :3] - X, axis=-1).mean()


def test_joints_seen_in_one_view_or_none_get_a_position_near_the_truth():
    rig, X = _rig(), _persons(2, walking=False)
    poses2d, boxes = _observe(rig, X, noise_px=1.0, seed=5)
    poses2d[1:, 0, 9] = 0.0  # person 0's left wrist: only view 0
    poses2d[:, 0, 7] = 0.0  # person 0's left elbow: no view
    poses2d[:, 1, 18] = 0.0  # person 1's left small toe: no view
    vanilla = VanillaTriangulation()(poses2d, boxes, rig).poses
    assert vanilla[0, 9, 3] == 0 and vanilla[0, 7, 3] == 0
    for stage in (MAPReconstruction(), MLEMAPReconstruction()):
        out = stage(poses2d, boxes, rig).poses
        assert np.all(np.isfinite(out))
        err = np.linalg.norm(out[..., :3] - X, axis=-1)
        assert err[0, 9] < 0.10 and err[0, 7] < 0.10 and err[1, 18] < 0.10
        np.testing.assert_allclose(out[0, 9, 3], 0.5 * 0.9)
        assert out[0, 7, 3] == pytest.approx(0.1) and out[1, 18, 3] == pytest.approx(0.1)
    mle = MLEReconstruction()(poses2d, boxes, rig).poses
    assert mle[0, 9, 3] == 0 and mle[0, 7, 3] == 0 and np.all(mle[0, 7, :3] == 0)


def test_stages_take_no_person_and_do_not_touch_their_input():
    rig = _rig()
    empty = MLEMAPReconstruction()(np.zeros((5, 0, 23, 3)), np.zeros((5, 0, 4)), rig)
    assert empty.poses.shape == (0, 23, 4) and empty.joint_variance.shape == (0, 23)
    poses2d, boxes = _observe(rig, _persons(2), noise_px=3.0)
    before = poses2d.copy(), boxes.copy()
    MLEMAPReconstruction(robust="cauchy")(poses2d, boxes, rig)
    np.testing.assert_array_equal(poses2d, before[0])
    np.testing.assert_array_equal(boxes, before[1])
    with pytest.raises(ValueError, match="robust"):
        MAPReconstruction(robust="l1")


def test_configs_instantiate_the_stages_with_the_configured_noise_model():
    from pathlib import Path

    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from reconstruction.noise_calibration import CalibratedNoiseModel

    stages = {"mle": MLEReconstruction, "map": MAPReconstruction, "mle_map": MLEMAPReconstruction, "paper": None}
    with initialize_config_dir(str(Path("configs").resolve()), version_base=None):
        for name, cls in stages.items():
            stage = instantiate(compose("eval", overrides=[f"reconstruction={name}"]).reconstruction)
            assert type(stage) is (cls or MLEMAPReconstruction)
            calibrated = CalibratedNoiseModel(start=NoiseModel())  # configs/noise_model/calibrated.yaml
            assert stage.noise_model == (NoiseModel(0.02, 0.0, 1.0) if name == "paper" else calibrated)
            assert stage.prior_weight == (0.0 if name == "mle" else 1.0)


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
        outs = {k: s(poses2d, boxes, seq.rig).poses for k, s in stages.items()}
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
    # the solver computes a solve's last trial by cost_only (_joint_terms without derivatives for one joint): it must
    # be the very number linearize (_joint_terms with them) gives, or the stopping decisions would differ
    from numba import njit

    @njit
    def costs(x, prob, plan, lin, k, p):
        X0, X1, X2 = x[k, 0], x[k, 1], x[k, 2]
        point = pose_kernels._joint_terms(0.0, X0, X1, X2, p, plan.pos_joint[k], prob, False)
        terms = pose_kernels._joint_terms(0.0, X0, X1, X2, p, plan.pos_joint[k], prob, True)
        C = len(plan.comp_start) - 1
        whole = [(pose_kernels.cost_only(x, c, p, prob, plan), 0.0) for c in range(C)]
        for c in range(C):
            whole[c] = (whole[c][0], pose_kernels.linearize(x, c, p, prob, plan, lin))
        return point[0], terms[0], whole

    rng = np.random.default_rng(robust)
    rig = ring_rig(5, 5.0, 2.5)
    P, J, L = 3, len(MEAN_POSE), len(BONE_PAIRS)
    X = MEAN_POSE[None] + rng.normal(0, 0.3, (P, 1, 3)) + rng.normal(0, 0.05, (P, J, 3))
    prob = pose_kernels.Problem(
        proj=rig.projection_matrices(),
        uv=rig.project(X) + rng.normal(0, 4.0, (5, P, J, 2)),
        w=np.where(rng.random((5, P, J)) < 0.3, 0.0, rng.uniform(0.05, 0.3, (5, P, J))),
        anchor=X + 0.01,
        ref=BONE_MEAN + rng.normal(0, 0.02, (P, L)),
        bw=rng.uniform(1, 30, (P, L)),
        tau2=1e-6,
        robust=robust,
        C2=9.0,
    )
    plan = solver_plan(J, tuple(map(tuple, BONE_PAIRS.tolist())))
    lin = pose_kernels.Linearisation(np.empty((J, 3, 3)), np.empty((J, 3)), np.empty((L, 3, 3)), np.empty((L, 3, 3)))
    for p in range(P):
        x = (X[p] + rng.normal(0, 0.02, (J, 3)))[plan.pos_joint]
        for k in range(J):
            point, terms, whole = costs(x, prob, plan, lin, k, p)
            assert point == terms
        assert all(alone == full for alone, full in whole)


def test_observations_are_the_finite_pixels_and_inverse_sigmas_of_the_noise_model():
    poses2d = np.array([[[[10.0, 20.0, 1.0], [np.nan, 5.0, 0.9], [np.inf, 3.0, 0.8], [7.0, 8.0, 0.0]]]])
    bboxes = np.array([[[0.0, 0.0, 100.0, 100.0]]])
    uv, inv_sigma = MAPReconstruction(noise_model=NoiseModel())._observations(poses2d, bboxes)
    big = np.finfo(np.float64).max
    np.testing.assert_array_equal(uv[0, 0], [[10.0, 20.0], [0.0, 5.0], [big, 3.0], [7.0, 8.0]])
    # score 1: sigma = hypot(5.2 px, 0.016 x 100 px); a non-finite pixel or score 0: not observed
    np.testing.assert_allclose(inv_sigma[0, 0], [1 / np.hypot(5.2, 1.6), 0.0, 0.0, 0.0])
