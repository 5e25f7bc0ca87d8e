"""Dataset entry points for ``configs/dataset/*.yaml``: each builds a :class:`data.multiview.Sequence`."""

from __future__ import annotations

from data.multiview import Sequence


def load_synthetic(**options) -> Sequence:
    """The built-in synthetic crowd; options are the fields of ``data.synthetic.SyntheticConfig``."""
    from data.synthetic import SyntheticConfig, generate_sequence

    cfg = SyntheticConfig(**options)
    sequence = generate_sequence(cfg)
    rig = "ring of cameras" if cfg.rig == "ring" else f"rig {cfg.rig}"
    sequence.meta["description"] = (
        f"Synthetic crowd (seed {cfg.seed}): {len(sequence.frames[0].gt_ids) if sequence.frames else 0} persons, "
        f"{rig}, 2D noise {cfg.noise_px} px at {cfg.noise_ref_depth_m} m x (depth ratio)^{cfg.noise_depth_exponent:g}, "
        f"occlusion {'on' if cfg.occlusion else 'off'}, "
        f"miss rate {cfg.miss_rate}, false positives {cfg.fp_rate} per view"
    )
    return sequence
