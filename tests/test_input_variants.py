"""benchmarks/input_variants.py: the other detectors' 2D made from a dev set, the source left as it was."""

import numpy as np

from benchmarks import input_variants as variants
from data.synthetic import SyntheticConfig, generate_sequence


def scene():
    return generate_sequence(SyntheticConfig(seed=2, num_frames=2, num_persons=4, num_cameras=3, noise_px=0.0))


def test_rescored_and_doubled_change_what_they_say():
    seq = scene()
    before = seq.frames[0].views[0].keypoints.copy()
    cubed = variants.rescored(seq, lambda s: s**3).frames[0].views[0]
    np.testing.assert_allclose(cubed.keypoints[..., 2], before[..., 2] ** 3)
    np.testing.assert_array_equal(cubed.keypoints[..., :2], before[..., :2])
    twice = variants.doubled(seq, 0.3).frames[0].views[0]
    n = len(before)
    np.testing.assert_allclose(twice.keypoints[n:, :, :2], before[..., :2] + 0.3)
    np.testing.assert_array_equal(twice.person_ids, np.concatenate([seq.frames[0].views[0].person_ids] * 2))
    np.testing.assert_array_equal(seq.frames[0].views[0].keypoints, before)


def test_detector_like_drops_a_tenth_and_scores_whatever_the_error():
    seq = scene()
    seen = np.concatenate([v.keypoints[..., 2] > 0 for f in seq.frames for v in f.views])
    made = variants.detector_like(seq, sigma_px=5.0, swaps=0.0, drops=0.1)
    kp = np.concatenate([v.keypoints for f in made.frames for v in f.views])
    kept = kp[..., 2] > 0
    assert not np.any(kept & ~seen)
    assert abs(1 - kept.sum() / seen.sum() - 0.1) < 0.05
    assert kp[kept, 2].min() >= 0.2 and kp[kept, 2].max() <= 1.0
    exact = np.concatenate([v.keypoints for f in seq.frames for v in f.views])
    error = np.linalg.norm(kp[kept, :2] - exact[kept, :2], axis=-1)
    assert 1.0 < np.median(error) < 15.0
    assert abs(np.corrcoef(error, kp[kept, 2])[0, 1]) < 0.1
