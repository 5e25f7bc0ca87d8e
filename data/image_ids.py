"""COCO image ids of multi-view frames (detector=file's keys): ``id = frame * V + view + 1``, whatever frames run."""

from __future__ import annotations


def coco_image_id(frame: int, view: int, num_views: int) -> int:
    """The COCO image id of view ``view`` (0..V-1) of frame number ``frame`` (>= 0) in a rig of V cameras."""
    frame, view, num_views = int(frame), int(view), int(num_views)
    if frame < 0 or not 0 <= view < num_views:
        raise ValueError(f"no image id for frame {frame}, view {view} of {num_views} cameras")
    return frame * num_views + view + 1
