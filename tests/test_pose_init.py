"""The compiled initial poses (pose_init) against the plain-numpy oracle in tests/oracles/pose_init.py."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from data.bone_lengths import MEAN_POSE
from data.geometry.triangulation import triangulate_dlt
from reconstruction.solver.pose_init import fit_mean_body, initial_poses, reinitialise_outliers
from tests.oracles import pose_init as ref
from tests.test_map_reconstruction import _observe, _persons, _rig


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Four persons in five views with missing and one-view joints, DLT outliers of every kind, a person without
    any triangulated joint: -> DLT (P, J, 4), undistorted poses2d (V, P, J, 3), proj (V, 3, 4), world X (P, J, 3)."""
    rng = np.random.default_rng(seed)
    rig, X = _rig(5), _persons(4)
    poses2d, _ = _observe(rig, X, noise_px=3.0, seed=seed)
    one_view = rng.random(X.shape[:2]) < 0.2
    keep = rng.integers(0, 5, X.shape[:2])
    poses2d[..., 2] *= np.where(one_view[None], np.arange(5)[:, None, None] == keep[None], 1.0)
    poses2d[rng.random(poses2d.shape[:-1]) < 0.15] = 0.0
    poses2d[1, 2, 4, :2] = np.nan  # a non-finite detection: no score
    und, proj = rig.undistort(poses2d), rig.projection_matrices()
    dlt = triangulate_dlt(und, proj)
    dlt[0, 9, :3] += [3.0, -2.0, 0.5]  # gross outlier
    dlt[1, 3, :3] += [0.0, 1.0, 0.0]  # beyond OUTLIER_M of the fitted body only
    centre = -np.linalg.inv(proj[0, :, :3]) @ proj[0, :, 3]
    dlt[2, 5, :3] = 2 * centre - dlt[2, 5, :3]  # behind camera 0
    dlt[2, 5, 3] = 1.0
    dlt[3, :, 3] = 0.0  # nothing triangulated
    return dlt, und, proj, X


@pytest.mark.parametrize("seed", range(4))
def test_initial_and_reinitialised_poses_match_the_numpy_reference(seed):
    dlt, und, proj, X = _scene(seed)
    start, placed = initial_poses(dlt, und, proj)
    want, want_placed = ref.start(dlt[..., :3], dlt[..., 3] > 0, und, proj)
    np.testing.assert_allclose(start, want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(placed, want_placed)
    assert placed[:3].all() and not placed[3]
    assert np.linalg.norm(start[0, 9] - X[0, 9]) < 0.75  # the outliers are reset near the body
    solved = X + np.random.default_rng(seed).normal(0, 0.02, X.shape)
    solved[1, 7] += [0.0, 0.0, 2.0]
    seen = np.any(und[..., 2] > 0, axis=0)
    np.testing.assert_allclose(
        reinitialise_outliers(solved, und, proj), ref.start(solved, seen, und, proj)[0], rtol=0, atol=1e-9
    )


def _point_sets(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """(points (J, 3), known (J,)) of every kind the Kabsch fit meets: rigid + noise, non-rigid (reflections),
    few joints (yaw), none, collinear (rank 1), coplanar (rank 2), all in one point."""
    J = len(MEAN_POSE)
    sets = []
    for _ in range(40):
        R = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        rigid = MEAN_POSE @ R.T + rng.normal(0, 3, 3) + rng.normal(0, 0.05, (J, 3))
        sets.append((rigid, rng.random(J) < rng.uniform(0.1, 1.0)))
        sets.append((rng.normal(0, 1, (J, 3)), rng.random(J) < 0.8))
    line = np.outer(rng.normal(0, 1, J), rng.normal(0, 1, 3)) + rng.normal(0, 1, 3)
    plane = np.concatenate([rng.normal(0, 1, (J, 2)), np.full((J, 1), 0.7)], axis=1)
    everything = np.ones(J, dtype=bool)
    sets += [(line, everything), (plane, everything), (np.ones((J, 3)), everything), (line, ~everything)]
    sets.append((MEAN_POSE + 1.0, everything))  # the template itself, translated: S exactly that of the template
    return sets


def test_mean_body_fit_matches_lapack_kabsch_on_random_and_degenerate_sets():
    sets = _point_sets(np.random.default_rng(11))
    points, known = np.stack([s[0] for s in sets]), np.stack([s[1] for s in sets])
    body, placed = fit_mean_body(points, known)
    for p in range(len(sets)):
        want, want_placed = ref.fit_one(points[p], known[p], MEAN_POSE)
        np.testing.assert_allclose(body[p], want, rtol=0, atol=1e-9, err_msg=str(p))
        assert placed[p] == want_placed


def test_one_compiled_specialisation_for_readonly_strided_and_float32_inputs():
    from reconstruction.solver import pose_init

    dlt, und, proj, _ = _scene(0)
    initial_poses(dlt, und, proj)
    frozen = proj.copy()
    frozen.flags.writeable = False
    strided = np.asfortranarray(dlt)[:, :, :]
    initial_poses(strided, und.astype(np.float32), frozen)
    reinitialise_outliers(strided[..., :3], und, frozen)
    fit_mean_body(dlt[..., :3].astype(np.float32), dlt[..., 3] > 0)
    assert len(pose_init._start_kernel.signatures) == 1 and len(pose_init._fit_one.signatures) == 1


def test_scattered_joints_match_the_reference_at_every_outlier_threshold():
    """Joints strewn up to ~2 m about the mean body (even and odd counts known): the median, the gross and the
    fitted-body thresholds all decide, person by person."""
    rng = np.random.default_rng(3)
    rig = _rig(5)
    P, J = 300, len(MEAN_POSE)
    points = MEAN_POSE + rng.normal(0, 1.5, (P, 1, 3)) * [1, 1, 0] + rng.uniform(-1.3, 1.3, (P, J, 3))
    known = rng.random((P, J)) < rng.uniform(0.2, 1.0, (P, 1))
    poses2d = np.concatenate([rig.project(points), rng.uniform(0, 1, (5, P, J, 1))], axis=-1)
    poses2d[rng.random((5, P, J)) < 0.3] = 0.0
    proj = rig.projection_matrices()
    dlt = np.concatenate([points, known[..., None].astype(float)], axis=-1)
    start, placed = initial_poses(dlt, poses2d, proj)
    want, want_placed = ref.start(points, known, poses2d, proj)
    np.testing.assert_allclose(start, want, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(placed, want_placed)
