"""Dataset entry points for ``configs/dataset/*.yaml``: each builds a :class:`data.multiview.Sequence`."""

from __future__ import annotations

from data.multiview import Sequence


def load_synthetic(render: bool = False, render_seed: int | None = None, **options) -> Sequence:
    """The built-in synthetic crowd (SyntheticConfig's options); render: views of a render (render_seed None: seed)."""
    from data.synthetic import SyntheticConfig, generate_sequence

    if not isinstance(render, bool):
        raise ValueError(f"synthetic dataset option render={render!r} must be true or false")
    if render_seed is not None and (isinstance(render_seed, bool) or not isinstance(render_seed, int)):
        raise ValueError(f"synthetic dataset option render_seed={render_seed!r} must be an integer or null")
    cfg = SyntheticConfig(**options)
    sequence = generate_sequence(cfg)
    rig = "ring of cameras" if cfg.rig == "ring" else f"rig {cfg.rig}"
    persons = f"{len(sequence.frames[0].gt_ids) if sequence.frames else 0} persons"
    if not render:
        sequence.description = (
            f"Synthetic crowd (seed {cfg.seed}): {persons}, {rig}, 2D noise {cfg.noise_px} px at "
            f"{cfg.noise_ref_depth_m} m x (depth ratio)^{cfg.noise_depth_exponent:g}, "
            f"occlusion {'on' if cfg.occlusion else 'off'}, "
            f"miss rate {cfg.miss_rate}, false positives {cfg.fp_rate} per view"
        )
        return sequence
    from data.pose2d.scene_render import render_sequence

    seed = cfg.seed if render_seed is None else int(render_seed)
    sequence = render_sequence(sequence, seed)
    sequence.description = (
        f"Synthetic crowd (seed {cfg.seed}), rendered (render seed {seed}): {persons}, {rig}, "
        f"views = the render's ground-truth 2D"
    )
    sequence.views_are_ground_truth = True
    return sequence
