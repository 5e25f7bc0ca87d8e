"""Motion files out of a run's poses3d.json (layer 6: imports data/ only, nothing imports it): BVH, TRC, CSV.

``python -m export bvh|trc|csv poses3d.json [-o OUT] [--fps FPS] [--fill] [--track ID]`` (docs/usage.md).
"""
