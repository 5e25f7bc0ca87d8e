"""The synthetic crowd generator: bodies, placement, cameras, occlusion and detections."""

from __future__ import annotations

import math

import numpy as np
import pytest

from data.geometry.camera import Rig
from data.keypoints import BONES, LEFT_FOOT, RIGHT_FOOT
from data.synthetic import SyntheticConfig, generate_sequence
from data.synthetic.body import mean_body, pose_joints, sample_body, stride_length
from data.synthetic.capsules import body_capsules, capsule_radii, occluded_joints, segment_distance
from data.synthetic.observe import observe_view
from data.synthetic.rigs import look_at_camera, ring_rig
from data.synthetic.scene import place_persons, scene_area, simulate_scene

PHASES = np.linspace(0.0, 1.0, 41)[:-1]
HEAD = [0, 1, 2, 3, 4]


def _bodies(n: int, seed: int = 1) -> list:
    rng = np.random.default_rng(seed)
    return [sample_body(rng) for _ in range(n)]


def _all_poses(body, theta: float = 0.3, x: float = 1.0, y: float = -2.0):
    """(label, (23, 3)) for the standing pose and the walking pose at every test phase."""
    yield "standing", pose_joints(body, x, y, theta, 0.0, False)
    for p in PHASES:
        yield f"walking {p:.3f}", pose_joints(body, x, y, theta, p, True)


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points (S, 3) to segments [a, b] (K, 3) or (3,): (S, K) or (S,)."""
    ab = b - a
    t = np.clip(
        np.einsum("s...i,...i->s...", p[:, None] - a if ab.ndim == 2 else p - a, ab)
        / np.maximum(np.sum(ab * ab, axis=-1), 1e-18),
        0.0,
        1.0,
    )
    closest = a + t[..., None] * ab
    return np.linalg.norm((p[:, None] if ab.ndim == 2 else p) - closest, axis=-1)


# --- determinism ------------------------------------------------------------------------------------


def _flatten(seq) -> list[np.ndarray]:
    out = []
    for fr in seq.frames:
        out += [fr.gt_poses, fr.gt_ids]
        for v in fr.views:
            out += [v.keypoints, v.bboxes, v.scores, v.person_ids, v.occluded]
    return out


def test_same_seed_same_arrays_different_seed_different():
    cfg = dict(num_frames=4, fp_rate=1.0, miss_rate=0.1)
    a = _flatten(generate_sequence(SyntheticConfig(seed=3, **cfg)))
    b = _flatten(generate_sequence(SyntheticConfig(seed=3, **cfg)))
    c = _flatten(generate_sequence(SyntheticConfig(seed=4, **cfg)))
    assert len(a) == len(b)
    assert all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, c))


# --- bodies -----------------------------------------------------------------------------------------

BONE_RANGES = {  # metres, generous adult ranges
    "shoulders": (0.28, 0.46),
    "hips": (0.14, 0.26),
    "left_torso": (0.38, 0.62),
    "left_upper_arm": (0.26, 0.40),
    "left_forearm": (0.20, 0.31),
    "left_thigh": (0.34, 0.52),
    "left_shin": (0.34, 0.52),
    "left_ankle_heel": (0.05, 0.12),
    "left_ankle_big_toe": (0.15, 0.28),
}


def test_bone_lengths_plausible_and_rigid():
    for body in _bodies(60):
        assert 1.5 <= body.stature <= 2.0
        lengths = {name: [] for name in BONES}
        for _, joints in _all_poses(body):
            for name, (a, b) in BONES.items():
                lengths[name].append(np.linalg.norm(joints[a] - joints[b]))
        for name, values in lengths.items():
            assert np.ptp(values) < 1e-9, f"{name} changes length over the gait"
            side = name.replace("right_", "left_")
            if side in BONE_RANGES:
                lo, hi = BONE_RANGES[side]
                assert lo <= values[0] <= hi, f"{name} = {values[0]:.3f} m for stature {body.stature:.2f}"


def test_poses_stand_on_the_ground_with_head_up_and_feet_apart():
    for body in _bodies(30, seed=2) + [mean_body(1.52), mean_body(1.95)]:
        foot_gaps = []
        for label, j in _all_poses(body):
            assert j[:, 2].min() >= -1e-9, label
            left, right = j[list(LEFT_FOOT), 2].min(), j[list(RIGHT_FOOT), 2].min()
            assert min(left, right) == pytest.approx(0.0, abs=1e-9), label
            assert j[HEAD, 2].min() > 1.3, label
            gap = np.linalg.norm(j[[15, *LEFT_FOOT], :2].mean(0) - j[[16, *RIGHT_FOOT], :2].mean(0))
            if label == "standing":
                assert 0.15 <= gap <= 0.40, gap
                assert max(left, right) == pytest.approx(0.0, abs=1e-9)  # both feet flat
            else:
                assert 0.08 <= gap <= 1.0, (label, gap)
                foot_gaps.append(gap)
        assert 0.5 <= max(foot_gaps) <= 0.95  # one step length
        assert 1.1 <= stride_length(body) <= 1.9


def test_left_is_left_of_heading_and_arms_swing_opposite_to_legs():
    for theta in np.linspace(0, 2 * math.pi, 9):
        forward = np.array([math.cos(theta), math.sin(theta)])
        left = np.array([-math.sin(theta), math.cos(theta)])
        for label, j in _all_poses(mean_body(), theta=theta):
            for a, b in ((5, 6), (11, 12), (1, 2), (3, 4), (19, 22)):
                assert (j[a, :2] - j[b, :2]) @ left > 0.02, (label, a, b)
            assert (j[0, :2] - (j[5, :2] + j[6, :2]) / 2) @ forward > 0.03, label  # nose in front
            assert (j[17, :2] - j[19, :2]) @ forward > 0.1, label  # toes ahead of heel
            if label != "standing":
                knees = (j[13, :2] - j[14, :2]) @ forward  # the thighs lead, the feet lag
                hands = (j[9, :2] - j[10, :2]) @ forward
                if abs(knees) > 0.1:
                    assert knees * hands < 0, label


# --- placement and motion ---------------------------------------------------------------------------


def test_placement_respects_spacing_and_density():
    cfg = SyntheticConfig(num_persons=40, density=1.2, min_spacing_m=0.6)
    xmin, xmax, ymin, ymax = scene_area(cfg)
    assert (xmax - xmin) * (ymax - ymin) == pytest.approx(40 / 1.2)
    assert (xmin + xmax) / 2 == pytest.approx(0) and (ymin + ymax) / 2 == pytest.approx(0)
    pts = place_persons(40, scene_area(cfg), 0.6, np.random.default_rng(0))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    assert d[np.triu_indices(40, 1)].min() >= 0.6
    assert np.all((pts[:, 0] >= xmin) & (pts[:, 0] <= xmax) & (pts[:, 1] >= ymin) & (pts[:, 1] <= ymax))

    scene = simulate_scene(SyntheticConfig(num_persons=30, density=1.0, num_frames=30), np.random.default_rng(1))
    for pos in scene.positions:
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
        assert d[np.triu_indices(30, 1)].min() >= 0.6 - 1e-9
    area = scene.area
    assert np.all((scene.positions[..., 0] >= area[0]) & (scene.positions[..., 0] <= area[1]))
    moved = np.linalg.norm(np.diff(scene.positions, axis=0), axis=-1)  # (F-1, P)
    walkers = scene.walking[0]
    assert walkers.sum() == 15
    assert np.all(moved[:, ~walkers] == 0)
    assert np.all(moved[:, walkers] <= 1.5 / 5 + 1e-9)
    assert np.mean(moved[:, walkers] > 0) > 0.5
    with pytest.raises(ValueError, match="cannot place"):
        place_persons(50, (0.0, 2.0, 0.0, 2.0), 0.6, np.random.default_rng(0))


def test_walkers_move_at_walking_speed_and_turn_at_the_border():
    cfg = SyntheticConfig(num_persons=6, walking_fraction=1.0, num_frames=60, fps=5)
    scene = simulate_scene(cfg, np.random.default_rng(5))
    step = np.linalg.norm(np.diff(scene.positions, axis=0), axis=-1)
    assert np.median(step) * cfg.fps == pytest.approx(1.35, abs=0.16)
    xmin, xmax, ymin, ymax = scene.area
    assert np.all((scene.positions[..., 1] >= ymin) & (scene.positions[..., 1] <= ymax))
    # 60 frames at ~1.35 m/s cover 16 m, more than the 4.5 m area: every walker must have turned.
    turned = np.abs(np.angle(np.exp(1j * (scene.headings[-1] - scene.headings[0])))) > 0.5
    assert turned.sum() >= 4


# --- cameras and projection -------------------------------------------------------------------------


def test_ring_rig_looks_at_the_centre_with_image_y_down():
    rig = ring_rig(4, 6.0, 2.0, (1.0, -1.0, 1.0), (640, 480), 500.0)
    for cam in rig:
        assert np.allclose(cam.R @ cam.R.T, np.eye(3)) and np.linalg.det(cam.R) == pytest.approx(1.0)
        assert np.hypot(*(cam.center[:2] - [1.0, -1.0])) == pytest.approx(6.0)
        assert cam.center[2] == pytest.approx(2.0)
        uv = cam.project(np.array([[1.0, -1.0, 1.0], [1.0, -1.0, 1.5]]))
        assert np.allclose(uv[0], [320, 240])
        assert uv[1, 1] < uv[0, 1] - 10  # higher in the world = higher in the image
        # A point on the camera's right (forward x up) appears right of the centre.
        forward = cam.R[2]
        right = np.cross(forward, [0, 0, 1])
        assert cam.project(np.array([1.0, -1.0, 1.0]) + 0.5 * right / np.linalg.norm(right))[0] > 330


def test_noise_free_keypoints_are_exact_projections():
    seq = generate_sequence(SyntheticConfig(noise_px=0.0, occlusion=False, num_frames=3))
    checked = 0
    for fr in seq.frames:
        gt = {int(i): p[:, :3] for i, p in zip(fr.gt_ids, fr.gt_poses)}
        assert np.all(fr.gt_poses[..., 3] == 1)
        for cam, view in zip(seq.rig, fr.views):
            assert not view.occluded.any()
            for kp, pid in zip(view.keypoints, view.person_ids):
                valid = kp[:, 2] > 0
                expected = cam.project(gt[int(pid)])
                assert np.abs(kp[valid, :2] - expected[valid]).max() < 1e-9
                assert np.array_equal(valid, cam.in_view(gt[int(pid)]))
                checked += valid.sum()
            # No person with enough joints in view is missing (miss_rate = 0).
            expected_ids = [i for i, p in gt.items() if cam.in_view(p).sum() >= 5]
            assert sorted(view.person_ids.tolist()) == sorted(expected_ids)
    assert checked > 1000


def test_pixel_noise_grows_with_depth_and_for_hidden_joints():
    seq = generate_sequence(
        SyntheticConfig(
            noise_px=2.0,
            noise_ref_depth_m=5.0,
            occluded_noise_scale=3.0,
            occluded_drop_prob=0.0,
            num_persons=20,
            density=1.0,
            num_frames=6,
        )
    )
    ratios = {False: [], True: []}
    for fr in seq.frames:
        gt = {int(i): p[:, :3] for i, p in zip(fr.gt_ids, fr.gt_poses)}
        for cam, view in zip(seq.rig, fr.views):
            for kp, pid, occ in zip(view.keypoints, view.person_ids, view.occluded):
                valid = kp[:, 2] > 0
                err = kp[:, :2] - cam.project(gt[int(pid)])
                ratio = err / (cam.depth(gt[int(pid)])[:, None] / 5.0)
                for hidden in (False, True):
                    ratios[hidden].append(ratio[valid & (occ == hidden)])
                assert kp[occ & valid, 2].max(initial=0) < kp[~occ & valid, 2].min(initial=1) + 0.1
    visible, hidden = np.concatenate(ratios[False]), np.concatenate(ratios[True])
    assert len(hidden) > 300
    assert np.std(visible) == pytest.approx(2.0, rel=0.08)
    assert np.std(hidden) == pytest.approx(6.0, rel=0.15)


# --- occlusion --------------------------------------------------------------------------------------


def test_segment_distance_matches_dense_sampling():
    rng = np.random.default_rng(0)
    s = np.linspace(0, 1, 801)
    for _ in range(200):
        p1, q1, p2, q2 = rng.normal(size=(4, 3))
        if rng.random() < 0.2:
            q2 = p2.copy()  # a sphere
        if rng.random() < 0.1:
            q2 = p2 + 3 * (q1 - p1)  # parallel segments
        got = segment_distance(p1, q1, p2, q2)
        pts = p1 + s[:, None] * (q1 - p1)
        brute = _point_segment_distance(pts, p2, q2).min()
        assert got <= brute + 1e-9 and got == pytest.approx(brute, abs=2e-3)


def test_person_directly_behind_another_is_hidden_only_there():
    camera = look_at_camera("c", (-6.0, 0.0, 1.6), (0.0, 0.0, 1.2), (1280, 720), 1000.0)
    front = pose_joints(mean_body(), 0.0, 0.0, math.pi)
    behind = pose_joints(mean_body(), 2.0, 0.0, math.pi)
    hidden = occluded_joints(camera.center, np.stack([front, behind]))
    assert not hidden[0].any()
    assert hidden[1, [5, 6, 11, 12]].all()
    aside = pose_joints(mean_body(), 2.0, 2.5, math.pi)
    assert not occluded_joints(camera.center, np.stack([front, aside])).any()

    cfg = SyntheticConfig(noise_px=0.0, occluded_drop_prob=0.0)
    view = observe_view(camera, np.stack([front, behind]), np.array([7, 8]), cfg, np.random.default_rng(0))
    flags = {int(i): o for i, o in zip(view.person_ids, view.occluded)}
    assert not flags[7].any() and flags[8][[5, 6, 11, 12]].all()
    scores = {int(i): kp[:, 2] for i, kp in zip(view.person_ids, view.keypoints)}
    assert scores[8][[5, 6, 11, 12]].max() < scores[7][[5, 6, 11, 12]].min()
    # Half hidden (one side behind the front person): with drop probability 1 exactly those joints go.
    half = pose_joints(mean_body(), 2.0, 0.3, math.pi)
    cfg = SyntheticConfig(occluded_drop_prob=1.0)
    view = observe_view(camera, np.stack([front, half]), np.array([7, 8]), cfg, np.random.default_rng(0))
    assert sorted(view.person_ids.tolist()) == [7, 8]
    assert 4 <= view.occluded.sum() <= 15
    for kp, occ in zip(view.keypoints, view.occluded):
        assert np.all(kp[occ] == 0) and np.all(kp[~occ, 2] > 0)


def test_occlusion_flags_agree_with_brute_force_ray_marching():
    seq = generate_sequence(SyntheticConfig(num_persons=25, density=1.0, num_frames=1, seed=7))
    fr = seq.frames[0]
    poses = fr.gt_poses[..., :3]
    ends_a, ends_b = body_capsules(poses)
    radii = capsule_radii()
    row = {int(i): r for r, i in enumerate(fr.gt_ids)}
    samples = np.linspace(0.0, 1.0, 2001)[:, None]  # <= 7 mm apart: sampled clearance is >= true, < true + 4 mm

    def clearance(center: np.ndarray, p: int, j: int) -> float:
        """Least (distance - radius) between the sight line and another person's capsules."""
        ray = center + samples * (poses[p, j] - center)
        best = np.inf
        for q in range(len(poses)):
            # Every capsule lies within 1.5 m of the mid-hip: farther persons cannot reach the ray.
            if q != p and np.linalg.norm(ray - poses[q, 11:13].mean(axis=0), axis=1).min() < 1.5:
                dist = _point_segment_distance(ray, ends_a[q], ends_b[q])  # (S, K)
                best = min(best, float((dist - radii).min()))
        return best

    flagged = unflagged = 0
    rng = np.random.default_rng(0)
    for cam, view in zip(seq.rig, fr.views):
        for d in rng.permutation(len(view))[:4]:
            p = row[int(view.person_ids[d])]
            occ = view.occluded[d]
            for j in list(np.flatnonzero(occ)[:3]) + list(np.flatnonzero(~occ & (view.keypoints[d, :, 2] > 0))[:2]):
                c = clearance(cam.center, p, j)
                if occ[j]:
                    assert c < 4e-3, (cam.name, p, j, c)
                    flagged += 1
                else:
                    assert c > 0.0, (cam.name, p, j, c)
                    unflagged += 1
    assert flagged >= 10 and unflagged >= 10


def test_person_behind_or_beside_a_camera_is_absent_from_that_view():
    positions = [[[0.0, 0.0], [10.0, 0.0], [4.0, 6.0]]]
    cfg = SyntheticConfig(positions=positions, noise_px=0.0)
    seq = generate_sequence(cfg)
    cam0 = seq.rig[0]
    gt = seq.frames[0].gt_poses[..., :3]
    assert not cam0.in_view(gt[1]).any() and not cam0.in_view(gt[2]).any()
    assert seq.frames[0].views[0].person_ids.tolist() == [0]
    assert any(1 in v.person_ids for v in seq.frames[0].views[1:])


# --- detector errors ---------------------------------------------------------------------------------


def test_false_positives_have_no_identity_and_follow_the_rate():
    seq = generate_sequence(SyntheticConfig(num_persons=4, num_cameras=3, num_frames=60, fp_rate=2.0))
    counts = [int(np.sum(v.person_ids == -1)) for fr in seq.frames for v in fr.views]
    assert np.mean(counts) == pytest.approx(2.0, abs=0.4)
    for fr in seq.frames:
        for v in fr.views:
            fp = v.person_ids == -1
            assert not v.occluded[fp].any()
            assert np.all(v.keypoints[fp, :, 2] < 0.6)
            assert set(v.person_ids[~fp].tolist()) <= set(fr.gt_ids.tolist())
    none = generate_sequence(SyntheticConfig(num_persons=4, num_cameras=3, num_frames=10))
    assert all(np.all(v.person_ids >= 0) for fr in none.frames for v in fr.views)


def test_missed_detections_reduce_counts():
    base = dict(num_persons=10, num_frames=20, noise_px=0.0)
    full = sum(len(v) for fr in generate_sequence(SyntheticConfig(**base)).frames for v in fr.views)
    half = sum(len(v) for fr in generate_sequence(SyntheticConfig(miss_rate=0.5, **base)).frames for v in fr.views)
    assert half / full == pytest.approx(0.5, abs=0.08)


def test_detection_fields_are_consistent_and_order_is_shuffled():
    seq = generate_sequence(SyntheticConfig(fp_rate=0.5))
    unsorted = 0
    for fr in seq.frames:
        assert fr.gt_poses.shape == (10, 23, 4)
        for v in fr.views:
            assert np.allclose(v.scores, v.keypoints[..., 2].mean(axis=1))
            for kp, box in zip(v.keypoints, v.bboxes):
                pts = kp[kp[:, 2] > 0, :2]
                inside = np.clip(pts, 0, [1279, 719])
                assert np.all(inside >= box[:2] - 1e-9) and np.all(inside <= box[:2] + box[2:] + 1e-9)
            valid = v.person_ids[v.person_ids >= 0]
            unsorted += bool(np.any(np.diff(valid) < 0))
    assert unsorted > 50
    assert seq.meta["config"]["num_persons"] == 10 and seq.meta["source"] == "synthetic"


def test_positions_hook_places_persons_and_derives_heading():
    track = [[[0.0, 0.0], [2.0, 1.0]], [[0.26, 0.0], [2.0, 1.0]], [[0.52, 0.0], [np.nan, np.nan]]]
    seq = generate_sequence(SyntheticConfig(positions=track, noise_px=0.0))
    assert len(seq.frames) == 3
    assert seq.frames[2].gt_ids.tolist() == [0]
    for f, fr in enumerate(seq.frames):
        pelvis = fr.gt_poses[0, [11, 12], :2].mean(axis=0)
        assert np.allclose(pelvis, track[f][0], atol=1e-9)
        forward = fr.gt_poses[0, 0, :2] - pelvis
        assert forward[0] > 0 and abs(forward[1]) < 1e-9  # walking along +x, facing +x


def test_config_accepts_plain_lists_and_rejects_bad_values():
    cfg = SyntheticConfig(**{"image_size": [640, 480], "area": [-3, 3, -2, 2], "noise_px": 0})
    assert cfg.image_size == (640, 480) and cfg.area == (-3.0, 3.0, -2.0, 2.0)
    assert SyntheticConfig(**cfg.to_dict()).to_dict() == cfg.to_dict()
    for bad in (
        {"miss_rate": 1.5},
        {"density": 0},
        {"image_size": [640]},
        {"area": [3, -3, 0, 1]},
        {"positions": [[[0, 0, 0]]]},
    ):
        with pytest.raises(ValueError):
            SyntheticConfig(**bad)
    rig = ring_rig(2, 5.0, 2.0)
    seq = generate_sequence(SyntheticConfig(num_frames=1), rig=rig)
    assert isinstance(seq.rig, Rig) and seq.rig is rig and len(seq.frames[0].views) == 2


def test_rig_from_a_calibration_file(tmp_path):
    import json

    ring = ring_rig(3, 7.0, 2.5, (1.0, 2.0, 1.0))
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(ring.to_dict()))
    seq = generate_sequence(
        SyntheticConfig(
            rig=str(path), area=[-1.0, 3.0, 0.0, 4.0], num_frames=2, num_persons=6, noise_px=0.0, occlusion=False
        )
    )
    assert seq.rig.names == ["0", "1", "2"]
    for cam, ref in zip(seq.rig, ring):
        assert np.allclose(cam.P, ref.P)
    assert all(len(v) == 6 for fr in seq.frames for v in fr.views)
    xy = np.concatenate([fr.gt_poses[:, [11, 12], :2].mean(axis=1) for fr in seq.frames])
    assert np.all((xy[:, 0] >= -1) & (xy[:, 0] <= 3) & (xy[:, 1] >= 0) & (xy[:, 1] <= 4))


def test_noise_depth_exponent_zero_gives_the_same_pixel_noise_at_every_depth():
    seq = generate_sequence(
        SyntheticConfig(
            noise_px=3.0, noise_depth_exponent=0.0, occlusion=False, num_persons=20, density=0.5, num_frames=4
        )
    )
    near, far = [], []
    for fr in seq.frames:
        gt = {int(i): p[:, :3] for i, p in zip(fr.gt_ids, fr.gt_poses)}
        for cam, view in zip(seq.rig, fr.views):
            for kp, pid in zip(view.keypoints, view.person_ids):
                valid = kp[:, 2] > 0
                err = (kp[:, :2] - cam.project(gt[int(pid)]))[valid]
                depth = cam.depth(gt[int(pid)])[valid]
                near.append(err[depth < np.median(depth)])
                far.append(err[depth >= np.median(depth)])
    assert np.std(np.concatenate(near)) == pytest.approx(3.0, rel=0.08)
    assert np.std(np.concatenate(far)) == pytest.approx(3.0, rel=0.08)
