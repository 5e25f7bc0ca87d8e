"""File formats (layer 1): readers and writers of poses2d/poses3d JSON, OpenPose JSON, 4D Association text, atomic writes.

May import only ``data`` layer-1 modules (``data.keypoints``, ``data.multiview``, ``data.geometry``) and third-party packages.
"""
