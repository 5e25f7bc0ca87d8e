"""Longer measurements that print markdown tables; run each as a module from the repository root.

Layer 5 (with ``eval.py``, ``train.py`` and ``run_folders.py``): may import every layer.
"""
