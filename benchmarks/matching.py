"""Cross-view matching benchmark: evidence (the default) / feet / feet_distinct / feet_epipolar / epipolar / ransac / oracle
on synthetic bodies, as markdown tables.

Run from the repository root (as a module, so that ``data``, ``reconstruction`` ... import):

    python -m benchmarks.matching [--quick] [--frames N] [--out FILE.md] [--data ../shared/data]
                                  [--skip-ransac-above 40] [--all] [--feet-args k1=1,gate=0.8]

(a) Wildtrack: the real 7-camera rig with synthetic bodies at the annotated ground positions of the
    first N annotated frames (one one-frame sequence each; the positions hook does not enforce
    ``min_spacing_m``, and it is set to 0 anyway since the annotations come as close as 0.09 m).
(b) Density sweep: a 5-camera ring around a FIXED 9 x 9 m area (40 people = 0.49 per m^2; the ring
    radius follows the area, so it is fixed too), 10-80 people, 2D noise 2/5/10 px, 0 or 30 % of the
    detections with their 6 foot joints hidden (ankles kept).
(c) Timing: matching ms per frame vs people (7 views) and vs views (20 people), median over repeats.

Precision / recall are over cross-view detection pairs and "pure+complete" is the share of persons
recovered exactly (evaluation.correspondence); ms is the matcher call only (time.perf_counter).
BLAS / OpenMP are pinned to one thread before numpy is imported: the timings are per core.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core: timings comparable with the 20 ms target, no BLAS thread noise

import argparse  # noqa: E402
import ast  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from data.formats.atomic_io import atomic_write_text  # noqa: E402
from data.geometry.calibration import load_wildtrack, load_wildtrack_positions  # noqa: E402
from data.geometry.camera import Rig  # noqa: E402
from data.keypoints import FOOT_JOINTS  # noqa: E402
from data.multiview import ViewDetections  # noqa: E402
from data.synthetic import SyntheticConfig, generate_sequence  # noqa: E402
from evaluation.correspondence import CorrespondenceCounts, correspondence_counts  # noqa: E402
from evaluation.report import format_table  # noqa: E402
from reconstruction.matching import (  # noqa: E402
    EpipolarMatcher,
    EvidenceMatcher,
    FeetEpipolarMatcher,
    FeetMatcher,
    OracleMatcher,
    RansacMatcher,
    evidence,  # noqa: E402
)

MATCHERS = ("evidence", "feet", "feet_distinct", "feet_epipolar", "epipolar", "ransac", "oracle")
FEET_DISTINCT = {"pixel_sigma": 5.0, "margin": 4.0}  # the keys of configs/matching/feet_distinct.yaml
WILDTRACK_AREA = (-3.0, 9.0, -9.0, 27.0)
SWEEP_AREA = (-4.5, 4.5, -4.5, 4.5)
TARGET_MS = 20.0
HEADERS = ("setting", "matcher", "precision (%)", "recall (%)", "persons pure+complete (%)", "ms / frame")
NOISE_NOTE = "Noise: 2D SD = px * (depth / 5 m) ** {exponent:g} (data.synthetic noise_depth_exponent)."
Frames = list[list[ViewDetections]]


def parse_kv(text: str) -> dict[str, object]:
    """'k1=1,gate=0.8,foot_rule=mean' -> {'k1': 1, 'gate': 0.8, 'foot_rule': 'mean'}."""
    out: dict[str, object] = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        try:
            out[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            out[key.strip()] = value.strip()
    return out


def make_matchers(feet_kwargs: dict[str, object]) -> dict[str, Callable]:
    """Fresh matchers with their default settings (feet and feet_distinct with feet_kwargs on top)."""
    evidence.warm_up()  # the compiled kernels loaded before any matcher is timed
    return {
        "evidence": EvidenceMatcher(),
        "feet": FeetMatcher(**feet_kwargs),
        "feet_distinct": FeetMatcher(**{**FEET_DISTINCT, **feet_kwargs}),
        "feet_epipolar": FeetEpipolarMatcher(),
        "epipolar": EpipolarMatcher(),
        "ransac": RansacMatcher(),
        "oracle": OracleMatcher(),
    }


def hide_feet(views: list[ViewDetections], fraction: float, rng: np.random.Generator) -> list[ViewDetections]:
    """Copies of the views with the 6 foot joints (17..22) of a random share of detections missing (0)."""
    out = []
    for v in views:
        kp = v.keypoints.copy()
        hit = rng.random(len(kp)) < fraction
        kp[np.ix_(hit, FOOT_JOINTS)] = 0.0  # score 0 = missing; pixels 0 as the generator writes them
        out.append(ViewDetections(kp, v.bboxes, v.scores, v.person_ids, v.occluded))
    return out


def run_matcher(matcher: Callable, frames: Frames, rig: Rig) -> tuple[CorrespondenceCounts, list[float]]:
    """Summed correspondence counts and per-frame matching times (ms) of one matcher over frames."""
    counts, times = CorrespondenceCounts(), []
    for views in frames:
        t0 = time.perf_counter()
        assignment = matcher(views, rig).assignment
        times.append(1e3 * (time.perf_counter() - t0))
        counts = counts + correspondence_counts(assignment, [v.person_ids for v in views])
    return counts, times


def setting_rows(label: str, frames: Frames, rig: Rig, feet_kwargs: dict, skip: dict[str, str]) -> list[list]:
    """One table row per matcher for one setting; a matcher named in skip gets its reason instead."""
    rows = []
    for name, matcher in make_matchers(feet_kwargs).items():
        if name in skip:
            rows.append([label, name, skip[name], "-", "-", "-"])
            continue
        c, t = run_matcher(matcher, frames, rig)
        rows.append([label, name, 100 * c.precision, 100 * c.recall, 100 * c.recovered_share, float(np.mean(t))])
    return rows


def wildtrack_table(args: argparse.Namespace) -> str:
    """Section (a): synthetic bodies at the real annotated positions, seen by the real Wildtrack rig."""
    root = Path(args.data) / "wildtrack"
    rig = load_wildtrack(root)
    positions = load_wildtrack_positions(root / "gt_positions_mvdet.txt")
    chosen = sorted(positions)[: args.frames]
    rows = []
    for noise in tqdm((5.0, 2.0, 10.0), desc="wildtrack"):
        frames = []
        for k, f in enumerate(chosen):
            cfg = SyntheticConfig(
                seed=args.seed + k,
                positions=[positions[f]],
                area=WILDTRACK_AREA,
                min_spacing_m=0.0,
                rig=str(root),
                rig_format="wildtrack",
                noise_px=noise,
                noise_depth_exponent=args.noise_depth_exponent,
            )
            frames.append(generate_sequence(cfg, rig=rig).frames[0].views)
        people = np.mean([len(positions[f]) for f in chosen])
        rows += setting_rows(
            f"{noise:g} px, {len(chosen)} frames, {people:.1f} people", frames, rig, args.feet_kwargs, {}
        )
    return (
        "### (a) Wildtrack rig (7 cameras), synthetic bodies at annotated positions, occlusion on\n\n"
        + NOISE_NOTE.format(exponent=args.noise_depth_exponent)
        + "\n\n"
        + format_table(HEADERS, rows)
    )


def density_table(args: argparse.Namespace) -> str:
    """Section (b): 10-80 people in one fixed area, 5 ring cameras, noise and hidden feet varied."""
    area_m2 = (SWEEP_AREA[1] - SWEEP_AREA[0]) * (SWEEP_AREA[3] - SWEEP_AREA[2])
    settings = [(n, noise, hidden) for n in (10, 20, 40, 80) for noise in (2.0, 5.0, 10.0) for hidden in (0.0, 0.3)]
    rows = []
    for n, noise, hidden in tqdm(settings, desc="density sweep"):
        cfg = SyntheticConfig(
            seed=args.seed + n,
            num_frames=args.sweep_frames,
            num_persons=n,
            area=SWEEP_AREA,
            num_cameras=5,
            noise_px=noise,
            noise_depth_exponent=args.noise_depth_exponent,
        )
        seq = generate_sequence(cfg)
        rng = np.random.default_rng([args.seed, n, int(noise), int(100 * hidden)])
        frames = [hide_feet(fr.views, hidden, rng) for fr in seq.frames]
        skip = (
            {"ransac": f"skipped (> {args.skip_ransac_above} people)"}
            if n > args.skip_ransac_above and not args.all
            else {}
        )
        label = f"{n} p ({n / area_m2:.2f}/m2), {noise:g} px, feet hidden {100 * hidden:.0f}%"
        rows += setting_rows(label, frames, seq.rig, args.feet_kwargs, skip)
    return (
        f"### (b) Density sweep: 5-camera ring, fixed area {area_m2:.0f} m2, "
        f"{args.sweep_frames} frames per setting\n\n"
        + NOISE_NOTE.format(exponent=args.noise_depth_exponent)
        + "\n\n"
        + format_table(HEADERS, rows)
    )


def median_ms(matcher: Callable, frames: Frames, rig: Rig, repeats: int) -> float:
    """Median over frames of the median over repeats of one matcher call (ms)."""
    per_frame = []
    for views in frames:
        t = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            matcher(views, rig)
            t.append(1e3 * (time.perf_counter() - t0))
        per_frame.append(float(np.median(t)))
    return float(np.median(per_frame))


def timing_table(args: argparse.Namespace) -> tuple[str, tuple[float, float]]:
    """Section (c): ms per frame vs people (7 views) and vs views (20 people); also evidence and feet ms at 100 x 7."""
    settings = [(n, 7) for n in (5, 10, 20, 50, 100)] + [(20, v) for v in (2, 4, 6, 8)]
    ransac_max = 10**9 if args.all else (20 if args.quick else 50)
    rows, feet_100 = [], (float("nan"), float("nan"))
    for n, v in tqdm(settings, desc="timing"):
        cfg = SyntheticConfig(
            seed=args.seed + 7 * n + v,
            num_frames=args.timing_frames,
            num_persons=n,
            density=0.5,
            num_cameras=v,
            noise_px=2.0,
        )
        seq = generate_sequence(cfg)
        frames = [fr.views for fr in seq.frames]
        dets = np.mean([len(d) for views in frames for d in views])
        row: list = [n, v, f"{dets:.1f}"]
        for name, matcher in make_matchers(args.feet_kwargs).items():
            if name == "ransac" and n > ransac_max:
                row.append(f"skipped (> {ransac_max} people)")
                continue
            row.append(median_ms(matcher, frames, seq.rig, 1 if name == "ransac" else args.repeats))
        if (n, v) == (100, 7):
            feet_100 = (row[3], row[4])  # evidence, feet
        rows.append(row)
    headers = ("people", "views", "detections / view", *(f"{m} ms" for m in MATCHERS))
    text = (
        f"### (c) Matching time per frame (ms, one core), ring rig, 0.5 people/m2, median over "
        f"{args.timing_frames} frames x {args.repeats} repeats (ransac 1)\n\n"
        + format_table(headers, rows, floatfmt=".2f")
    )
    return text, feet_100


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options; --quick shrinks every section."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="few frames and repeats (a smoke run)")
    p.add_argument("--frames", type=int, default=None, help="Wildtrack frames (default 20, quick 3)")
    p.add_argument("--data", default="../shared/data", help="folder holding wildtrack/")
    p.add_argument("--out", default=None, help="also write the tables to this markdown file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip-ransac-above", type=int, default=40, help="density sweep: no ransac above this many people")
    p.add_argument("--all", action="store_true", help="run ransac everywhere")
    p.add_argument(
        "--feet-args",
        default="",
        help="FeetMatcher keyword arguments of the feet and feet_distinct rows, e.g. k1=1,gate=0.8",
    )
    p.add_argument(
        "--noise-depth-exponent",
        type=float,
        default=1.0,
        help="2D noise SD = px * (depth / 5 m) ** this (data.synthetic); 0 = same pixels at every depth",
    )
    p.add_argument("--sections", default="abc", help="which sections to run, e.g. 'a' or 'bc'")
    args = p.parse_args(argv)
    args.frames = args.frames if args.frames is not None else (3 if args.quick else 20)
    args.sweep_frames = 1 if args.quick else 5
    args.timing_frames, args.repeats = (1, 2) if args.quick else (5, 9)
    args.feet_kwargs = parse_kv(args.feet_args)
    return args


def main(argv: list[str] | None = None) -> None:
    """Run the chosen sections, print the tables and write them to --out."""
    args = parse_args(argv)
    start = time.perf_counter()
    parts = [
        f"## Matching benchmark (seed {args.seed}{', quick' if args.quick else ''}"
        f"{', feet ' + args.feet_args if args.feet_args else ''})"
    ]
    if "a" in args.sections:
        parts.append(wildtrack_table(args))
    if "b" in args.sections:
        parts.append(density_table(args))
    if "c" in args.sections:
        text, feet_100 = timing_table(args)
        parts += [
            text,
            f"Matching, 100 people in 7 views, ms per frame on one core: evidence (the default) "
            f"{feet_100[0]:.2f}, feet {feet_100[1]:.2f} (ratio {feet_100[0] / feet_100[1]:.2f}); "
            f"feet target <= {TARGET_MS:g} ms, ratio measured / target = {feet_100[1] / TARGET_MS:.2f}",
        ]
    parts.append(f"Total wall time {time.perf_counter() - start:.0f} s.")
    text = "\n\n".join(parts) + "\n"
    print(text)
    if args.out:
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
