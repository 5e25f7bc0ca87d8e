"""Dev-set table: the default pipeline beside the paper's configuration and the baselines, same frames, same run."""

from benchmarks import common  # isort: split

import argparse
import time

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig
from tqdm import tqdm

from benchmarks import input_variants as variants
from data.frame_inputs import clean_frames
from data.multiview import Sequence
from evaluation.report import format_table

ROWS = {
    "default": ("default", []),
    "untracked": ("default, tracking off", ["tracking=off"]),
    "fix_sides": ("default + fix_sides", ["reconstruction.fix_sides=true"]),
    "paper": ("paper", ["matching=feet_paper", "reconstruction=paper", "tracking=off"]),
    "epipolar_vanilla": ("epipolar + vanilla", ["matching=epipolar", "reconstruction=vanilla", "tracking=off"]),
    "epipolar_mle_map": ("epipolar + mle_map", ["matching=epipolar", "reconstruction=mle_map", "tracking=off"]),
    "oracle": ("oracle + vanilla", ["matching=oracle", "reconstruction=vanilla", "tracking=off"]),
}
CROWD_SIZES = (10, 50, 100, 200, 400)
VARIANTS = {  # label: (the dev set it is made from, the change of its 2D)
    "Shelf, scores x4": ("Shelf", lambda s: variants.rescored(s, lambda x: 4.0 * x)),
    "Shelf, scores ^3": ("Shelf", lambda s: variants.rescored(s, lambda x: x**3)),
    "Shelf, doubled 0.3 px": ("Shelf", variants.doubled),
    "Panoptic band1 detector-like": ("Panoptic band1 0 px", variants.detector_like),
    "Panoptic band2 detector-like": ("Panoptic band2 0 px", variants.detector_like),
}
HEADERS = ("dev set", "configuration", "found (%)", "found of >=2 views (%)", "false pos.", "pair P (%)")
HEADERS += ("pair R (%)", "MPJPE (mm)", "PCP (%)", "ms / frame")


def dev_sets(names: list[str], data: str, crowd_frames: int) -> dict[str, list[str]]:
    """Dev set label -> dataset overrides."""
    sets: dict[str, list[str]] = {}
    if "shelf" in names:
        sets["Shelf"] = common.shelf(data)
        sets["Shelf, feet removed"] = [*common.shelf(data), "dataset.drop_feet=true"]
    if "panoptic" in names:
        sets.update(common.panoptic_sets(data, (0, 2, 5)))
    if "wildtrack" in names:
        sets["Wildtrack 5 px"] = ["dataset=wildtrack", f"dataset.root={data}/wildtrack"]
    if "timing" in names:
        ring = ["dataset.num_persons=100", "dataset.num_cameras=7", "dataset.density=0.5", "dataset.num_frames=3"]
        sets["ring 100 people x 7 views"] = ["dataset=synthetic", *ring]
    if "crowd" in names:
        for n in CROWD_SIZES:
            sets[f"crowd {n} people"] = common.crowd(n, crowd_frames)
    if "variants" in names:
        bases = {"Shelf": common.shelf(data), **common.panoptic_sets(data, (0,))}
        sets.update({label: bases[base] for label, (base, _) in VARIANTS.items()})
    return sets


def detectable_persons(sequence: Sequence) -> int:
    """GT person-frames seen in >= 2 views of a sequence with identities."""
    seen = 0
    for frame in sequence.frames:
        if frame.gt_ids is None:
            continue
        ids = np.concatenate([v.person_ids for v in frame.views]) if frame.views else np.zeros(0, int)
        seen += sum(int(np.sum(ids == i)) >= 2 for i in frame.gt_ids)
    return seen


def run_row(sequence: Sequence, cfg: DictConfig) -> list:
    """One table row's values: the pipeline of cfg on a fresh copy of the sequence."""
    report, ms = common.evaluate(sequence, cfg, grouping=True)
    if "shelf" in report.protocols:
        return ["-"] * 6 + [report.protocols["shelf"]["ours"]["strict"]["average"]["average"], ms]
    m, seen = report.metrics, detectable_persons(sequence)
    found, get = m.get("num_matched", 0), lambda k: m.get(k, "-")
    pairs = [100.0 * m[k] if k in m else "-" for k in ("matching_precision", "matching_recall")]
    share = 100.0 * found / seen if seen else "-"
    return [get("recall"), share, m.get("num_pred", 0) - found, *pairs, get("mpjpe_mm"), get("pcp_average"), ms]


def main(argv: list[str] | None = None) -> list[list]:
    """Print (and optionally write) the dev-set table; returns its rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sets", default="shelf,panoptic,wildtrack,crowd,timing,variants")
    parser.add_argument("--rows", default=",".join(ROWS), help=f"comma list of {', '.join(ROWS)}")
    parser.add_argument("--match", default="", help="only the dev sets whose label contains this text")
    parser.add_argument("--crowd-frames", type=int, default=3)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--out", default=None)
    parser.add_argument("overrides", nargs="*", help="eval.yaml overrides added to every row (matching.x=1 ...)")
    args = parser.parse_args(argv)
    rows_wanted = [ROWS[r] for r in args.rows.split(",")]
    table = []
    t_start = time.perf_counter()
    with initialize_config_dir(str(common.CONFIG_DIR), version_base="1.3"):
        chosen = {
            k: v for k, v in dev_sets(args.sets.split(","), args.data, args.crowd_frames).items() if args.match in k
        }
        for label, dataset in tqdm(chosen.items(), desc="dev sets"):
            base = compose(config_name="eval", overrides=dataset)
            sequence = instantiate(base.dataset, _convert_="all")
            sequence = VARIANTS[label][1](sequence) if label in VARIANTS else sequence
            sequence, _ = clean_frames(sequence, base.inputs.max_detections_per_frame, base.inputs.near_duplicate)
            for row, overrides in rows_wanted:
                if row.startswith("oracle") and label.startswith("Shelf"):  # Shelf's detections carry no identities
                    table.append([label, row, *["-"] * 8])
                    continue
                cfg = compose(config_name="eval", overrides=[*dataset, *overrides, *args.overrides])
                table.append([label, row, *run_row(sequence, cfg)])
    common.emit(f"{format_table(HEADERS, table, floatfmt='.2f')}\n\n({time.perf_counter() - t_start:.0f} s)", args.out)
    return table


if __name__ == "__main__":
    main()
