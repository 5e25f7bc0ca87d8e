"""Longer measurements that print markdown tables; run each as a module from the repository root (layer 5)."""
