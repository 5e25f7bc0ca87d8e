"""Geometry (layer 1): cameras and the formats and checks of their calibration.

``camera`` (Camera, Rig: projection, distortion), ``calibration`` (cameras.json, 4D Association,
VoxelPose, Panoptic, Wildtrack, Shelf P-matrix readers; ``load_rig``), ``check_rig`` (the rig check;
a CLI), ``triangulation`` (score-weighted DLT, reprojection error), ``linalg`` (batched 3x3 inverse).
May import only layer 1 (``data.keypoints``, ``data.multiview``, ``data.formats``) and third-party packages.
"""
