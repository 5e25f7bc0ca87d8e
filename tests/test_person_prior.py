"""What the MAP learns per person before its prior: noise scale, own bone lengths; left / right swaps undone."""

import numpy as np
import pytest
from scipy.stats import chi2

from data.bone_lengths import ABSOLUTE_SD_M, BONE_MEAN, BONE_NAMES, BONE_PAIRS, BONE_STD, bone_lengths
from data.geometry.linalg import inverse_3x3
from data.keypoints import shelf15_validity
from data.synthetic.body import mean_body, pose_joints
from data.synthetic.observe import bbox_from_keypoints
from data.synthetic.rigs import ring_rig
from evaluation.pcp import pcp_by_part
from evaluation.pose3d import Pose3DEvaluator
from reconstruction.noise_model import NoiseModel
from reconstruction.solver.map_solver import MAPReconstruction, MLEReconstruction, mean_variances
from reconstruction.solver.person_prior import (
    OUTLIER_SD,
    PROPORTION_SD,
    STATURE_SD,
    bone_groups,
    bone_variances,
    chi2_medians,
    joint_information,
    noise_scale,
    person_bone_lengths,
    project,
    proportion_sds,
)
from reconstruction.solver.side_swaps import apply_swaps, find_swaps


def _scaled_body(scale: float, x: float = 0.0, y: float = 0.0) -> np.ndarray:
    """The mean body scaled about its feet: (23, 3)."""
    pose = pose_joints(mean_body(), 0.0, 0.0, 0.4, 0.2, True)
    return pose * scale + np.array([x, y, 0.0])


def _observe(rig, X, noise_px: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    uv = rig.project(X) + rng.normal(0.0, noise_px, (len(rig),) + X.shape[:2] + (2,))
    poses2d = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
    return poses2d, np.stack([bbox_from_keypoints(p, cam.size) for p, cam in zip(poses2d, rig)])


def _joint_information_numpy(X: np.ndarray, proj: np.ndarray, inv_sigma: np.ndarray) -> np.ndarray:
    """The numpy formula the compiled joint_information replaced: (P, J, 3), (V, 3, 4), (V, P, J) -> (P, J, 3, 3)."""
    xy, z = project(X, proj)
    M = proj[:, :, :3]
    info = np.zeros(X.shape[:2] + (3, 3))
    for k in range(2):
        rows = (M[:, None, None, k, :] - xy[..., k, None] * M[:, None, None, 2, :]) * (inv_sigma / z)[..., None]
        info += np.sum(rows[..., :, None] * rows[..., None, :], axis=0)
    return info


def test_joint_information_is_the_numpy_formula_and_the_jacobian_product():
    rig = ring_rig(5, 7.0, 2.5)
    X = np.stack([_scaled_body(1.0, 0.3 * p, -0.2 * p) for p in range(4)])
    inv_sigma = np.random.default_rng(1).uniform(0.05, 0.5, (5, 4, 23)) * (np.arange(5 * 4 * 23) % 7 > 0).reshape(
        5, 4, 23
    )
    proj = rig.projection_matrices()
    info = joint_information(X, proj, inv_sigma)
    np.testing.assert_array_equal(info, _joint_information_numpy(X, proj, inv_sigma))  # same arithmetic
    eps, p, j = 1e-6, 2, 11  # J^T J of the weighted projection of one joint, by central differences
    jac = (
        np.stack(
            [
                (project(X + eps * d, proj)[0] - project(X - eps * d, proj)[0])[:, p, j] / (2 * eps)
                for d in _unit_moves(X, p, j)
            ],
            axis=-1,
        )
        * inv_sigma[:, p, j, None, None]
    )
    np.testing.assert_allclose(info[p, j], np.einsum("vka,vkb->ab", jac, jac), rtol=1e-5)


def _bone_variances_numpy(X: np.ndarray, info: np.ndarray, pairs: np.ndarray, measured: np.ndarray) -> tuple:
    """The numpy formula the compiled bone_variances replaced: (P, J, 3), (P, J, 3, 3), (L, 2), (P, J) -> (P, L) x2."""
    a, b = pairs[:, 0], pairs[:, 1]
    d = X[:, a] - X[:, b]
    n = np.linalg.norm(d, axis=-1)
    u = d / np.maximum(n, 1e-12)[..., None]
    info = np.nan_to_num(info)
    inv, _ = inverse_3x3(np.moveaxis(info, (-2, -1), (0, 1)), check=False)
    trace = np.trace(info, axis1=-2, axis2=-1)
    good = measured & (np.linalg.det(info) > 1e-9 * (trace / 3) ** 3) & (trace > 0)
    cov = np.where(good[..., None, None], np.moveaxis(inv, (0, 1), (-2, -1)), 0.0)
    var = np.sum(u[..., :, None] * (cov[:, a] + cov[:, b]) * u[..., None, :], axis=(-2, -1))
    return n, np.where(good[:, a] & good[:, b], var, np.inf)


def test_bone_variances_are_the_numpy_formula():
    rig = ring_rig(5, 7.0, 2.5)
    X = np.stack([_scaled_body(1.0 + 0.05 * p, 0.3 * p, -0.2 * p) for p in range(6)])
    rng = np.random.default_rng(4)
    inv_sigma = rng.uniform(0.05, 0.5, (5, 6, 23)) * (rng.uniform(size=(5, 6, 23)) > 0.3)
    info = joint_information(X, rig.projection_matrices(), inv_sigma)
    info[0, 3] = np.nan  # unusable information, a singular one (a joint on one ray), an unmeasured joint
    info[1, 5] = np.outer([1.0, 2.0, 0.5], [1.0, 2.0, 0.5])
    measured = (inv_sigma > 0).sum(axis=0) >= 2
    measured[2, 7] = False
    pairs = np.asarray(BONE_PAIRS)
    n, var = bone_variances(X, info, pairs, measured)
    n_ref, var_ref = _bone_variances_numpy(X, info, pairs, measured)
    np.testing.assert_array_equal(n, n_ref)
    np.testing.assert_array_equal(var, var_ref)  # same arithmetic, same order
    assert np.isinf(var).any() and np.isfinite(var).any()


def _unit_moves(X: np.ndarray, p: int, j: int) -> list[np.ndarray]:
    """The three unit moves of joint j of person p, as arrays shaped like X."""
    moves = []
    for a in range(3):
        d = np.zeros_like(X)
        d[p, j, a] = 1.0
        moves.append(d)
    return moves


def test_bone_groups_pair_left_and_right():
    groups = bone_groups()
    for name, g in zip(BONE_NAMES, groups):
        if name.startswith("left_"):
            assert groups[BONE_NAMES.index("right_" + name[5:])] == g
    assert len(set(groups)) == 13


def test_proportion_sds_are_what_the_table_leaves_after_stature_and_placement():
    prop = proportion_sds(BONE_MEAN, BONE_STD, ABSOLUTE_SD_M)
    np.testing.assert_allclose(prop, np.sqrt(0.057**2 - 0.053**2), rtol=1e-6)
    assert abs(prop[0] - PROPORTION_SD) < 0.002


def test_the_hierarchical_prior_recovers_a_body_15_percent_larger_than_the_table():
    # noise-free views: the MAP keeps the person's own bones (within 5 mm); the population prior does not
    rig = ring_rig(5, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = _scaled_body(1.15)[None]
    poses2d, boxes = _observe(rig, X, 0.0)
    own = bone_lengths(X)[0]
    adaptive = MAPReconstruction()(poses2d, boxes, rig).poses
    assert np.max(np.abs(bone_lengths(adaptive[..., :3])[0] - own)) < 0.005
    # 3 px of noise, the person's lengths estimated from the MLE: closer to their own than the table is
    noisy, boxes = _observe(rig, X, 3.0, seed=1)
    mle = MLEReconstruction()(noisy, boxes, rig).poses[..., :3]
    lengths = bone_lengths(mle)
    mean, sd = person_bone_lengths(
        lengths,
        np.full_like(lengths, 0.005**2),
        BONE_MEAN,
        proportion_sds(BONE_MEAN, BONE_STD, ABSOLUTE_SD_M),
        0.01,
        bone_groups(),
    )
    assert np.mean(np.abs(mean[0] - own)) < 0.005 < np.mean(np.abs(BONE_MEAN - own))
    assert np.all(sd[0] < BONE_STD)
    paper = MAPReconstruction(bone_prior="population", noise_scale="model")(noisy, boxes, rig).poses
    ours = MAPReconstruction()(noisy, boxes, rig).poses
    err = lambda out: np.mean(np.abs(bone_lengths(out[..., :3])[0] - own))  # noqa: E731
    assert err(ours) < err(paper)


def test_unmeasured_bones_follow_the_stature_of_the_measured_ones():
    own = BONE_MEAN * 1.1
    lengths = own[None].copy()
    variances = np.full_like(lengths, 1e-6)
    variances[0, BONE_NAMES.index("left_forearm")] = np.inf  # not measured
    variances[0, BONE_NAMES.index("right_forearm")] = np.inf
    mean, _ = person_bone_lengths(lengths, variances, BONE_MEAN, np.full(24, 0.02), 0.01, bone_groups())
    k = BONE_NAMES.index("left_forearm")
    assert abs(mean[0, k] - own[k]) < 0.4 * abs(BONE_MEAN[k] - own[k])


def _dense_bone_posterior(lengths, variances, ref, proportion_sd, tie_sd, groups, stature_sd=STATURE_SD):
    """The posterior of person_bone_lengths by a dense (1 + G) x (1 + G) inverse per person (the reference)."""
    L, G = len(ref), int(groups.max()) + 1
    A = np.zeros((L, 1 + G))
    A[:, 0], A[np.arange(L), 1 + groups] = ref * stature_sd, ref * proportion_sd
    use = np.isfinite(variances) & np.isfinite(lengths)
    for _ in range(2):
        noise = np.where(use, variances, 0.0) + tie_sd**2
        w = np.where(use, 1.0 / noise, 0.0)
        cov = np.linalg.inv(np.eye(1 + G) + np.einsum("pl,lg,lh->pgh", w, A, A))
        theta = np.einsum("pgh,ph->pg", cov, (w * np.where(use, lengths - ref, 0.0)) @ A)
        mean, var = ref + theta @ A.T, np.einsum("lg,pgh,lh->pl", A, cov, A)
        outlier = use & (np.abs(np.where(use, lengths, mean) - mean) / np.sqrt(noise + var) > OUTLIER_SD)
        if not outlier.any():
            break
        use &= ~outlier
    return mean, np.sqrt(var)


def test_the_arrowhead_posterior_equals_the_dense_inverse():
    # random people, unmeasured bones (inf / NaN) and outlying measurements (the second pass) included
    rng = np.random.default_rng(3)
    P, groups, sds = 40, bone_groups(), proportion_sds(BONE_MEAN, BONE_STD, ABSOLUTE_SD_M)
    lengths = BONE_MEAN * rng.normal(1.0, 0.08, (P, 1)) + rng.normal(0, 0.01, (P, len(BONE_MEAN)))
    variances = rng.uniform(1e-6, 4e-4, lengths.shape)
    variances[rng.random(lengths.shape) < 0.2] = np.inf
    lengths[rng.random(lengths.shape) < 0.05] = np.nan
    lengths[rng.random(lengths.shape) < 0.05] *= 1.6  # outliers
    mean, sd = person_bone_lengths(lengths, variances, BONE_MEAN, sds, 0.01, groups)
    ref_mean, ref_sd = _dense_bone_posterior(lengths, variances, BONE_MEAN, sds, 0.01, groups)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-12)
    np.testing.assert_allclose(sd, ref_sd, rtol=1e-9)
    assert np.any(np.abs(lengths - mean) > 0.1)  # outlying measurements were there to drop


def test_noise_scale_recovers_the_true_noise_over_the_model():
    rng = np.random.default_rng(0)
    rig = ring_rig(5, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = np.stack([_scaled_body(1.0, -1.0, 0.5), _scaled_body(1.0, 1.0, -0.5)])
    proj = rig.projection_matrices()
    for true in (0.5, 2.0):
        uv = rig.project(X) + rng.normal(0.0, 3.0 * true, (5, 2, 23, 2))
        poses2d = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
        stage = MLEReconstruction(noise_model=NoiseModel(c=0.0, sigma_px=3.0, score_power=0.0))
        mle = stage(poses2d, np.zeros((5, 2, 4)), rig).poses[..., :3]
        s = noise_scale(mle, uv, np.full((5, 2, 23), 1 / 3.0), proj)
        np.testing.assert_allclose(s, true, rtol=0.25)
    assert chi2.median(1) < 1


def _numpy_noise_scale(X, uv, inv_sigma, proj, floor):
    """The reference: median over joints seen in n >= 2 views of RSS / scipy's chi^2(2n - 3) median, by np.median."""
    hom = np.einsum("vab,pjb->vpja", proj[:, :, :3], X) + proj[:, None, None, :, 3]
    xy = hom[..., :2] / np.maximum(hom[..., 2:], 1e-6)
    seen = inv_sigma > 0
    r2 = np.where(seen, ((uv - xy) ** 2).sum(axis=-1) * inv_sigma**2, 0.0)
    views = seen.sum(axis=0)
    out = np.ones(len(X))
    for p in range(len(X)):
        ok = views[p] >= 2
        if ok.any():
            out[p] = np.sqrt(np.median(r2.sum(axis=0)[p, ok] / chi2.median(2 * views[p, ok] - 3)))
    return np.maximum(out, floor)


def test_noise_scale_equals_the_numpy_median_formula():
    rng = np.random.default_rng(3)
    rig = ring_rig(4, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = np.stack([_scaled_body(1.0, -1.0, 0.5), _scaled_body(1.1, 1.0, -0.5), _scaled_body(0.9)])
    proj = rig.projection_matrices()
    uv = rig.project(X) + rng.normal(0.0, 4.0, (4, 3, 23, 2))
    inv_sigma = rng.uniform(0.1, 0.5, (4, 3, 23)) * (rng.random((4, 3, 23)) > 0.3)
    inv_sigma[:, 2, 5:] = 0.0  # person 2: 5 joints at most (odd and even counts across persons)
    inv_sigma[1:, 2, :5] = 0.0  # ... each in one view only: no joint in >= 2 views, scale 1
    expected = _numpy_noise_scale(X, uv, inv_sigma, proj, 0.01)
    assert expected[2] == 1.0
    np.testing.assert_allclose(noise_scale(X, uv, inv_sigma, proj, 0.01), expected, rtol=1e-12)


def test_a_left_right_swap_in_one_view_is_found_and_undone():
    rig = ring_rig(4, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = _scaled_body(1.0)[None]
    poses2d, boxes = _observe(rig, X, 1.0)
    swapped = apply_swaps(poses2d, [(2, 0, 9, 10)])  # wrists exchanged in view 2
    assert not np.shares_memory(swapped, poses2d)
    fixed = MAPReconstruction()(swapped, boxes, rig).poses
    broken = MAPReconstruction(fix_swaps=False)(swapped, boxes, rig).poses
    err = lambda out: np.linalg.norm(out[0, [9, 10], :3] - X[0, [9, 10]], axis=-1).max()  # noqa: E731
    assert err(fixed) < 0.01 < err(broken)
    proj = rig.projection_matrices()
    assert find_swaps(swapped, np.ones((4, 1, 23)), proj) == [(2, 0, 9, 10)]
    assert find_swaps(poses2d, np.ones((4, 1, 23)), proj) == []


def test_pcp_counts_only_parts_whose_ground_truth_is_annotated():
    valid = np.ones((1, 23), dtype=bool)
    valid[0, 3] = False  # an ear: the head joints are unknown
    v15 = shelf15_validity(valid)
    assert not v15[0, 12] and not v15[0, 13] and v15[0, :12].all() and v15[0, 14]
    ev = Pose3DEvaluator()
    gt = np.concatenate([_scaled_body(1.0), np.ones((23, 1))], axis=1)[None]
    gt[0, 3] = 0.0
    pred = gt.copy()
    pred[0, 3] = [0.1, 0.1, 1.6, 1.0]  # an ear placed where the GT has none
    ev.update(pred, gt)
    assert ev.summary()["pcp_average"] == 100.0
    assert np.isnan(pcp_by_part(np.zeros((1, 10), bool), np.zeros((1, 10), bool))["average"])


def test_rejects_bad_settings():
    for bad in ({"sigma_px": -1.0}, {"c": 0.0, "sigma_px": 0.0, "sigma_min": 0.0}):
        with pytest.raises(ValueError, match="noise_model"):
            NoiseModel(**bad)
    for bad in (
        {"bone_prior": "x"},
        {"noise_scale": "x"},
        {"bone_tie_sd_m": 0.0},
        {"min_noise_scale": 0.0},
        {"robust_scale": 0.0},
        {"prior_weight": -1.0},
        {"noise_model": {"c": 0.02}},
    ):
        with pytest.raises(ValueError):
            MAPReconstruction(**bad)


def test_chi2_medians_are_scipy_chi2_medians() -> None:
    dof = np.arange(1, 64)
    np.testing.assert_array_equal(chi2_medians(dof), chi2.median(dof))


def test_mean_variances_equal_the_trace_of_inverse_3x3():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(4, 23, 3, 5))
    info = B @ np.swapaxes(B, -1, -2)
    info[:, :3] = 0.0  # singular where no tie: inf / NaN as the full inverse gives
    tie = np.where(rng.random((4, 23)) > 0.5, 1111.1, 0.0)
    inv, _ = inverse_3x3(np.moveaxis(info + tie[..., None, None] * np.eye(3), (-2, -1), (0, 1)), check=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        got = mean_variances(info, tie)
    np.testing.assert_array_equal(got, np.trace(inv, axis1=0, axis2=1) / 3)
