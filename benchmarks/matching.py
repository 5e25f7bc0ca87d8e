"""Cross-view matching benchmark: evidence (the default) / feet / feet_distinct / feet_epipolar / epipolar / ransac /
oracle on synthetic bodies, as markdown tables."""

from benchmarks import common  # isort: split

import argparse
import time
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from data.geometry.calibration import load_wildtrack, load_wildtrack_positions
from data.geometry.camera import Rig
from data.keypoints import FOOT_JOINTS
from data.multiview import ViewDetections
from data.synthetic import SyntheticConfig, generate_sequence
from evaluation.correspondence import CorrespondenceCounts, correspondence_counts
from evaluation.report import format_table
from reconstruction.matching import (
    EpipolarMatcher,
    EvidenceMatcher,
    FeetEpipolarMatcher,
    FeetMatcher,
    OracleMatcher,
    RansacMatcher,
)
from reconstruction.precompile import precompile

MATCHERS = ("evidence", "feet", "feet_distinct", "feet_epipolar", "epipolar", "ransac", "oracle")
FEET_DISTINCT = {"pixel_sigma": 5.0, "margin": 4.0}  # the keys of configs/matching/feet_distinct.yaml
SWEEP_AREA = (-4.5, 4.5, -4.5, 4.5)
HEADERS = ("setting", "matcher", "precision (%)", "recall (%)", "persons pure+complete (%)", "ms / frame")
RANSAC_MAX_PEOPLE = 40  # the density sweep's ransac rows stop here: its time grows steeply with the people
Frames = list[list[ViewDetections]]


def make_matchers() -> dict[str, Callable]:
    """Fresh matchers with their default settings."""
    return {
        "evidence": EvidenceMatcher(),
        "feet": FeetMatcher(),
        "feet_distinct": FeetMatcher(**FEET_DISTINCT),
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
        ms, matches = common.timed(lambda: matcher(views, rig))
        times.append(ms)
        counts = counts + correspondence_counts(matches.assignment, [v.person_ids for v in views])
    return counts, times


def setting_rows(label: str, frames: Frames, rig: Rig, skip: dict[str, str]) -> list[list]:
    """One table row per matcher for one setting; a matcher named in skip gets its reason instead."""
    rows = []
    for name, matcher in make_matchers().items():
        if name in skip:
            rows.append([label, name, skip[name], "-", "-", "-"])
            continue
        c, t = run_matcher(matcher, frames, rig)
        rows.append([label, name, 100 * c.precision, 100 * c.recall, 100 * c.recovered_share, float(np.mean(t))])
    return rows


def wildtrack_table(args: argparse.Namespace) -> str:
    """Section (a): synthetic bodies at the real annotated positions, seen by the real Wildtrack rig."""
    root = Path(args.data) / "wildtrack"
    positions = load_wildtrack_positions(root / "gt_positions_mvdet.txt")
    chosen = sorted(positions)[: args.frames]
    rig, rows = load_wildtrack(root), []
    for noise in tqdm((5.0, 2.0, 10.0), desc="wildtrack"):
        scenes = [common.wildtrack_scene(root, [positions[f]], noise, args.seed + k) for k, f in enumerate(chosen)]
        people = np.mean([len(positions[f]) for f in chosen])
        label = f"{noise:g} px, {len(chosen)} frames, {people:.1f} people"
        rows += setting_rows(label, [scene.frames[0].views for scene in scenes], rig, {})
    title = "### (a) Wildtrack rig (7 cameras), synthetic bodies at annotated positions, occlusion on"
    return f"{title}\n\n{format_table(HEADERS, rows)}"


def density_table(args: argparse.Namespace) -> str:
    """Section (b): 10-80 people in one fixed area, 5 ring cameras, noise and hidden feet varied."""
    area_m2 = (SWEEP_AREA[1] - SWEEP_AREA[0]) * (SWEEP_AREA[3] - SWEEP_AREA[2])
    settings = [(n, noise, hidden) for n in (10, 20, 40, 80) for noise in (2.0, 5.0, 10.0) for hidden in (0.0, 0.3)]
    rows = []
    for n, noise, hidden in tqdm(settings, desc="density sweep"):
        size = dict(num_frames=args.sweep_frames, num_persons=n, area=SWEEP_AREA, num_cameras=5)
        seq = generate_sequence(SyntheticConfig(seed=args.seed + n, noise_px=noise, **size))
        rng = np.random.default_rng([args.seed, n, int(noise), int(100 * hidden)])
        frames = [hide_feet(fr.views, hidden, rng) for fr in seq.frames]
        skip = {"ransac": f"skipped (> {RANSAC_MAX_PEOPLE} people)"} if n > RANSAC_MAX_PEOPLE else {}
        label = f"{n} p ({n / area_m2:.2f}/m2), {noise:g} px, feet hidden {100 * hidden:.0f}%"
        rows += setting_rows(label, frames, seq.rig, skip)
    title = f"### (b) Density sweep: 5-camera ring, fixed area {area_m2:.0f} m2, {args.sweep_frames} frames per setting"
    return f"{title}\n\n{format_table(HEADERS, rows)}"


def timing_table(args: argparse.Namespace) -> str:
    """Section (c): ms per frame vs people (7 views) and vs views (20 people)."""
    settings = [(n, 7) for n in (5, 10, 20, 50, 100)] + [(20, v) for v in (2, 4, 6, 8)]
    ransac_max = 20 if args.quick else 50
    rows = []
    for n, v in tqdm(settings, desc="timing"):
        size = dict(num_frames=args.timing_frames, num_persons=n, density=0.5, num_cameras=v)
        seq = generate_sequence(SyntheticConfig(seed=args.seed + 7 * n + v, noise_px=2.0, **size))
        frames = [fr.views for fr in seq.frames]
        dets = np.mean([len(d) for views in frames for d in views])
        row: list = [n, v, f"{dets:.1f}"]
        for name, matcher in make_matchers().items():
            if name == "ransac" and n > ransac_max:
                row.append(f"skipped (> {ransac_max} people)")
                continue
            repeats = 1 if name == "ransac" else args.repeats  # per frame: the median of repeats calls
            row.append(float(np.median([common.timed(lambda: matcher(v, seq.rig), repeats)[0] for v in frames])))
        rows.append(row)
    headers = ("people", "views", "detections / view", *(f"{m} ms" for m in MATCHERS))
    return (
        f"### (c) Matching time per frame (ms, one core), ring rig, 0.5 people/m2, median over "
        f"{args.timing_frames} frames x {args.repeats} repeats (ransac 1)\n\n"
        + format_table(headers, rows, floatfmt=".2f")
    )


def main(argv: list[str] | None = None) -> str:
    """Run the chosen sections, print the tables and write them to --out; return them."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="few frames and repeats (a smoke run)")
    p.add_argument("--frames", type=int, default=None, help="Wildtrack frames (default 20, quick 3)")
    p.add_argument("--data", default="../shared/data", help="folder holding wildtrack/")
    p.add_argument("--out", default=None, help="also write the tables to this markdown file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sections", default="abc", help="which sections to run, e.g. 'a' or 'bc'")
    args = p.parse_args(argv)
    precompile()  # the matchers' kernels compiled or loaded before any frame is timed
    args.frames = args.frames if args.frames is not None else (3 if args.quick else 20)
    args.sweep_frames = 1 if args.quick else 5
    args.timing_frames, args.repeats = (1, 2) if args.quick else (5, 9)
    start = time.perf_counter()
    sections = {"a": wildtrack_table, "b": density_table, "c": timing_table}
    parts = [f"## Matching benchmark (seed {args.seed}{', quick' if args.quick else ''})"]
    parts += [table(args) for key, table in sections.items() if key in args.sections]
    return common.emit("\n\n".join([*parts, f"Total wall time {time.perf_counter() - start:.0f} s."]), args.out)


if __name__ == "__main__":
    main()
