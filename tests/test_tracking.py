"""The online tracker (tracking/tracker.py) and its identity metrics (evaluation/identity.py)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from data.bone_lengths import BONE_PAIRS
from data.synthetic.body import mean_body, pose_joints
from evaluation.identity import IdentityEvaluator
from reconstruction.results import Reconstruction
from reconstruction.solver.map_solver import combine_estimates
from tracking import Tracker, tracker
from tracking.track_kernels import Bodies, centres, pair_mean_distances, robust_skeleton
from tracking.tracker import (
    CORE_JOINTS,
    Tracked,
    TrackState,
    _core_mask,
    mean_distances,
    near_pairs,
    predicted_positions,
)

FPS = 25.0


def _walker(start, heading: float, speed: float, frame: int, scale: float = 1.0, walking: bool = True) -> np.ndarray:
    """A walking (or standing) mean body (scaled stature) at a frame: (23, 4), score 1."""
    t = frame / FPS
    x, y = start[0] + speed * t * np.cos(heading), start[1] + speed * t * np.sin(heading)
    joints = pose_joints(mean_body(1.7 * scale), x, y, heading, phase=0.8 * t, walking=walking)
    return np.concatenate([joints, np.ones((len(joints), 1))], axis=1)


def _step(tracker: Tracker, frame: int, poses: np.ndarray, variance=None, bones=None) -> Tracked:
    """One frame through the tracker: associate, then update with the persons' poses (P, J, 4)."""
    return tracker.update(tracker.associate(frame, poses), Reconstruction(poses, variance, bones))


def _noisy(poses: np.ndarray, rng: np.random.Generator, sd: float = 0.02) -> np.ndarray:
    out = poses.copy()
    out[..., :3] += rng.normal(0, sd, out[..., :3].shape)
    return out


def test_two_people_crossing_paths_keep_their_ids():
    rng = np.random.default_rng(0)
    tracker = Tracker()
    seen = {0: set(), 1: set()}
    for f in range(100):
        a = _walker((-2.4, 0.0), 0.0, 1.2, f)  # along x
        b = _walker((0.0, -2.4), np.pi / 2, 1.2, f - 4)  # along y, 4 frames behind: closest approach ~0.3 m
        order = rng.permutation(2)  # the frame's persons come in any order
        poses = _noisy(np.stack([a, b])[order], rng)
        ids = _step(tracker, f, poses).ids
        for slot, person in enumerate(order):
            seen[int(person)].add(int(ids[slot]))
    assert all(len(s) == 1 for s in seen.values()) and seen[0] != seen[1]


def test_a_person_who_returns_after_the_death_age_gets_a_new_id_and_before_it_keeps_it():
    tracker = Tracker(max_age=5, min_hits=2)
    pose = _walker((0.0, 0.0), 0.0, 0.0, 0)
    first = _step(tracker, 0, pose[None]).ids[0]
    _step(tracker, 1, pose[None])
    _step(tracker, 2, np.zeros((0, 23, 4)))  # missed 4 frames (2..5): within max_age
    assert _step(tracker, 6, pose[None]).ids[0] == first
    assert _step(tracker, 13, pose[None]).ids[0] != first  # gone 6 frames after its last hit: a new id


def test_a_tentative_track_missed_once_is_dropped():
    tracker = Tracker(min_hits=3)
    pose = _walker((0.0, 0.0), 0.0, 0.0, 0)
    first = _step(tracker, 0, pose[None]).ids[0]
    _step(tracker, 1, np.zeros((0, 23, 4)))
    assert _step(tracker, 2, pose[None]).ids[0] != first


def test_frames_that_go_backwards_or_repeat_stop_with_a_message():
    tracker = Tracker()
    _step(tracker, 5, np.zeros((0, 23, 4)))
    for bad in (5, 4):
        with pytest.raises(ValueError, match="must\\s+increase"):
            _step(tracker, bad, np.zeros((0, 23, 4)))


def test_a_gap_is_predicted_over_the_missed_frames_not_taken_as_a_jump():
    tracker = Tracker()
    for f in range(20):
        ids = _step(tracker, f, _walker((0.0, 0.0), 0.0, 1.5, f)[None]).ids
    # frames 20..27 missing: the body is 9 x 6 cm further on at frame 28; taken as one frame's step, the
    # velocity would jump to 0.54 m per frame
    assert _step(tracker, 28, _walker((0.0, 0.0), 0.0, 1.5, 28)[None]).ids[0] == ids[0]
    hips = tracker.state.velocity[0, 11:13].mean(axis=0)
    np.testing.assert_allclose(hips[:2], [1.5 / FPS, 0.0], atol=0.01)  # horizontal: the hips bob in z


def test_the_bone_lengths_of_a_track_converge_to_the_bodys_own():
    rng = np.random.default_rng(1)
    tracker = Tracker()
    for f in range(30):
        _step(tracker, f, _noisy(_walker((0.0, 0.0), 0.3, 1.0, f, scale=1.15)[None], rng, sd=0.005))
    median, se, count = tracker.state.skel_median[0], tracker.state.skel_se[0], tracker.state.skel_count[0]
    truth = _walker((0.0, 0.0), 0.3, 1.0, 0, scale=1.15)
    true_len = np.linalg.norm(truth[BONE_PAIRS[:, 0], :3] - truth[BONE_PAIRS[:, 1], :3], axis=-1)
    assert np.all(count == 30)
    assert np.max(np.abs(median - true_len)) < 0.005
    assert np.all(se < 0.03 / np.sqrt(30))


def test_identity_metrics_count_switches_fragments_and_the_kept_share():
    ev = IdentityEvaluator(max_dist_m=0.5)
    gt = np.stack([_walker((0.0, 0.0), 0.0, 0.0, 0), _walker((3.0, 0.0), 0.0, 0.0, 0)])
    gt_ids = np.array([10, 11])
    #            frame:    0        1        2        3        4        5
    tracks_of_0 = [7, 7, 8, -1, 8, 7]  # one switch 7->8, one back 8->7; one gap (fragment)
    for t0 in tracks_of_0:
        pred = gt if t0 >= 0 else gt[1:]
        ids = np.array([t0, 3]) if t0 >= 0 else np.array([3])
        ev.update(pred, ids, gt, gt_ids)
    s = ev.summary()
    assert s["id_switches"] == 2 and s["fragmentations"] == 1 and s["gt_person_frames"] == 12
    assert s["idf1_like"] == pytest.approx(100 * (3 + 6) / 12)


@pytest.mark.parametrize("compiled_pairs", [0, 10**6])  # the KD-trees' pairs, then one compiled pass over all
def test_pre_gated_mean_distances_equal_the_brute_force_within_the_gate(compiled_pairs, monkeypatch):
    monkeypatch.setattr(tracker, "COMPILED_PAIRS", compiled_pairs)
    rng = np.random.default_rng(3)
    guess = rng.uniform(-3, 3, (12, 1, 3)) + rng.normal(0, 0.3, (12, 23, 3))
    seen = rng.random((12, 23)) > 0.2
    poses = np.concatenate(
        [
            rng.uniform(-3, 3, (15, 1, 3)) + rng.normal(0, 0.3, (15, 23, 3)),
            (rng.random((15, 23, 1)) > 0.2).astype(float),
        ],
        axis=-1,
    )
    poses[0, CORE_JOINTS, 3] = 0.0  # a person without head and trunk: every joint counts
    got = mean_distances(guess, seen, poses, max_m=1.0)
    for t in range(12):
        for p in range(15):
            both = seen[t] & (poses[p, :, 3] > 0)
            core = np.zeros(23, bool)
            core[CORE_JOINTS] = True
            use = both & core if (both & core).any() else both
            want = np.linalg.norm(guess[t, use] - poses[p, use, :3], axis=-1).mean() if use.any() else np.inf
            if want <= 1.0:
                assert got[t, p] == pytest.approx(want)
            else:
                assert got[t, p] > 1.0


def test_the_pipeline_gives_track_ids_to_poses3d_json_and_identity_metrics(tmp_path):
    from data.formats.poses_io import write_poses3d
    from data.synthetic import SyntheticConfig, generate_sequence
    from evaluation.pose3d import Pose3DEvaluator
    from evaluation.sequence_eval import evaluate_sequence
    from reconstruction.matching import OracleMatcher
    from reconstruction.pipeline import MultiViewPipeline
    from reconstruction.reconstructors import VanillaTriangulation

    sequence = generate_sequence(SyntheticConfig(num_persons=4, num_frames=6, num_cameras=3, seed=2))
    pipeline = MultiViewPipeline(sequence.rig, OracleMatcher(), VanillaTriangulation(), Tracker())
    report = evaluate_sequence(sequence, pipeline, Pose3DEvaluator(), progress=False)
    assert report.metrics["tracking_id_switches"] == 0 and report.metrics["tracking_idf1_like"] == 100.0
    assert "tracking" in report.timings
    write_poses3d(
        tmp_path / "p.json", [(r.frame, r.poses3d, r.assignment, r.ids) for r in report.results], sequence.rig.names
    )
    frames = json.loads((tmp_path / "p.json").read_text())["frames"]
    first = {p["id"] for p in frames[0]["poses"]}
    assert all({p["id"] for p in f["poses"]} == first for f in frames) and len(first) == 4
    untracked = MultiViewPipeline(sequence.rig, OracleMatcher(), VanillaTriangulation())
    assert untracked(sequence.frames[0]).ids is None
    assert (
        "tracking_id_switches" not in evaluate_sequence(sequence, untracked, Pose3DEvaluator(), progress=False).metrics
    )


def test_exact_joints_are_kept_and_noisy_ones_are_smoothed():
    rng = np.random.default_rng(4)
    exact, smooth = Tracker(), Tracker()
    raw_err, out_err = [], []
    for f in range(40):
        truth = _walker((0.0, 0.0), 0.2, 0.0, f, walking=False)[None]  # a player on a stage
        kept = _step(exact, f, truth, np.full((1, 23), 1e-10)).poses3d
        np.testing.assert_allclose(kept, truth, atol=1e-6)
        noisy = _noisy(truth, rng, sd=0.01)
        out = _step(smooth, f, noisy, np.full((1, 23), 1e-4)).poses3d
        if f >= 10:
            raw_err.append(np.linalg.norm(noisy[0, :, :3] - truth[0, :, :3], axis=-1).mean())
            out_err.append(np.linalg.norm(out[0, :, :3] - truth[0, :, :3], axis=-1).mean())
    assert np.mean(out_err) < 0.75 * np.mean(raw_err)
    plain = Tracker()  # no variances (e.g. reconstruction=vanilla): ids only
    for f in range(5):
        noisy = _noisy(_walker((0.0, 0.0), 0.2, 0.0, f, walking=False)[None], rng, sd=0.01)
        np.testing.assert_array_equal(_step(plain, f, noisy).poses3d, noisy)


def test_a_joint_hidden_in_every_view_for_three_frames_follows_the_motion():
    from data.synthetic.observe import bbox_from_keypoints
    from data.synthetic.rigs import ring_rig
    from reconstruction.solver.map_solver import MLEMAPReconstruction

    rig = ring_rig(4, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    rng = np.random.default_rng(5)
    tracker, rec = Tracker(), MLEMAPReconstruction()
    hidden = 9  # left wrist: no view sees it in frames 20-22
    for f in range(23):
        truth = _walker((-1.0, 0.0), 0.0, 1.2, f)
        uv = rig.project(truth[None, :, :3]) + rng.normal(0, 1.0, (4, 1, 23, 2))
        poses2d = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
        if f >= 20:
            poses2d[:, 0, hidden, 2] = 0.0
        boxes = np.stack([bbox_from_keypoints(p, cam.size) for p, cam in zip(poses2d, rig)])
        result = rec(poses2d, boxes, rig)
        alone = result.poses
        out = _step(tracker, f, alone, result.joint_variance).poses3d
    tracked, by_prior = (np.linalg.norm(p[0, hidden, :3] - truth[hidden, :3]) for p in (out, alone))
    assert tracked < 0.05 and tracked < by_prior
    assert out[0, hidden, 3] == alone[0, hidden, 3] < 0.5  # the reconstruction's low score is kept


def test_the_map_reports_each_joints_variance_for_the_tracker():
    from data.synthetic.observe import bbox_from_keypoints
    from data.synthetic.rigs import ring_rig
    from reconstruction.solver.map_solver import MLEMAPReconstruction

    rig = ring_rig(4, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    X = _walker((0.0, 0.0), 0.4, 0.0, 0)[None, :, :3]
    rng = np.random.default_rng(0)
    out = {}
    for noise in (1.0, 4.0):
        uv = rig.project(X) + rng.normal(0, noise, (4, 1, 23, 2))
        poses2d = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
        poses2d[1:, 0, 9, 2] = 0.0  # the left wrist seen in one view only
        poses2d[:, 0, 10, 2] = 0.0  # the right wrist in none
        boxes = np.stack([bbox_from_keypoints(p, cam.size) for p, cam in zip(poses2d, rig)])
        out[noise] = MLEMAPReconstruction()(poses2d, boxes, rig).joint_variance
    var = out[1.0][0]
    assert var.shape == (23,) and np.isinf(var[10])
    many = np.ones(23, bool)
    many[[9, 10]] = False  # seen in 4 views: the likelihood fixes them
    assert np.all(np.isfinite(var[many])) and np.all(out[4.0][0, many] > 4 * var[many])
    assert 10 * var[many].max() < var[9] < 0.03**2  # one view: the bone tie fixes its depth


def test_the_robust_skeleton_is_numpys_nanmedian_and_mad():
    rng = np.random.default_rng(0)
    for W in (1, 2, 5, 31, 100):
        bones = rng.normal(0.3, 0.02, (W, 40))
        bones[rng.random(bones.shape) < 0.3] = np.nan  # unmeasured
        bones[:, 0] = np.nan
        median, se, count = np.empty(40), np.empty(40), np.empty(40, np.int64)
        robust_skeleton(bones, median, se, count, np.empty((2, W)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanmedian(bones, axis=0)
            mad = np.nanmedian(np.abs(bones - ref), axis=0)
        n = np.isfinite(bones).sum(axis=0)
        np.testing.assert_array_equal(count, n)
        np.testing.assert_allclose(median, ref, rtol=1e-15, equal_nan=True)
        np.testing.assert_allclose(se, np.where(n > 1, 1.4826 * mad / np.sqrt(np.maximum(n, 1)), np.inf), rtol=1e-15)


def test_precision_weighted_combination_of_two_bone_estimates():
    mean, sd = combine_estimates(
        np.array([[0.30, 0.40]]), np.array([[0.02, 0.02]]), np.array([[0.34, np.nan]]), np.array([[0.01, 0.01]])
    )
    np.testing.assert_allclose(mean, [[(0.30 / 4e-4 + 0.34 / 1e-4) / (1 / 4e-4 + 1 / 1e-4), 0.40]])
    np.testing.assert_allclose(sd, [[1 / np.sqrt(1 / 4e-4 + 1 / 1e-4), 0.02]])


def test_a_tracked_persons_own_skeleton_sharpens_the_maps_bones():
    from data.synthetic.observe import bbox_from_keypoints
    from data.synthetic.rigs import ring_rig
    from reconstruction.pipeline import MultiViewPipeline
    from reconstruction.solver.map_solver import MLEMAPReconstruction

    rig = ring_rig(3, 7.0, 2.5, look_at=(0.0, 0.0, 1.0))
    a, b = BONE_PAIRS[:, 0], BONE_PAIRS[:, 1]
    errors, measured = {}, []
    for tracked in (False, True):
        rng = np.random.default_rng(7)
        tracker, rec = Tracker(smooth=False), MLEMAPReconstruction()
        pipe = MultiViewPipeline(rig, None, rec, tracker if tracked else None)
        err = []
        for f in range(30):
            truth = _walker((-0.5, 0.0), 0.3, 0.0, f, scale=1.15, walking=False)[:, :3]  # 15 % above the table
            true_bones = np.linalg.norm(truth[a] - truth[b], axis=-1)
            uv = rig.project(truth[None]) + rng.normal(0, 4.0, (3, 1, 23, 2))
            poses2d = np.concatenate([uv, np.full(uv.shape[:-1] + (1,), 0.9)], axis=-1)
            boxes = np.stack([bbox_from_keypoints(p, cam.size) for p, cam in zip(poses2d, rig)])
            result, association = pipe._reconstruct(f, poses2d, boxes)
            out = result.poses
            if tracked:  # the pairing the skeleton prior came from, as the pipeline keeps it
                tracker.update(association or tracker.associate(f, out), result)
                measured.append(np.abs(result.bone_lengths[0] - true_bones).mean())
            if f >= 20:
                err.append(np.abs(np.linalg.norm(out[0, a, :3] - out[0, b, :3], axis=-1) - true_bones).mean())
        errors[tracked] = np.mean(err)
    median, count = tracker.state.skel_median[0], tracker.state.skel_count[0]
    assert np.all(count == 30)
    assert np.abs(median - true_bones).mean() < 0.5 * np.mean(measured)  # the track knows the body better
    assert errors[True] < errors[False]  # and the MAP's bones follow


@pytest.mark.parametrize("sizes", [(7, 5), (300, 200)])  # the dense path and the KD-tree path
def test_near_pairs_are_the_brute_force_pairs(sizes: tuple[int, int]) -> None:
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-10, 10, (sizes[0], 3)), rng.uniform(-10, 10, (sizes[1], 3))
    a[1, 2] = np.nan  # no pairs for a point with a non-finite coordinate
    rows, cols = near_pairs(a, b, 2.5)
    dist = np.linalg.norm(a[:, None] - b[None], axis=-1)
    want = set(zip(*np.nonzero(dist <= 2.5)))
    assert set(zip(rows.tolist(), cols.tolist())) == want and len(rows) == len(want) > 0
    assert 1 not in set(rows.tolist())


def _numpy_centres(points, ok, core):
    """The numpy formula the centres kernel replaced."""
    use = ok & core
    use = np.where(use.any(axis=1, keepdims=True), use, ok)
    return np.where(use[..., None], points, 0.0).sum(axis=1) / np.maximum(use.sum(axis=1), 1)[:, None]


def _numpy_pair_mean_distance(a, a_ok, b, b_ok):
    """The numpy formula the pair distance kernel replaced."""
    both = a_ok & b_ok
    dist = np.sqrt(((a - b) ** 2).sum(-1))
    n = both.sum(-1)
    return np.where(n > 0, np.where(both, dist, 0.0).sum(-1) / np.maximum(n, 1), np.inf)


def test_the_association_kernels_equal_the_numpy_formulas():
    rng = np.random.default_rng(5)
    T, P, J = 40, 30, 23
    guess, poses = rng.normal(0, 3, (T, J, 3)), rng.normal(0, 3, (P, J, 4))
    seen = rng.random((T, J)) < 0.7
    seen[:4, CORE_JOINTS] = False  # no head or trunk joint: the centre of all, the distance over all shared
    seen[4] = False  # nothing seen: no centre, no distance
    poses[rng.random((P, J)) < 0.3, 3] = 0.0
    poses[:3, CORE_JOINTS, 3] = 0.0
    valid, core = poses[..., 3] > 0, _core_mask(J)
    for points, ok in ((guess, seen), (poses, valid)):
        out = centres(points, ok, core)
        with np.errstate(invalid="ignore"):
            assert np.array_equal(out, _numpy_centres(points[..., :3], ok, core))
    for K in (1, 2, T * P):
        rows, cols = np.divmod(np.arange(T * P), P)
        rows, cols = rows[::-1][:K].copy(), cols[::-1][:K].copy()  # the last: core joints in both
        got = np.full((T, P), np.inf)
        pair_mean_distances(Bodies(guess=guess, seen=seen, poses3d=poses, valid=valid, core=core), rows, cols, got)
        core_d = _numpy_pair_mean_distance(
            guess[rows][:, core], seen[rows][:, core], poses[cols][:, core, :3], valid[cols][:, core]
        )
        left = ~np.isfinite(core_d)
        core_d[left] = _numpy_pair_mean_distance(
            guess[rows[left]], seen[rows[left]], poses[cols[left], :, :3], valid[cols[left]]
        )
        np.testing.assert_allclose(got[rows, cols], core_d, rtol=1e-15)  # numpy's sums are pairwise at times
    assert left.any() and np.isinf(core_d).any()
    np.testing.assert_array_equal(mean_distances(guess, seen, poses), got)  # every pair within an infinite gate


def test_the_prediction_kernel_equals_the_numpy_formula_bit_for_bit():
    rng = np.random.default_rng(7)
    T, J = 30, 23
    position, velocity, dt = rng.normal(0, 3, (T, J, 3)), rng.normal(0, 1, (T, J, 3)), rng.integers(1, 5, T) * 1.0
    live = rng.random((T, J)) < 0.6
    live[:3, CORE_JOINTS] = False  # no head or trunk joint: the mean of all live joints
    live[3] = False  # nothing live: no motion
    core = _core_mask(J)
    use = live & core
    use = np.where(use.any(axis=1, keepdims=True), use, live)  # the numpy formula the kernel replaced
    body = np.where(use[..., None], velocity, 0.0).sum(axis=1) / np.maximum(use.sum(axis=1), 1)[:, None]
    out = predicted_positions(position, velocity, live, dt)
    assert np.array_equal(out, position + dt[:, None, None] * body[:, None, :])
    assert np.array_equal(out[3], position[3]) and not np.array_equal(out[0], position[0])


def _states(joints: int, window: int, *sizes: int, seed: int = 3) -> list[TrackState]:
    """States of n random tracks each, of the tracker's field shapes and dtypes."""
    rng, L = np.random.default_rng(seed), len(BONE_PAIRS)
    empty = Tracker(bone_window=window)._births(
        np.zeros(0, np.int64), 0, np.zeros((0, joints, 4)), np.zeros((0, joints)), np.zeros((0, L))
    )
    return [TrackState(*(rng.normal(size=(n, *a.shape[1:])).astype(a.dtype) for a in empty)) for n in sizes]


def test_selecting_tracks_into_the_bone_pool_then_appending_equals_a_mask_then_a_concatenation():
    rng = np.random.default_rng(2)
    for keep_rate, births in ((1.0, 3), (0.7, 0), (0.4, 5), (0.0, 2), (1.0, 0)):
        st, then = _states(23, 6, 12, births)
        pool = np.full((40, 6, len(BONE_PAIRS)), np.nan)
        pool[:12] = st.bones
        st = st._replace(bones=pool[:12])
        keep = rng.random(12) < keep_rate
        want = [np.concatenate([a[keep], b]) for a, b in zip(st, then)]
        out = st.select(keep, then if births else None, pool)
        for name, got, expected in zip(TrackState._fields, out, want):
            np.testing.assert_array_equal(got, expected, err_msg=name)
            assert got.dtype == expected.dtype
        assert out.bones.base is pool and out.bones.ctypes.data == pool.ctypes.data or out is st
    assert st.select(np.ones(12, bool), None, pool) is st


def test_associate_changes_nothing_and_update_takes_its_pairing():
    """associate() is pure (twice the same answer, the tracks unchanged); update() follows the association it is
    given (here one that pairs the first person with the second one's track) and refuses a stale one."""
    tracker = Tracker(min_hits=1, skeleton_min_frames=1)
    a, b = _walker((0.0, 0.0), 0.0, 0.0, 0), _walker((3.0, 0.0), 0.0, 0.0, 0)
    first = _step(tracker, 0, np.stack([a, b])).ids
    before = [field.copy() for field in tracker.state]
    one, two = tracker.associate(1, np.stack([a, b])), tracker.associate(1, np.stack([a, b]))
    assert all(np.array_equal(x, y) for x, y in zip(one, two)) and sorted(one.tracks) == sorted(first)
    prior = tracker.skeleton_prior(one)
    assert prior.lengths.shape == (2, len(BONE_PAIRS)) and np.all(np.isnan(prior.lengths))  # one frame: too few
    for now, then in zip(tracker.state, before):
        np.testing.assert_array_equal(now, then)  # NaN equal NaN
    swapped = one._replace(persons=one.persons[::-1].copy())
    assert list(tracker.update(swapped, Reconstruction(np.stack([a, b]))).ids) == list(first[::-1])
    with pytest.raises(ValueError, match="must\\s+increase"):
        tracker.update(one, Reconstruction(np.stack([a, b])))
    with pytest.raises(ValueError, match="2 poses"):
        tracker.update(tracker.associate(2, np.stack([a, b])), Reconstruction(a[None]))
