"""Issue "inputs checked against each other": repeated detections dropped or merged before matching and counted in
the report, and a cap on the detections of a frame."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.config_checks import ConfigError
from data.frame_inputs import EXACT, NEAR, InputWarning, clean_frames, merge_duplicates
from data.multiview import Frame, Sequence, ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from reconstruction.pipeline import MultiViewPipeline

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_rig"


def config(*overrides: str):
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        return compose(config_name="eval", overrides=["progress=false", *overrides])


def person(size: float, shift: float = 0.0) -> np.ndarray:
    """A (23, 3) detection spanning about size px, shifted right by shift px, every joint scored 0.9."""
    kp = np.zeros((23, 3))
    kp[:, 0] = 100 + np.linspace(0, size / 3, 23) + shift
    kp[:, 1] = 100 + np.linspace(0, size, 23) ** 1.0
    kp[:, 2] = 0.9
    return kp


def view(*kps: np.ndarray, scores: list[float] | None = None) -> ViewDetections:
    n = len(kps)
    return ViewDetections(np.stack(kps), np.zeros((n, 4)), scores or [0.9] * n, -np.ones(n, int))


def test_exact_repeats_in_poses2d_json_are_dropped_with_a_warning_and_counted_in_the_report(tmp_path):
    entries = json.loads((EXAMPLE / "poses2d.json").read_text())
    entries += [copy.deepcopy(entries[3]), copy.deepcopy(entries[20])]
    path = tmp_path / "in.json"
    path.write_text(json.dumps(entries))
    cfg = config("dataset=files", f"dataset.cameras={EXAMPLE / 'cameras.json'}", f"dataset.poses2d={path}")
    with pytest.warns(InputWarning) as record:
        report = eval_script.run(cfg, tmp_path)
    (text,) = [str(w.message) for w in record if w.category is InputWarning]
    first = f"frame {entries[3]['frame']}, camera {entries[3]['camera']!r}"
    assert text == (
        "exact repeats of a detection dropped: 2 (same frame, camera and keypoints: a detector or an export run "
        f"twice?), the first in {first}"
    )
    assert report.inputs == {EXACT: 2}
    assert "Detections before matching: 2 exact duplicates dropped" in (tmp_path / "report.txt").read_text()
    assert json.loads((tmp_path / "metrics.json").read_text())["inputs"] == {EXACT: 2}
    assert len(json.loads((tmp_path / "poses2d.json").read_text())) == len(entries) - 2


def test_each_detection_repeated_with_a_03_px_shift_gives_the_same_people():
    sequence = generate_sequence(SyntheticConfig(num_frames=1, num_persons=4))
    frame = sequence.frames[0]
    doubled = []
    for v in frame.views:  # the copies score higher, and half their joints too: the merge takes from both
        copy_kp = v.keypoints + [0.3, 0.0, 0.0]
        copy_kp[..., 2] += np.where(v.keypoints[..., 2] > 0, [0.01, -0.01] * 11 + [0.01], 0.0)
        copy_kp[..., 2] = np.minimum(copy_kp[..., 2], 1.0)
        doubled.append(
            ViewDetections(
                np.concatenate([v.keypoints, copy_kp]),
                np.concatenate([v.bboxes, v.bboxes]),
                np.r_[v.scores, v.scores + 0.01],
                np.r_[v.person_ids, v.person_ids],
            )
        )
    pipeline = MultiViewPipeline.from_config(config("tracking=off"), sequence.rig)
    original = pipeline(frame).poses3d
    assert len(pipeline(Frame(0, doubled)).poses3d) != len(original)  # unmerged, the copies are people too
    cleaned, counts = clean_frames(Sequence(sequence.rig, [Frame(0, doubled)]), 2000, 0.01)
    assert counts == {NEAR: sum(len(v) for v in frame.views)}
    people = pipeline(cleaned.frames[0]).poses3d
    assert len(people) == len(original) == 4
    np.testing.assert_allclose(people[..., :3], original[..., :3], atol=0.01)  # 0.3 px: millimetres
    np.testing.assert_allclose(people[..., 3], original[..., 3], atol=0.011)  # joint scores moved by 0.01


def test_the_near_threshold_is_relative_to_the_persons_size():
    """1 % of the size: a 2 px shift is one person at 400 px, two at 100 px; 5 % apart are two people."""
    big, small = person(400), person(100)
    assert len(merge_duplicates(view(big, person(400, 2.0)), 0.01)[0]) == 1
    assert len(merge_duplicates(view(small, person(100, 2.0)), 0.01)[0]) == 2
    assert len(merge_duplicates(view(big, person(400, 0.05 * 400)), 0.01)[0]) == 2


def test_the_merge_keeps_per_joint_the_higher_score_and_leaves_the_callers_arrays():
    a, b = person(300), person(300, 0.5)
    a[:5, 2], b[5:, 2] = 0.2, 0.3  # a lacks confidence in joints 0-4, b in the rest
    b[20:, 2] = 0.0
    detections = view(a, b, scores=[0.8, 0.9])
    before = detections.keypoints.copy()
    merged, exact, near = merge_duplicates(detections, 0.01)
    assert (exact, near, len(merged)) == (0, 1, 1)
    np.testing.assert_array_equal(merged.keypoints[0, :5], b[:5])
    np.testing.assert_array_equal(merged.keypoints[0, 5:], a[5:])
    assert merged.scores[0] == 0.9 and np.array_equal(detections.keypoints, before)


def test_detections_without_any_scored_joint_may_repeat():
    empty = np.zeros((23, 3))
    assert len(merge_duplicates(view(empty, empty), 0.01)[0]) == 2


def test_a_frame_over_the_cap_stops_naming_the_frame_and_the_key():
    sequence = generate_sequence(SyntheticConfig(num_frames=2, num_persons=3))
    count = sum(len(v) for v in sequence.frames[0].views)
    with pytest.raises(ConfigError) as err:
        clean_frames(sequence, count - 1, 0.01)
    assert str(err.value) == (
        f"frame 0 has {count} detections over {len(sequence.rig)} views, more than "
        f"inputs.max_detections_per_frame={count - 1} (a detector without non-maximum suppression?)"
    )
    assert clean_frames(sequence, max(sum(len(v) for v in f.views) for f in sequence.frames), 0.01)[1] == {}


def test_eval_checks_the_inputs_keys(tmp_path):
    with pytest.raises(ConfigError, match=r"inputs.near_duplicate=-0.1: must be a number >= 0"):
        eval_script.run(config("inputs.near_duplicate=-0.1", "dataset.num_frames=1"), tmp_path)
