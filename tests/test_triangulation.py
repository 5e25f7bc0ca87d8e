import cv2
import numpy as np
import pytest

from data.geometry.camera import Rig
from data.geometry.triangulation import reprojection_error, triangulate_dlt
from data.synthetic.rigs import ring_rig


def ring(num: int, radius: float = 6.0, height: float = 2.5) -> Rig:
    return ring_rig(num, radius, height, look_at=(0.0, 0.0, 1.0))


def observe(rig: Rig, X: np.ndarray) -> np.ndarray:
    uv = rig.project(X)  # (V, P, J, 2)
    return np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)


def test_noise_free_points_are_recovered_to_a_micrometre():
    rng = np.random.default_rng(0)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], size=(7, 23, 3))
    rig = ring(5)
    out = triangulate_dlt(observe(rig, X), rig.projection_matrices())
    assert out.shape == (7, 23, 4)
    np.testing.assert_allclose(out[..., :3], X, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 1.0)


def test_two_views_match_cv2_triangulate_points():
    rng = np.random.default_rng(1)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], size=(1, 50, 3))
    rig = ring(2)
    obs = observe(rig, X) + np.concatenate([rng.normal(0, 2.0, (2, 1, 50, 2)), np.zeros((2, 1, 50, 1))], -1)
    ours = triangulate_dlt(obs, rig.projection_matrices())[0, :, :3]
    P0, P1 = rig.projection_matrices()
    h = cv2.triangulatePoints(P0, P1, obs[0, 0, :, :2].T.copy(), obs[1, 0, :, :2].T.copy())
    theirs = (h[:3] / h[3]).T
    # with noise the two algebraic solutions differ (we normalise the rows); neither may be worse
    err_ours = np.linalg.norm(ours - X[0], axis=-1).mean()
    err_cv2 = np.linalg.norm(theirs - X[0], axis=-1).mean()
    assert err_ours <= 1.05 * err_cv2
    rig_exact = observe(rig, X)
    h = cv2.triangulatePoints(P0, P1, rig_exact[0, 0, :, :2].T.copy(), rig_exact[1, 0, :, :2].T.copy())
    np.testing.assert_allclose(
        triangulate_dlt(rig_exact, rig.projection_matrices())[0, :, :3], (h[:3] / h[3]).T, atol=1e-6
    )


def test_joint_seen_in_one_view_gets_score_zero():
    rig = ring(3)
    X = np.array([[[0.0, 0.0, 1.0], [0.5, 0.2, 1.5]]])
    obs = observe(rig, X)
    obs[1:, 0, 1, 2] = 0.0  # joint 1 only in view 0
    out = triangulate_dlt(obs, rig.projection_matrices())
    assert out[0, 1, 3] == 0 and np.all(out[0, 1, :3] == 0)
    np.testing.assert_allclose(out[0, 0, :3], X[0, 0], atol=1e-6)


def test_scores_weight_the_views():
    rig = ring(4)
    X = np.array([[[0.3, -0.2, 1.2]]])
    obs = observe(rig, X)
    obs[0, 0, 0, :2] += 40.0  # an outlier in view 0
    low = obs.copy()
    low[0, 0, 0, 2] = 0.05
    err_high = np.linalg.norm(triangulate_dlt(obs, rig.projection_matrices())[0, 0, :3] - X[0, 0])
    err_low = np.linalg.norm(triangulate_dlt(low, rig.projection_matrices())[0, 0, :3] - X[0, 0])
    assert err_low < 0.25 * err_high
    np.testing.assert_allclose(triangulate_dlt(low, rig.projection_matrices())[0, 0, 3], (0.05 + 3) / 4)


def test_reprojection_error_is_zero_on_exact_data_and_nan_where_unseen():
    rig = ring(3)
    X = np.random.default_rng(2).uniform(-1, 1, (2, 23, 3)) + [0, 0, 1]
    obs = observe(rig, X)
    obs[2, 1, 5, 2] = 0
    out = triangulate_dlt(obs, rig.projection_matrices())
    err = reprojection_error(out, obs, rig.projection_matrices())
    assert np.isnan(err[2, 1, 5]) and np.nanmax(err) < 1e-6


def test_bad_projection_shape_is_an_error():
    with pytest.raises(ValueError, match="expected"):
        triangulate_dlt(np.zeros((3, 1, 23, 3)), np.zeros((2, 3, 4)))


def test_rayleigh_quotient_certifies_nearly_every_noisy_dlt_point():
    """The compiled Rayleigh quotient iteration, not LAPACK, solves the DLT of noisy detections: its steps go on once
    the Schur complement of N - rho I vanishes (rho converged), so its certificate (the eigenvector to 1e-10)
    holds for nearly every point; where it holds the eigenvector is LAPACK's."""
    from data.geometry.triangulation import RQI_ITERATIONS, RQI_TOLERANCE, _normal_matrices, _rayleigh_quotient

    rng = np.random.default_rng(7)
    rig = ring(7, radius=12.0)
    X = rng.uniform([-4, -4, 0], [4, 4, 2], size=(1, 2000, 3))
    obs = observe(rig, X)
    obs[..., :2] += rng.normal(0, 3.0, obs[..., :2].shape)
    obs[..., 2] = rng.uniform(0.3, 1.0, obs[..., 2].shape)
    poses = np.ascontiguousarray(obs.reshape(7, 2000, 3))
    N, conf, solve = np.empty((2000, 4, 4)), np.empty(2000), np.empty(2000, dtype=bool)
    _normal_matrices(poses, np.ascontiguousarray(rig.projection_matrices()), 2, N, conf, solve)
    v, ok = np.empty((2000, 4)), np.empty(2000, dtype=bool)
    _rayleigh_quotient(N, RQI_ITERATIONS, RQI_TOLERANCE, np.ones(2000, dtype=bool), v, ok)
    assert ok.mean() > 0.99  # 0.82 when a converged rho stopped the steps (the Schur complement divided by 0)
    ref = np.linalg.eigh(N)[1][..., 0]
    sine = np.sqrt(np.maximum(1 - np.abs((v * ref).sum(axis=1)) ** 2, 0.0))
    assert np.all(sine[ok] < 1e-7)  # 1e-10 is below what this difference of two rounded vectors can show
