"""2D training data (layer 2) for the 2D network.

``records`` (ImageRecord), ``coco_keypoints`` (COCO-format keypoint files -> records),
``crop_transforms`` (top-down crop affine, flips, augmentation), ``topdown_dataset`` (the torch
Dataset; its heatmap codec is given by the caller), ``render`` (the drawing path of the synthetic images),
``synthetic_images`` (single crowded images), ``scene_render`` (every camera's view of a multi-view 3D
crowd, with its ground-truth 2D), ``multiview_images`` (those renders as a training set), ``view_coco``
(frames' per-view 2D as COCO ground truth and results),
``coco_eval`` (the COCO keypoint AP/AR of that format: pycocotools OKS, used by training and evaluation).
May import layers 1 and 2 (``data.*``); never the stages, ``evaluation`` or the entry points.
"""
