"""Multi-view reconstruction (layer 3): matching across views, 3D poses, the per-frame pipeline (docs/design.md)."""
