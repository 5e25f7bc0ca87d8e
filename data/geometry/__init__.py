"""Geometry (layer 1): cameras and rigs, calibration file formats, the rig check and DLT triangulation.

May import only ``data`` layer-1 modules (``data.keypoints``, ``data.multiview``, ``data.formats``) and third-party packages.
"""
