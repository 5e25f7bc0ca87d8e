"""3D reconstruction benchmark: vanilla / mle / map / mle_map on synthetic crowds, as one markdown report."""

from benchmarks import common  # isort: split

import argparse
import time
from pathlib import Path
from typing import Callable

import numpy as np

from data.geometry.calibration import load_wildtrack_positions
from data.geometry.camera import Rig
from data.keypoints import flip_permutation
from data.multiview import Frame, Sequence
from data.synthetic import SyntheticConfig, generate_sequence
from evaluation.pose3d import Pose3DEvaluator
from evaluation.report import format_table
from evaluation.reprojection import frame_reprojection_errors, reprojection_stats
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import gather_views
from reconstruction.reconstructors import VanillaTriangulation
from reconstruction.results import Reconstruction
from reconstruction.solver.map_solver import MAPReconstruction, MLEMAPReconstruction, MLEReconstruction

NOISES = (2.0, 5.0, 10.0)
Stage = Callable[[np.ndarray, np.ndarray, Rig], Reconstruction]
A_HEADERS = ("scene", "noise px", "persons", "stage", "MPJPE (mm)", "MPJPE vanilla's joints (mm)", "PCP (%)")
B_HEADERS = ("scene", "stage", "reference", "mean", "min", "max", "var", "count")


def make_stages() -> dict[str, Stage]:
    """The four reconstruction stages with their config defaults."""
    return {
        "vanilla": VanillaTriangulation(),
        "mle": MLEReconstruction(),
        "map": MAPReconstruction(),
        "mle_map": MLEMAPReconstruction(),
    }


def gt_for_assignment(frame: Frame, assignment: np.ndarray) -> np.ndarray:
    """Ground truth of each matched person through the detection identities: (P, V) -> (P, J, 4)."""
    ids = [frame.views[v].person_ids[assignment[p, v]] for p, v in enumerate(np.argmax(assignment >= 0, axis=1))]
    index = {int(i): k for k, i in enumerate(frame.gt_ids)}
    return frame.gt_poses[[index[int(i)] for i in ids]]


def wildtrack_sequence(root: Path, noise: float, frames: int, seed: int) -> Sequence:
    """Synthetic bodies at the first annotated Wildtrack positions, seen by the real 7-camera rig."""
    positions = load_wildtrack_positions(root / "gt_positions_mvdet.txt")
    return common.wildtrack_scene(root, [positions[f] for f in sorted(positions)[:frames]], noise, seed)


def ring_sequence(noise: float, frames: int, seed: int) -> Sequence:
    """The default synthetic scene (10 persons, 0.3 / m2, 5 ring cameras) at a noise level."""
    return generate_sequence(SyntheticConfig(seed=seed, num_frames=frames, noise_px=noise))


def evaluate_stages(seq: Sequence, stages: dict[str, Stage]) -> dict[str, dict]:
    """Every stage on oracle-matched frames: metrics, MPJPE on vanilla's joints, ms/frame, reprojection errors."""
    evals = {k: Pose3DEvaluator() for k in stages}
    shared = {k: [] for k in stages}
    reproj = {k: {"detections": [], "ground truth": []} for k in stages}
    times = dict.fromkeys(stages, 0.0)
    for frame in seq.frames:
        assignment = OracleMatcher()(frame.views, seq.rig).assignment
        poses2d, boxes = gather_views(frame.views, assignment)
        gt = gt_for_assignment(frame, assignment)
        outs = {}
        for name, stage in stages.items():
            t0 = time.perf_counter()
            outs[name] = out = stage(poses2d, boxes, seq.rig).poses
            times[name] += time.perf_counter() - t0
            evals[name].update(out, frame.gt_poses)
            for ref, truth in (("detections", None), ("ground truth", gt)):
                errors = frame_reprojection_errors(out, assignment, frame.views, seq.rig, truth)
                reproj[name][ref].append(errors.ravel())
        mask = outs["vanilla"][..., 3] > 0
        for name, out in outs.items():
            shared[name].append(np.linalg.norm(out[..., :3] - gt[..., :3], axis=-1)[mask & (out[..., 3] > 0)])
    return {
        k: {
            **evals[k].summary(),
            "mpjpe_common_mm": 1e3 * float(np.mean(np.concatenate(shared[k]))),
            "ms": 1e3 * times[k] / len(seq.frames),
            "reproj": {ref: np.concatenate(v) for ref, v in reproj[k].items()},
        }
        for k in stages
    }


def reprojection_rows(scene: str, res: dict[str, dict]) -> list[list]:
    """Section (b)'s rows of one scene: map and mle_map against the detections and against the ground truth."""
    rows = []
    for name in ("map", "mle_map"):
        for ref, err in res[name]["reproj"].items():
            s = reprojection_stats(err)
            stats = [f"{s['mean']:.2f}", f"{s['min']:.3f}", f"{s['max']:.1f}", f"{s['var']:.2f}", s["count"]]
            rows.append([scene, name, ref, *stats])
    return rows


def accuracy_section(args: argparse.Namespace) -> tuple[str, str]:
    """Sections (a) and (b)."""
    root = Path(args.data) / "wildtrack"
    scenes = {
        "Wildtrack rig (7 cams)": lambda n: wildtrack_sequence(root, n, args.frames, args.seed),
        "ring (5 cams, 10 persons)": lambda n: ring_sequence(n, args.frames, args.seed),
    }
    rows, stat_rows = [], []
    for scene, build in scenes.items():
        for noise in NOISES:
            seq = build(noise)
            people = f"{np.mean([len(f.gt_ids) for f in seq.frames]):.1f}"
            res = evaluate_stages(seq, make_stages())
            for name, r in res.items():
                errors = [r["mpjpe_mm"], r["mpjpe_common_mm"], r["pcp_average"], f"{r['ms']:.2f}"]
                rows.append([scene, f"{noise:g}", people, name, *errors])
            if noise == 5.0:
                stat_rows += reprojection_rows(scene, res)
    a = f"### (a) MPJPE and PCP, oracle matching, occlusion on, {args.frames} frames per setting\n\n"
    a += "MPJPE (protocol): joints valid in prediction and GT; MPJPE (vanilla's joints): the joints vanilla outputs."
    b = "### (b) Reprojection error (px) of the paper's Table 3, 5 px noise, undistorted pixels, var = population\n\n"
    b += "'detections': against the noisy 2D the solver fits; 'ground truth': against the GT's noise-free projection."
    a += "\n\n" + format_table((*A_HEADERS, "ms / frame"), rows)
    b += "\n\n" + format_table(B_HEADERS, stat_rows)
    return a, b


def swap_left_right(poses2d: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    """A copy of (V, P, J, 3) detections with the left and right joints of a share of them swapped."""
    out = poses2d.copy()
    swap = rng.random(poses2d.shape[:2]) < share
    out[swap] = poses2d[swap][:, flip_permutation()]
    return out


def robust_section(args: argparse.Namespace) -> str:
    """Section (c): the robust losses against 2D outliers (left/right swaps, as OpenPose makes them)."""
    stages = {
        "vanilla": VanillaTriangulation(),
        **{f"mle_map robust={k}": MLEMAPReconstruction(robust=k) for k in ("none", "huber", "cauchy")},
    }
    rows = []
    for share in (0.0, 0.1, 0.2):
        seq = ring_sequence(5.0, args.frames, args.seed)
        rng = np.random.default_rng(args.seed)
        evals = {k: Pose3DEvaluator() for k in stages}
        for frame in seq.frames:
            poses2d, boxes = gather_views(frame.views, OracleMatcher()(frame.views, seq.rig).assignment)
            poses2d = swap_left_right(poses2d, share, rng)
            for name, stage in stages.items():
                evals[name].update(stage(poses2d, boxes, seq.rig).poses, frame.gt_poses)
        for name, ev in evals.items():
            m = ev.summary()
            rows.append([f"{100 * share:.0f}", name, m["mpjpe_mm"], m["pcp_average"]])
    title = f"### (c) Robust losses against left / right swaps ring, 5 px, {args.frames} frames"
    return f"{title}\n\n{format_table(('swapped (%)', 'stage', 'MPJPE (mm)', 'PCP (%)'), rows)}"


def main(argv: list[str] | None = None) -> str:
    """Run the sections, print the report and write it to --out; return it."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="2 frames per setting (a smoke run)")
    p.add_argument("--data", default="../shared/data", help="folder holding wildtrack/")
    p.add_argument("--out", default=None, help="also write the report to this markdown file")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    args.frames = 2 if args.quick else 10
    start = time.perf_counter()
    parts = [f"## Reconstruction benchmark (seed {args.seed}{', quick' if args.quick else ''})"]
    parts += [*accuracy_section(args), robust_section(args)]
    return common.emit("\n\n".join([*parts, f"Total wall time {time.perf_counter() - start:.0f} s."]), args.out)


if __name__ == "__main__":
    main()
