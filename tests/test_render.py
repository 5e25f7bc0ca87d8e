"""The shared drawing path of the synthetic images: ground lines are clipped in front of the camera."""

from __future__ import annotations

import numpy as np

from data.pose2d.render import draw_ground_lines
from data.synthetic.rigs import look_at_camera


def test_ground_lines_crossing_behind_the_camera_stay_below_the_horizon():
    camera = look_at_camera("c", (0.0, 0.0, 1.5), (10.0, 0.0, 1.0), (320, 240), 250.0)
    horizon = camera.project(np.array([1e6, 0.0, 0.0]))[1]
    ends = np.array([[[-6.0, y], [6.0, y]] for y in (-0.5, 0.3, 1.0)])
    image = np.zeros((240, 320, 3), np.uint8)
    draw_ground_lines(image, camera, ends, (255, 255, 255))
    rows, cols = np.nonzero(image[..., 0])
    assert len(rows) > 100 and rows.min() > horizon
    # the visible half is drawn where the projection puts it: the far end sits at its projected pixel
    far = camera.project(np.array([6.0, 0.3, 0.0]))
    assert image[int(round(far[1])), int(round(far[0])), 0] > 0
    behind_only = np.zeros_like(image)
    draw_ground_lines(behind_only, camera, np.array([[[-6.0, 0.0], [-1.0, 0.0]]]), (255, 255, 255))
    assert not behind_only.any()
