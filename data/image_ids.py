"""COCO image ids of multi-view frames: one id per (frame, view), the key of a detections file (detector=file).

The id depends only on the frame number, the view index and the number of cameras, so it does not
change when a run selects other frames: ``id = frame * V + view + 1`` (ids start at 1, as in COCO).
"""

from __future__ import annotations


def coco_image_id(frame: int, view: int, num_views: int) -> int:
    """The COCO image id of view ``view`` (0..V-1) of frame number ``frame`` (>= 0) in a rig of V cameras."""
    frame, view, num_views = int(frame), int(view), int(num_views)
    if frame < 0 or not 0 <= view < num_views:
        raise ValueError(f"no image id for frame {frame}, view {view} of {num_views} cameras")
    return frame * num_views + view + 1


def frame_view_of(image_id: int, num_views: int) -> tuple[int, int]:
    """The (frame number, view index) of a COCO image id made by :func:`coco_image_id`."""
    image_id, num_views = int(image_id), int(num_views)
    if image_id < 1 or num_views < 1:
        raise ValueError(f"image id {image_id} was not made for a rig of {num_views} cameras")
    return divmod(image_id - 1, num_views)
