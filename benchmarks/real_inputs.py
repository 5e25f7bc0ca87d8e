"""Dev-set table: the default pipeline beside the paper's configuration and the baselines, same frames, same run.

Run from the repository root:

    python -m benchmarks.real_inputs [--sets shelf,panoptic,wildtrack,crowd] [--rows default,paper,...]
                                     [--crowd-frames 3] [--out FILE.md] [--data ../shared/data]

Dev sets: Shelf as shipped (real OpenPose BODY_25, feet included) and with the 6 foot keypoints removed
(``dataset.drop_feet=true``, ankles kept: what a COCO-17 detector gives); Panoptic band1 / band2 of
``panoptic_seq`` (20 consecutive frames, 5 HD cameras, 2D projected from the GT with 0 / 2 / 5 px noise,
no foot joints); Wildtrack (7 real cameras, synthetic bodies at the annotated positions, 5 px); the
synthetic crowd sweep of 10-400 people on the surveillance rig of ``configs/dataset/crowd.yaml``; the
speed setting of the issues, 100 people in 7 ring views (``timing``).

Rows (Hydra overrides of ``configs/eval.yaml``): ``default`` (no override: tracking and its temporal
evidence included), ``default, tracking off`` (every frame on its own), ``default + fix_sides`` (left / right labels settled
across views, reconstruction/solver/side_labels.py; off by default), ``paper`` (the paper's exact
method: feet-only matching and MLE -> MAP with the population bone table and the fixed 2D sigma model),
``epipolar + vanilla``, ``epipolar + mle_map`` and ``oracle + vanilla`` (ground-truth identities group the
detections: the upper bound; not on Shelf, whose detections carry no identities); every row but
``default`` and ``default + fix_sides`` runs with ``tracking=off``.

Columns: people found = GT persons matched by a prediction within ``evaluation.max_dist_m`` (%), and of
those seen in >= 2 views (%); false positives = predictions matched to no GT person; matching pair
precision / recall against GT identities; absolute MPJPE (mm, GT-matched, no root alignment, all joints
valid in both); PCP (%, alpha 0.5; Shelf: the strict Shelf protocol averaged over actors 1-3);
ms / frame = matching + reconstruction + tracking (Shelf: + PAF grouping), one BLAS thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, as the speed targets are stated

import argparse  # noqa: E402
import copy  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from hydra.utils import instantiate  # noqa: E402
from tqdm import tqdm  # noqa: E402

from data.formats.atomic_io import atomic_write_text  # noqa: E402
from evaluation.pose3d import Pose3DEvaluator  # noqa: E402
from evaluation.report import format_table  # noqa: E402
from evaluation.sequence_eval import evaluate_sequence  # noqa: E402
from reconstruction.pipeline import MultiViewPipeline  # noqa: E402

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
ROWS = {
    "default": [],
    "default, tracking off": ["tracking=off"],
    "default + fix_sides": ["reconstruction.fix_sides=true"],
    "paper": ["matching=feet_paper", "reconstruction=paper", "tracking=off"],
    "epipolar + vanilla": ["matching=epipolar", "reconstruction=vanilla", "tracking=off"],
    "epipolar + mle_map": ["matching=epipolar", "reconstruction=mle_map", "tracking=off"],
    "oracle + vanilla": ["matching=oracle", "reconstruction=vanilla", "tracking=off"],
}
ROW_KEYS = {
    "default": "default",
    "untracked": "default, tracking off",
    "fix_sides": "default + fix_sides",
    "paper": "paper",
    "epipolar_vanilla": "epipolar + vanilla",
    "epipolar_mle_map": "epipolar + mle_map",
    "oracle": "oracle + vanilla",
}
CROWD_SIZES = (10, 50, 100, 200, 400)
HEADERS = (
    "dev set",
    "configuration",
    "found (%)",
    "found of >=2 views (%)",
    "false pos.",
    "pair P (%)",
    "pair R (%)",
    "MPJPE (mm)",
    "PCP (%)",
    "ms / frame",
)


def dev_sets(names: list[str], data: str, crowd_frames: int) -> dict[str, list[str]]:
    """Dev set label -> dataset overrides."""
    sets: dict[str, list[str]] = {}
    if "shelf" in names:
        shelf = ["dataset=shelf", f"dataset.root={data}/shelf"]
        sets["Shelf"] = shelf
        sets["Shelf, feet removed"] = [*shelf, "dataset.drop_feet=true"]
    if "panoptic" in names:
        for seq in ("160906_band1", "160906_band2"):
            for noise in (0, 2, 5):
                sets[f"Panoptic {seq[-5:]} {noise} px"] = [
                    "dataset=panoptic",
                    f"dataset.root={data}/panoptic_seq",
                    f"dataset.sequence={seq}",
                    f"dataset.noise_px={noise}",
                ]
    if "wildtrack" in names:
        sets["Wildtrack 5 px"] = ["dataset=wildtrack", f"dataset.root={data}/wildtrack"]
    if "timing" in names:
        sets["ring 100 people x 7 views"] = [
            "dataset=synthetic",
            "dataset.num_persons=100",
            "dataset.num_cameras=7",
            "dataset.density=0.5",
            "dataset.num_frames=3",
        ]
    if "crowd" in names:
        for n in CROWD_SIZES:
            sets[f"crowd {n} people"] = [
                "dataset=crowd",
                f"dataset.num_persons={n}",
                f"dataset.num_frames={crowd_frames}",
            ]
    return sets


def detectable_persons(sequence) -> tuple[int, int]:
    """(GT person-frames seen in >= 2 views, all GT person-frames) of a sequence with identities."""
    seen, total = 0, 0
    for frame in sequence.frames:
        if frame.gt_ids is None:
            continue
        ids = np.concatenate([v.person_ids for v in frame.views]) if frame.views else np.zeros(0, int)
        counts = {int(i): int(np.sum(ids == i)) for i in frame.gt_ids}
        seen += sum(c >= 2 for c in counts.values())
        total += len(frame.gt_ids)
    return seen, total


def run_row(sequence, cfg) -> list:
    """One table row's values: the pipeline of cfg on a fresh copy of the sequence."""
    sequence = copy.deepcopy(sequence)
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    report = evaluate_sequence(sequence, pipeline, Pose3DEvaluator(**cfg.evaluation), progress=False)
    m, frames = report.metrics, max(len(sequence.frames), 1)
    ms = (
        1e3
        * (
            sum(report.timings.get(k, 0.0) for k in ("matching", "reconstruction", "tracking"))
            + sequence.stage_seconds.get("grouping", 0.0)
        )
        / frames
    )
    if "shelf" in report.protocols:
        shelf = report.protocols["shelf"]
        return ["-", "-", "-", "-", "-", "-", shelf["ours"]["strict"]["average"]["average"], ms]
    seen, _ = detectable_persons(sequence)
    found = m.get("num_matched", 0)
    pct = lambda k: 100.0 * m[k] if k in m else "-"  # noqa: E731
    return [
        m.get("recall", "-"),
        100.0 * found / seen if seen else "-",
        m.get("num_pred", 0) - found,
        pct("matching_precision"),
        pct("matching_recall"),
        m.get("mpjpe_mm", "-"),
        m.get("pcp_average", "-"),
        ms,
    ]


def main(argv: list[str] | None = None) -> list[list]:
    """Print (and optionally write) the dev-set table; returns its rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sets", default="shelf,panoptic,wildtrack,crowd,timing")
    parser.add_argument("--rows", default=",".join(ROW_KEYS), help=f"comma list of {', '.join(ROW_KEYS)}")
    parser.add_argument("--match", default="", help="only the dev sets whose label contains this text")
    parser.add_argument("--crowd-frames", type=int, default=3)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows_wanted = [ROW_KEYS[r] for r in args.rows.split(",")]
    table = []
    t_start = time.perf_counter()
    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        chosen = {
            k: v for k, v in dev_sets(args.sets.split(","), args.data, args.crowd_frames).items() if args.match in k
        }
        for label, dataset in tqdm(chosen.items(), desc="dev sets"):
            base = compose(config_name="eval", overrides=dataset)
            sequence = instantiate(base.dataset, _convert_="all")
            for row in rows_wanted:
                if row.startswith("oracle") and label.startswith("Shelf"):
                    table.append([label, row, *["-"] * 8])
                    continue
                cfg = compose(config_name="eval", overrides=[*dataset, *ROWS[row]])
                table.append([label, row, *run_row(sequence, cfg)])
    text = format_table(HEADERS, table, floatfmt=".2f")
    text += f"\n\n({time.perf_counter() - t_start:.0f} s)"
    print(text)
    if args.out:
        atomic_write_text(Path(args.out), text + "\n")
    return table


if __name__ == "__main__":
    main()
