"""Data, the bottom layer: keypoint metadata, assignment solvers, containers, file formats, geometry (layer 1); datasets, the
synthetic scene generator, 2D training data (layer 2). Imports nothing above it (tests/test_import_layers.py)."""
