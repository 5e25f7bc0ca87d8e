"""Evaluation (layer 4): metrics against ground truth, the datasets' protocols, pictures.

``association`` (predictions to GT), ``mpjpe``, ``pcp``, ``pose3d`` (the generic 3D evaluator),
``correspondence`` (matching precision / recall), ``identity`` (tracking identity metrics),
``reprojection`` (reprojection error, paper Table 3), ``sequence_eval`` (evaluate_sequence),
``pose2d_eval`` (the 2D model's COCO AP), ``report`` (tables); ``protocols/`` (Shelf, Panoptic,
Wildtrack reprojection COCO); ``pictures/`` (run pictures and the sequence viewer).
May import layers 1-3 (``data``, ``models``, ``reconstruction``, ``tracking``); never the entry points.
"""
