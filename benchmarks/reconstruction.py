"""3D reconstruction benchmark: vanilla / mle / map / mle_map on synthetic crowds, as one markdown report.

Run from the repository root:  python -m benchmarks.reconstruction [--quick] [--out FILE.md] [--data ../shared/data]

(a) MPJPE (mm, Pose3DEvaluator protocol: joints valid in prediction and GT) and PCP (%) of the four
    stages, oracle matching, occlusion on, 2D noise 2 / 5 / 10 px (SD at 5 m, growing with depth), on
    the real Wildtrack rig (synthetic bodies at the annotated ground positions) and on a 5-camera ring;
    also MPJPE over the joints the vanilla DLT outputs (same joint set for every stage).
(b) Table 3 of the paper: reprojection error statistics (px) of map (no MLE step) and mle_map, against
    the 2D detections and against the noise-free projections of the ground truth, at 5 px.
(c) ms per frame vs persons (1, 10, 50, 100) in 7 views and vs views (2, 4, 8) for 20 persons: our
    mle_map stage against per-person scipy.optimize.least_squares(method='trf', jac='2-point', default
    tolerances) on the same residuals (tests/oracles/pose_problem.py's residual_vector) from the same DLT
    start, both MLE then MAP.
(d) The robust losses (none / huber / cauchy) of mle_map against 2D outliers: 0, 10, 20 % of the
    detections with left and right swapped, ring, 5 px.
BLAS / OpenMP are pinned to one thread before numpy is imported: the timings are per core.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core: timings comparable with the 30 ms target

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from data.formats.atomic_io import atomic_write_text  # noqa: E402
from data.geometry.calibration import load_wildtrack, load_wildtrack_positions  # noqa: E402
from data.geometry.camera import Rig  # noqa: E402
from data.geometry.triangulation import triangulate_dlt  # noqa: E402
from data.keypoints import flip_permutation  # noqa: E402
from data.multiview import Frame, Sequence  # noqa: E402
from data.synthetic import SyntheticConfig, generate_sequence  # noqa: E402
from evaluation.pose3d import Pose3DEvaluator  # noqa: E402
from evaluation.report import format_table  # noqa: E402
from evaluation.reprojection import frame_reprojection_errors, reprojection_stats  # noqa: E402
from reconstruction.matching import OracleMatcher  # noqa: E402
from reconstruction.pipeline import gather_views  # noqa: E402
from reconstruction.reconstructors import VanillaTriangulation  # noqa: E402
from reconstruction.results import Reconstruction  # noqa: E402
from reconstruction.solver.compiled_solver import PoseProblem  # noqa: E402
from reconstruction.solver.map_solver import (  # noqa: E402
    MAPReconstruction,
    MLEMAPReconstruction,
    MLEReconstruction,
    output_confidence,
)
from reconstruction.solver.pose_init import initial_poses  # noqa: E402
from tests.oracles.pose_problem import residual_vector  # noqa: E402

WILDTRACK_AREA = (-3.0, 9.0, -9.0, 27.0)
NOISES = (2.0, 5.0, 10.0)
TARGET_GAIN, TARGET_SPEEDUP, TARGET_MS = 0.15, 50.0, 30.0
Stage = Callable[[np.ndarray, np.ndarray, Rig], Reconstruction]


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
    first = np.argmax(assignment >= 0, axis=1)
    ids = [frame.views[v].person_ids[assignment[p, v]] for p, v in enumerate(first)]
    index = {int(i): k for k, i in enumerate(frame.gt_ids)}
    return frame.gt_poses[[index[int(i)] for i in ids]]


def wildtrack_sequence(root: Path, noise: float, frames: int, seed: int) -> Sequence:
    """Synthetic bodies at the first annotated Wildtrack positions, seen by the real 7-camera rig."""
    positions = load_wildtrack_positions(root / "gt_positions_mvdet.txt")
    chosen = sorted(positions)[:frames]
    cfg = SyntheticConfig(
        seed=seed,
        positions=[positions[f] for f in chosen],
        area=WILDTRACK_AREA,
        min_spacing_m=0.0,
        rig=str(root),
        rig_format="wildtrack",
        noise_px=noise,
    )
    return generate_sequence(cfg, rig=load_wildtrack(root))


def ring_sequence(noise: float, frames: int, seed: int) -> Sequence:
    """The default synthetic scene (10 persons, 0.3 / m2, 5 ring cameras) at a noise level."""
    return generate_sequence(SyntheticConfig(seed=seed, num_frames=frames, noise_px=noise))


def evaluate_stages(seq: Sequence, stages: dict[str, Stage]) -> dict[str, dict]:
    """Every stage on oracle-matched frames: metrics, MPJPE on vanilla's joints, ms/frame, reprojection errors."""
    evals = {k: Pose3DEvaluator() for k in stages}
    common = {k: [] for k in stages}
    reproj = {k: {"detections": [], "ground truth": []} for k in stages}
    times = {k: 0.0 for k in stages}
    for frame in seq.frames:
        assignment = OracleMatcher()(frame.views, seq.rig).assignment
        poses2d, boxes = gather_views(frame.views, assignment)
        gt = gt_for_assignment(frame, assignment)
        outs = {}
        for name, stage in stages.items():
            t0 = time.perf_counter()
            outs[name] = stage(poses2d, boxes, seq.rig).poses
            times[name] += time.perf_counter() - t0
            evals[name].update(outs[name], frame.gt_poses)
            reproj[name]["detections"].append(
                frame_reprojection_errors(outs[name], assignment, frame.views, seq.rig).ravel()
            )
            reproj[name]["ground truth"].append(
                frame_reprojection_errors(outs[name], assignment, frame.views, seq.rig, gt).ravel()
            )
        mask = outs["vanilla"][..., 3] > 0
        for name, out in outs.items():
            common[name].append(np.linalg.norm(out[..., :3] - gt[..., :3], axis=-1)[mask & (out[..., 3] > 0)])
    return {
        k: {
            **evals[k].summary(),
            "mpjpe_common_mm": 1e3 * float(np.mean(np.concatenate(common[k]))),
            "ms": 1e3 * times[k] / len(seq.frames),
            "reproj": {ref: np.concatenate(v) for ref, v in reproj[k].items()},
        }
        for k in stages
    }


def accuracy_section(args: argparse.Namespace) -> tuple[str, str, list[str]]:
    """Sections (a) and (b), and the target lines of the MPJPE gain at 5 px."""
    scenes = {
        "Wildtrack rig (7 cams)": lambda n: wildtrack_sequence(
            Path(args.data) / "wildtrack", n, args.frames, args.seed
        ),
        "ring (5 cams, 10 persons)": lambda n: ring_sequence(n, args.frames, args.seed),
    }
    rows, stat_rows, targets = [], [], []
    for scene, build in scenes.items():
        for noise in NOISES:
            seq = build(noise)
            people = np.mean([len(f.gt_ids) for f in seq.frames])
            res = evaluate_stages(seq, make_stages())
            for name, r in res.items():
                rows.append(
                    [
                        scene,
                        f"{noise:g}",
                        f"{people:.1f}",
                        name,
                        r["mpjpe_mm"],
                        r["mpjpe_common_mm"],
                        r["pcp_average"],
                        f"{r['ms']:.2f}",
                    ]
                )
            if noise == 5.0:
                for name in ("map", "mle_map"):
                    for ref, err in res[name]["reproj"].items():
                        s = reprojection_stats(err)
                        stat_rows.append(
                            [
                                scene,
                                name,
                                ref,
                                f"{s['mean']:.2f}",
                                f"{s['min']:.3f}",
                                f"{s['max']:.1f}",
                                f"{s['var']:.2f}",
                                s["count"],
                            ]
                        )
                van, ours = res["vanilla"]["mpjpe_common_mm"], res["mle_map"]["mpjpe_common_mm"]
                van_all, ours_all = res["vanilla"]["mpjpe_mm"], res["mle_map"]["mpjpe_mm"]
                targets.append(
                    f"- {scene}, 5 px, occlusion: mle_map MPJPE {ours:.1f} mm vs vanilla {van:.1f} mm on vanilla's "
                    f"joints = {100 * (1 - ours / van):.1f} % lower (target >= {100 * TARGET_GAIN:.0f} %, ratio "
                    f"{(1 - ours / van) / TARGET_GAIN:.2f}: {'MET' if 1 - ours / van >= TARGET_GAIN else 'NOT MET'}); "
                    f"protocol MPJPE (all output joints) {ours_all:.1f} vs {van_all:.1f} mm = "
                    f"{100 * (1 - ours_all / van_all):.1f} % lower"
                )
    a = (
        "### (a) MPJPE and PCP, oracle matching, occlusion on, "
        f"{args.frames} frames per setting\n\n"
        "MPJPE (protocol): Hungarian-matched, over joints valid in prediction and GT (vanilla outputs only "
        "joints seen in >= 2 views, mle uses output_min_views=2, map / mle_map output every joint). "
        "MPJPE (vanilla's joints): only joints vanilla outputs, through the oracle identities.\n\n"
        + format_table(
            (
                "scene",
                "noise px",
                "persons",
                "stage",
                "MPJPE (mm)",
                "MPJPE vanilla's joints (mm)",
                "PCP (%)",
                "ms / frame",
            ),
            rows,
        )
    )
    b = (
        "### (b) Reprojection error (px), the statistics of the paper's Table 3, 5 px noise\n\n"
        "Each reconstructed joint projected into every view where its 2D joint has score > 0 (undistorted "
        "pixels). 'detections': against the noisy 2D detections the solver fits; 'ground truth': against "
        "the noise-free projection of the ground-truth joint (the meaningful one on synthetic data). "
        "map = without the MLE step, mle_map = with it. var = population variance (px^2).\n\n"
        + format_table(("scene", "stage", "reference", "mean", "min", "max", "var", "count"), stat_rows)
    )
    return a, b, targets


def scipy_solve(problem: PoseProblem, X0: np.ndarray) -> np.ndarray:
    """Per-person scipy TRF with a 2-point numerical Jacobian, default tolerances: (P, J, 3) -> (P, J, 3)."""
    out = []
    for p in range(len(X0)):
        one = problem.take(np.array([p]))
        res = least_squares(
            lambda x: residual_vector(x.reshape(1, -1, 3), one)[0], X0[p].ravel(), method="trf", jac="2-point"
        )
        out.append(res.x.reshape(-1, 3))
    return np.stack(out) if out else X0.copy()


def scipy_mle_map(stage: MAPReconstruction, poses2d: np.ndarray, bboxes: np.ndarray, rig: Rig) -> np.ndarray:
    """The mle_map stage with scipy in place of the batched solver: (V, P, J, 3), (V, P, 4) -> (P, J, 4)."""
    und, proj = rig.undistort(poses2d), rig.projection_matrices()
    dlt = triangulate_dlt(und, proj, stage.min_views)
    X, placed = initial_poses(dlt, und, proj)
    idx = np.flatnonzero(placed)
    Xp, sub, boxes = X[idx], und[:, idx], np.asarray(bboxes, dtype=np.float64)[:, idx]
    for prior in stage.stages():
        Xp = scipy_solve(stage.problem(sub, boxes, proj, Xp, prior), Xp)
    X = X.copy()
    X[idx] = Xp
    conf = output_confidence(
        dlt[..., 3], und, placed, stage.output_min_views, stage.single_view_score, stage.unseen_score
    )
    return np.concatenate([np.where(conf[..., None] > 0, X, 0.0), conf[..., None]], axis=-1)


def best_ms(fn: Callable[[], np.ndarray], repeats: int) -> tuple[float, np.ndarray]:
    """Median ms over repeats of fn() and its last output."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times)), out


def mpjpe_mm(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean joint error (mm) over joints with confidence > 0: (P, J, 4), (P, J, 4) -> scalar."""
    ok = pred[..., 3] > 0
    return 1e3 * float(np.mean(np.linalg.norm(pred[..., :3] - gt[..., :3], axis=-1)[ok]))


def time_setting(stage: MAPReconstruction, persons: int, views: int, args: argparse.Namespace) -> dict:
    """Median ms per frame of ours and of per-person scipy, and both MPJPEs, on one crowd / rig size."""
    seed = args.seed + persons + 1000 * (views != 7)
    seq = generate_sequence(
        SyntheticConfig(
            seed=seed, num_frames=args.timing_frames, num_persons=persons, density=0.5, num_cameras=views, noise_px=5.0
        )
    )
    ours_ms, scipy_ms, e_ours, e_scipy, subset = [], [], [], [], persons
    for frame in seq.frames:
        assignment = OracleMatcher()(frame.views, seq.rig).assignment
        poses2d, boxes = gather_views(frame.views, assignment)
        gt = gt_for_assignment(frame, assignment)
        P = len(assignment)
        subset = min(P, args.scipy_max)
        t, out = best_ms(lambda: stage(poses2d, boxes, seq.rig).poses, args.repeats)
        ours_ms.append(t)
        t_s, out_s = best_ms(lambda: scipy_mle_map(stage, poses2d[:, :subset], boxes[:, :subset], seq.rig), 1)
        scipy_ms.append(t_s * P / subset)
        e_ours.append(mpjpe_mm(out[:subset], gt[:subset]))
        e_scipy.append(mpjpe_mm(out_s, gt[:subset]))
    o, s = float(np.median(ours_ms)), float(np.median(scipy_ms))
    note = f"timed on {subset} of {persons}, x {persons / subset:.1f}" if subset < persons else "all persons"
    return {"ours": o, "scipy": s, "note": note, "e_ours": float(np.mean(e_ours)), "e_scipy": float(np.mean(e_scipy))}


def timing_section(args: argparse.Namespace) -> tuple[str, list[str]]:
    """Section (c): time against persons (7 views) and against views (20 persons); the speed target lines."""
    stage, rows, lines = MLEMAPReconstruction(), [], []
    settings = [(n, 7) for n in (1, 10, 50, 100)] + [(20, v) for v in (2, 4, 8)]
    for n, views in settings:
        r = time_setting(stage, n, views, args)
        o, s = r["ours"], r["scipy"]
        rows.append(
            [n, views, f"{o:.2f}", f"{s:.1f}", r["note"], f"{s / o:.0f}", f"{r['e_ours']:.2f}", f"{r['e_scipy']:.2f}"]
        )
        if (n, views) == (100, 7):
            lines.append(
                f"- 100 persons in 7 views: mle_map {o:.2f} ms per frame on one core; target <= "
                f"{TARGET_MS:g} ms; ratio measured / target = {o / TARGET_MS:.2f} "
                f"({'MET' if o <= TARGET_MS else 'NOT MET'})"
            )
        lines.append(
            f"- {n} persons, {views} views: ours {s / o:.0f}x faster than per-person scipy (target >= "
            f"{TARGET_SPEEDUP:g}x, ratio {s / o / TARGET_SPEEDUP:.2f}: "
            f"{'MET' if s / o >= TARGET_SPEEDUP else 'NOT MET'}); MPJPE ours {r['e_ours']:.2f} vs "
            f"scipy {r['e_scipy']:.2f} mm (same persons)"
        )
    text = (
        f"### (c) Time per frame, mle_map (DLT + MLE + MAP), ring cameras, 0.5 persons/m2, 5 px, "
        f"median over {args.timing_frames} frames (ours: median of {args.repeats} repeats; scipy: 1 run)\n\n"
        "scipy: least_squares(method='trf', jac='2-point', default ftol/xtol/gtol 1e-8) per person on "
        "tests/oracles/pose_problem.residual_vector, same DLT start, MLE then MAP; with more than "
        f"{args.scipy_max} persons it is timed on the first {args.scipy_max} and scaled by P / "
        f"{args.scipy_max}, and both MPJPEs are over those persons.\n\n"
        + format_table(
            (
                "persons",
                "views",
                "ours ms",
                "scipy ms",
                "scipy timing",
                "speedup (x)",
                "MPJPE ours (mm)",
                "MPJPE scipy (mm)",
            ),
            rows,
        )
    )
    return text, lines


def swap_left_right(poses2d: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    """A copy of (V, P, J, 3) detections with the left and right joints of a share of them swapped."""
    out = poses2d.copy()
    swap = rng.random(poses2d.shape[:2]) < share
    out[swap] = poses2d[swap][:, flip_permutation()]
    return out


def robust_section(args: argparse.Namespace) -> str:
    """Section (d): the robust losses against 2D outliers (left/right swaps, as OpenPose makes them)."""
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
    return (
        "### (d) Robust losses against 2D outliers, ring (5 cams, 10 persons), 5 px, oracle matching, "
        f"{args.frames} frames\n\nA share of the detections (view, person) has its left and right joints "
        "swapped (data.keypoints.flip_permutation), the error OpenPose makes most; MPJPE (protocol) and PCP as "
        "in (a). robust_scale = 3 sigma (the config default).\n\n"
        + format_table(("swapped (%)", "stage", "MPJPE (mm)", "PCP (%)"), rows)
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options; --quick shrinks every section."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="few frames and repeats (a smoke run)")
    p.add_argument("--data", default="../shared/data", help="folder holding wildtrack/")
    p.add_argument("--out", default=None, help="also write the report to this markdown file")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    args.frames = 2 if args.quick else 10
    args.timing_frames, args.repeats = (1, 2) if args.quick else (3, 5)
    args.scipy_max = 5 if args.quick else 10
    return args


def main(argv: list[str] | None = None) -> str:
    """Run the three sections, print the report, write it to --out; return it."""
    args = parse_args(argv)
    start = time.perf_counter()
    a, b, gain_lines = accuracy_section(args)
    c, speed_lines = timing_section(args)
    d = robust_section(args)
    parts = [
        f"## Reconstruction benchmark (seed {args.seed}{', quick' if args.quick else ''})",
        a,
        b,
        c,
        d,
        "### Targets\n\n" + "\n".join(gain_lines + speed_lines),
        f"Total wall time {time.perf_counter() - start:.0f} s.",
    ]
    text = "\n\n".join(parts) + "\n"
    print(text)
    if args.out:
        atomic_write_text(args.out, text)
    return text


if __name__ == "__main__":
    main()
