"""2D training data (layer 2): COCO-format records and keypoints, top-down crops and their transforms, the
synthetic image renderer, the COCO keypoint AP/AR scoring of that format.

May import layer 1 (``data.*``, ``data.formats``, ``data.geometry``) and layer 2 (``data.synthetic``).
"""
