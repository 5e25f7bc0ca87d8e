"""Reprojection statistics of the paper's Table 3, and the reconstruction ablation sweep."""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from data.synthetic import SyntheticConfig, generate_sequence
from evaluation.reprojection import frame_reprojection_errors, reprojection_stats
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import gather_views
from reconstruction.reconstructors import VanillaTriangulation

REPO = Path(__file__).resolve().parents[1]


def test_reprojection_stats_known_answer_ignores_nan():
    stats = reprojection_stats(np.array([[1.0, 2.0, np.nan], [3.0, 6.0, np.inf]]))
    assert stats == {"mean": 3.0, "min": 1.0, "max": 6.0, "var": pytest.approx(3.5), "count": 4}
    empty = reprojection_stats(np.full(3, np.nan))
    assert empty["count"] == 0 and np.isnan(empty["mean"])


def test_frame_errors_are_zero_on_noise_free_input_against_detections_and_ground_truth():
    seq = generate_sequence(SyntheticConfig(num_frames=1, num_persons=3, noise_px=0.0, occlusion=False))
    frame = seq.frames[0]
    assignment = OracleMatcher()(frame.views, seq.rig).assignment
    poses2d, boxes = gather_views(frame.views, assignment)
    out = VanillaTriangulation()(poses2d, boxes, seq.rig).poses
    ids = [frame.views[0].person_ids[assignment[p, 0]] for p in range(len(assignment))]
    gt = frame.gt_poses[[list(frame.gt_ids).index(i) for i in ids]]
    for ref in (None, gt):
        err = frame_reprojection_errors(out, assignment, frame.views, seq.rig, ref)
        assert err.shape == (len(seq.rig), len(assignment), 23)
        assert np.isfinite(err).sum() > 100 and np.nanmax(err) < 1e-6


def test_reconstruction_ablation_sweep_runs_every_stage(tmp_path):
    sweep = tmp_path / "sweep"
    cmd = [
        sys.executable,
        "eval.py",
        "-m",
        "+experiment=reconstruction_ablation",
        "dataset.num_frames=1",
        "dataset.num_persons=4",
        "progress=false",
        f"hydra.sweep.dir={sweep}",
    ]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=REPO, timeout=60)
    assert time.perf_counter() - t0 < 20
    names = sorted(p.parent.name.rpartition("=")[2] for p in sweep.glob("*/metrics.json"))
    assert names == ["map", "mle", "mle_map", "paper", "vanilla"]
    cmd = [sys.executable, "-m", "benchmarks.gather_sweep", str(sweep), "--metrics", "mpjpe_mm,pcp_average"]
    table = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=REPO, timeout=60).stdout
    assert table.splitlines()[0].split("|")[1].strip() == "reconstruction" and table.count("\n") == 7


def test_benchmark_left_right_swap_swaps_the_chosen_detections_only():
    from benchmarks.reconstruction import swap_left_right
    from data.keypoints import JOINT_INDEX

    rng = np.random.default_rng(0)
    poses2d = rng.normal(size=(3, 4, 23, 3))
    before = poses2d.copy()
    assert np.array_equal(swap_left_right(poses2d, 0.0, rng), poses2d)
    swapped = swap_left_right(poses2d, 1.0, rng)
    left, right = JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]
    np.testing.assert_array_equal(swapped[..., left, :], poses2d[..., right, :])
    np.testing.assert_array_equal(swapped[..., 0, :], poses2d[..., 0, :])  # the nose stays
    np.testing.assert_array_equal(poses2d, before)
