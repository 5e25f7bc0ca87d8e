"""Data (layers 1-2): keypoints, assignment, containers, formats, geometry; datasets, synthetic scenes, 2D training."""
