"""Data, bottom of the layout (layers 1 and 2: everything else may import it, it imports nothing above).

Layer 1, plain data and files: ``keypoints`` (COCO-23 metadata, skeleton and part tables), ``assignment`` (the
assignment solvers shared by the stages),
``bone_lengths`` (bone tables), ``multiview`` (Frame / Sequence / ViewDetections containers),
``config_checks`` (one-line config errors); ``formats/`` (readers and writers); ``geometry/``
(cameras, rigs, calibration files, the rig check, DLT triangulation).
Layer 2, datasets: ``datasets/`` (one module per multi-view dataset), ``synthetic/`` (the synthetic
scene generator), ``pose2d/`` (the 2D training data).
Layer-1 modules may import only layer 1; layer-2 modules layers 1 and 2. No module here imports the
stages (``models``, ``reconstruction``, ``tracking``), ``evaluation`` or the entry points
(tests/test_import_layers.py checks it).
"""
