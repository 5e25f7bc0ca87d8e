"""models/view_completion.py: a view a person was missed in is filled by the 2D model on the box of their projected
first-pass 3D pose, when the 2D pose agrees with the projection; another person in that box is refused."""

import numpy as np
import pytest

from data.multiview import ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from models.view_completion import ViewCompletion
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.solver.map_solver import MAPReconstruction


class Truth2D:
    """A pose2d stand-in: per box, the ground-truth 2D pose of the person the box was made for, shifted by ``shift``."""

    def __init__(self, pose: np.ndarray, shift: float = 0.0) -> None:
        self.pose, self.shift, self.boxes = pose, shift, []

    def __call__(self, images, boxes):
        self.boxes += [b.copy() for b in boxes]
        pose = self.pose.copy()
        pose[:, 0] += self.shift
        return [ViewDetections(pose[None], b[:, :4], b[:, 4], [-1]) for b in boxes]


@pytest.fixture(scope="module")
def scene():
    """One frame of 4 persons in 4 cameras with exact 2D; person 0 removed from view 2."""
    sequence = generate_sequence(SyntheticConfig(seed=3, num_frames=1, num_persons=4, num_cameras=4, noise_px=0.0))
    frame = sequence.frames[0]
    view = frame.views[2]
    index = int(np.flatnonzero(view.person_ids == 0)[0])
    keep = np.arange(len(view)) != index
    missing = ViewDetections(view.keypoints[keep], view.bboxes[keep], view.scores[keep], view.person_ids[keep])
    views = [*frame.views[:2], missing, *frame.views[3:]]
    return sequence, frame, views, view.keypoints[index]


def completion(sequence) -> ViewCompletion:
    return ViewCompletion(MultiViewPipeline(sequence.rig, OracleMatcher(), MAPReconstruction()))


def test_the_missed_view_gets_the_2d_pose_found_in_the_projected_box(scene):
    sequence, frame, views, truth = scene
    images = [np.zeros((c.size[1], c.size[0], 3), np.uint8) for c in sequence.rig]
    stage, model = completion(sequence), Truth2D(truth)
    out = stage(frame, images, views, model)
    assert [len(v) for v in out] == [len(frame.views[v]) for v in range(4)]  # only view 2 grew, by one
    assert len(model.boxes) == 1 and stage.added == 1
    np.testing.assert_array_equal(out[2].keypoints[-1], truth)
    x, y, w, h = model.boxes[0][0, :4]  # the box of the projection holds the person's seen joints
    seen = truth[truth[:, 2] > 0, :2]
    assert np.all((seen >= [x - 1, y - 1]) & (seen <= [x + w + 1, y + h + 1]))


def test_another_person_in_the_box_is_refused(scene):
    sequence, frame, views, truth = scene
    images = [np.zeros((c.size[1], c.size[0], 3), np.uint8) for c in sequence.rig]
    width = np.ptp(truth[truth[:, 2] > 0, 0])
    stage = completion(sequence)
    out = stage(frame, images, views, Truth2D(truth, shift=0.6 * width))
    assert [len(v) for v in out] == [len(v) for v in views] and stage.added == 0


def test_bad_keys_name_themselves():
    with pytest.raises(ValueError, match="complete_views.min_oks"):
        ViewCompletion(None, min_oks=0)
    with pytest.raises(ValueError, match="complete_views.min_joints"):
        ViewCompletion(None, min_joints=0)


def test_a_pose_the_view_holds_already_is_a_repeat(scene):
    sequence, frame, views, truth = scene
    stage = completion(sequence)
    assert stage.repeats(frame.views[2], truth)  # the view before person 0 was removed holds them
    assert not stage.repeats(views[2], truth)  # after: only the others
