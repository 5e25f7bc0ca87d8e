"""File formats (layer 1): readers and writers, one module per format.

``atomic_io`` (atomic file writes), ``poses2d_io`` (poses2d.json), ``poses_io`` (poses3d.json),
``openpose_json`` (OpenPose --write_json folders -> poses2d.json; a CLI), ``fourd_detections`` (4D
Association's ungrouped BODY_25 candidates and PAFs), ``fourd_skeletons`` (4D Association skeleton text:
Shelf GT and stored output), ``coco_detections`` (COCO detection-results files: person boxes). May import only layer 1 (``data.keypoints``, ``data.multiview``,
``data.geometry``, the other formats) and third-party packages.
"""
