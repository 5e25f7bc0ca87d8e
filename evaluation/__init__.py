"""Evaluation: metrics against ground truth, the datasets' protocols, pictures; never imports the entry points."""
