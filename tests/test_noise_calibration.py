"""The self-calibrating 2D noise model (reconstruction/noise_calibration.py): known per-camera noise recovered,
score scale ignored, too little data refused."""

import numpy as np
import pytest

from data.multiview import ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from reconstruction.matching import OracleMatcher
from reconstruction.noise_calibration import CalibratedNoiseModel, joint_types
from reconstruction.noise_model import NoiseModel
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.solver.map_solver import MAPReconstruction


def noisy_sequence(noise_px: list[float], frames: int = 8, persons: int = 6, seed: int = 0):
    """Exact synthetic 2D with Gaussian pixel noise of the given SD per camera and scores unrelated to the error."""
    cfg = SyntheticConfig(
        seed=seed, num_frames=frames, num_persons=persons, num_cameras=len(noise_px), noise_px=0.0, occlusion=False
    )
    sequence, rng = generate_sequence(cfg), np.random.default_rng(seed)
    for frame in sequence.frames:
        views = []
        for view, sd in zip(frame.views, noise_px):
            kp = view.keypoints.copy()
            seen = kp[..., 2] > 0
            kp[..., :2] += np.where(seen[..., None], rng.normal(0.0, sd, kp[..., :2].shape), 0.0)
            kp[..., 2] = np.where(seen, rng.uniform(0.3, 1.0, seen.shape), 0.0)
            views.append(ViewDetections(kp, view.bboxes, view.scores, view.person_ids))
        frame.views = views
    return sequence


def calibrated(sequence, model: CalibratedNoiseModel) -> tuple[CalibratedNoiseModel, str]:
    """The pipeline's calibration with GT matching: the fitted model and the report's line."""
    pipeline = MultiViewPipeline(sequence.rig, OracleMatcher(), MAPReconstruction(noise_model=model))
    line = pipeline.calibrate_noise(sequence.frames)
    return pipeline.reconstructor.noise_model, line


def median_sigma(model, sequence, view: int) -> float:
    """The model's median SD over the seen joints of one camera's detections."""
    kp = np.concatenate([f.views[view].keypoints for f in sequence.frames])
    boxes = np.concatenate([f.views[view].bboxes for f in sequence.frames])
    sigma = model.sigma(kp, boxes, np.full(len(kp), view))
    return float(np.median(sigma[np.isfinite(sigma)]))


@pytest.mark.parametrize("noise_px", [[2.0, 5.0, 10.0], [2.0, 10.0, 5.0, 2.0, 5.0, 10.0]])
def test_recovers_simulated_per_camera_noise_within_20_percent(noise_px):
    sequence = noisy_sequence(noise_px)
    model, line = calibrated(sequence, CalibratedNoiseModel(frames=8))
    assert model.table is not None and "self-calibrated" in line
    for view, truth in enumerate(noise_px):
        assert median_sigma(model, sequence, view) == pytest.approx(truth, rel=0.2), (view, line)


def test_the_score_counts_by_its_rank_only():
    sequence = noisy_sequence([3.0, 3.0, 6.0, 6.0])
    model, _ = calibrated(sequence, CalibratedNoiseModel(frames=8))
    rescaled = noisy_sequence([3.0, 3.0, 6.0, 6.0])
    for frame in rescaled.frames:
        for view in frame.views:
            view.keypoints[..., 2] = 4.0 * view.keypoints[..., 2] ** 3  # another detector's scale, same order
    model2, _ = calibrated(rescaled, CalibratedNoiseModel(frames=8))
    for view in range(4):
        assert median_sigma(model2, rescaled, view) == pytest.approx(median_sigma(model, sequence, view), rel=0.05)


def test_too_few_residuals_keep_the_start_model():
    sequence = noisy_sequence([2.0, 5.0, 10.0], frames=1, persons=1)
    start = NoiseModel(c=0.02, sigma_px=0.0, score_power=1.0)
    model, line = calibrated(sequence, CalibratedNoiseModel(start=start, frames=1, min_count=200))
    assert model.table is None and "not calibrated" in line
    kp, boxes = sequence.frames[0].views[0].keypoints, sequence.frames[0].views[0].bboxes
    np.testing.assert_array_equal(model.sigma(kp, boxes, np.zeros(len(kp), int)), start.sigma(kp, boxes))


def test_two_views_leave_no_residual_and_keep_the_start_model():
    sequence = noisy_sequence([2.0, 5.0], frames=2)
    model, line = calibrated(sequence, CalibratedNoiseModel(frames=2))
    assert model.table is None and line.startswith("2D noise model: not calibrated (0 joint residuals")


def test_fixed_models_leave_the_pipeline_uncalibrated():
    sequence = noisy_sequence([2.0, 5.0, 10.0], frames=2)
    pipeline = MultiViewPipeline(sequence.rig, OracleMatcher(), MAPReconstruction(noise_model=NoiseModel()))
    assert pipeline.calibrate_noise(sequence.frames) is None
    assert isinstance(pipeline.reconstructor.noise_model, NoiseModel)


def test_left_and_right_joints_share_a_type_and_bad_keys_stop():
    types = joint_types(23)
    assert types[5] == types[6] and types[0] != types[1] and len(set(types)) == 12
    np.testing.assert_array_equal(joint_types(14), np.arange(14))
    with pytest.raises(ValueError, match="min_views"):
        CalibratedNoiseModel(min_views=2)
    with pytest.raises(ValueError, match="frames"):
        CalibratedNoiseModel(frames=0)


def test_unseen_joints_get_infinite_sigma():
    sequence = noisy_sequence([2.0, 5.0, 10.0], frames=4)
    model, _ = calibrated(sequence, CalibratedNoiseModel(frames=4))
    kp = sequence.frames[0].views[0].keypoints.copy()
    kp[0, 3, 2] = 0.0
    sigma = model.sigma(kp, sequence.frames[0].views[0].bboxes, np.zeros(len(kp), int))
    assert np.isinf(sigma[0, 3]) and np.all(np.isfinite(np.delete(sigma[0], 3)))


def test_the_default_config_calibrates_once_for_matcher_and_map():
    """eval.yaml's default: the evidence matcher's gates and the MAP's weights read the one fitted model."""
    from hydra import compose, initialize

    sequence = noisy_sequence([2.0, 5.0, 10.0, 5.0], frames=4)
    with initialize(config_path="../configs", version_base="1.3"):
        cfg = compose("eval")
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    line = pipeline.calibrate_noise(sequence.frames)
    assert pipeline.matcher.noise_model is pipeline.reconstructor.noise_model
    assert pipeline.matcher.noise_model.table is not None and line.startswith("2D noise model: self-calibrated")
    sigma = [median_sigma(pipeline.matcher.noise_model, sequence, v) for v in range(4)]
    assert sigma[0] < sigma[1] < sigma[2] and sigma[3] == pytest.approx(sigma[1], rel=0.2)
    assert len(pipeline(sequence.frames[0]).poses3d) == 6


def test_a_level_only_unseen_views_reach_is_no_error():
    """fit_table: a camera none of whose views is seen (e.g. 1 frame, nobody in its view) keeps the fit working."""
    from reconstruction.noise_calibration import fit_table

    rng = np.random.default_rng(0)
    K, V = 400, 4
    seen = np.ones((K, V), bool)
    seen[:, 3] = False  # camera 3 sees none of the joints
    score = np.where(seen, rng.uniform(0.2, 0.6, (K, V)), 0.0)
    mix = np.where(seen[:, :, None] & seen[:, None, :], 0.3, 0.0)
    r2 = np.where(seen, rng.chisquare(2, (K, V)) * 4.0, 0.0)
    blocks = dict(r2=r2, mix=mix, seen=seen, chi2=np.full(K, 3.0), dof=2 * seen.sum(axis=1) - 3)
    blocks |= dict(joint=np.zeros(K, int), score=score, box=np.where(seen, rng.uniform(50, 200, (K, V)), np.nan))
    table = fit_table(blocks, rank_bins=5, box_bins=4, min_count=10)
    assert table is not None
    assert [len(e) for e in table.effects] == [V, 1, 5, 4]
    # the seen cameras' fit is the one without the empty camera
    without = {k: (a[:, :3, :3] if k == "mix" else a[:, :3] if a.ndim == 2 else a) for k, a in blocks.items()}
    without["dof"] = 2 * without["seen"].sum(axis=1) - 3
    reference = fit_table(without, rank_bins=5, box_bins=4, min_count=10)
    assert table.base == pytest.approx(reference.base)
    np.testing.assert_allclose(table.effects[0][:3], reference.effects[0])
    assert np.all(np.isfinite(np.concatenate(table.effects)))
