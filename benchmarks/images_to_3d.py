"""Images to 3D: a rendered synthetic scene (the SPPE beside the render's ground-truth 2D), and real images (--real).

Scene: ``dataset=synthetic dataset.render=true`` (ring cameras, 1280 x 720); every row runs the same frames
through eval.py's ``run`` with the default matching, MAP and tracking. Rows (ROWS): the render's exact 2D (the
upper bound of any 2D stage), the SPPE on the render's boxes with flip test, with separate_pairs + fix_sides,
with boxes jittered by 10 % (a detector's error), without flip test, and the simulated 2D detections of
``render=false``. Columns: per-view COCO OKS AP (COCO-23 sigmas: all 23 / body 17 / foot 6 joints), absolute
MPJPE (mm, all 23 joints, GT-matched within 0.5 m), PCP (%, alpha 0.5), GT persons found (%), ms per frame of
the 2D stage (images + detector + SPPE) and of the rest (matching, MAP, tracking).

--real: Shelf frame 572's five real images (images_000572, rescaled from the stretched 1920 x 1080 to the calibrated
1032 x 776) through pose2d=blazepose + detector=blazepose, beside the pipeline fed the shipped OpenPose detections of
that frame, both scored by the Shelf protocol (strict PCP, actors 1 and 3: actor 2 is not in frame 572); and COCO OKS AP
of each pose model on the COCO-WholeBody sample (4 images, 14 persons; pycocotools, COCO-23 sigmas) on the ground-truth
boxes and on the detector's boxes. CPU seconds per stage.
"""

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

from hydra import compose, initialize_config_dir

from data.formats.atomic_io import atomic_write_text
from evaluation.report import format_table
from run_folders import register_resolvers

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
SPPE = ["dataset.render=true", "pose2d=sppe", "detector=gt"]
ROWS = {
    "gt2d": ("2D = render's ground truth (upper bound)", ["dataset.render=true"]),
    "sppe": ("SPPE, flip test, boxes of the render", SPPE),
    "sppe_sides": (
        "SPPE + separate_pairs + fix_sides",
        [*SPPE, "pose2d.separate_pairs=true", "reconstruction.fix_sides=true"],
    ),
    "sppe_jitter": ("SPPE, flip test, boxes jittered 10 %", [*SPPE, "detector.jitter=0.1"]),
    "sppe_noflip": ("SPPE, no flip test, boxes of the render", [*SPPE, "pose2d.flip_test=false"]),
    "simulated": ("simulated detections, 2 px (render=false)", []),
}
TWO_D_STAGES = ("images", "detector", "pose2d")


def run_row(overrides: list[str]) -> tuple[dict, dict]:
    """eval.py's run on the composed config -> (metrics, timings in s); its printed report is swallowed."""
    report = run_report(overrides)
    return report.metrics, report.timings


def run_report(overrides: list[str]):
    """eval.py's run on the composed config -> its SequenceReport; the printed report is swallowed."""
    import eval as eval_script  # the entry point's run(), so the benchmark measures what a user runs

    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("eval", overrides=["progress=false", *overrides])
    with tempfile.TemporaryDirectory() as out, contextlib.redirect_stdout(io.StringIO()):
        return eval_script.run(cfg, Path(out))


def table_row(name: str, metrics: dict, timings: dict, frames: int) -> list:
    """One printed row of a run's metrics and timings."""
    ap = [metrics.get(f"pose2d_AP_{s}") for s in ("all", "body", "foot")]
    two_d = sum(timings.get(k, 0.0) for k in TWO_D_STAGES)
    rest = sum(timings.get(k, 0.0) for k in ("matching", "reconstruction", "tracking"))
    return [
        name,
        *("-" if a is None else f"{a:.3f}" for a in ap),
        metrics["mpjpe_mm"],
        metrics["pcp_average"],
        metrics["recall"],
        1000 * two_d / frames if any(k in timings for k in TWO_D_STAGES) else "-",
        1000 * rest / frames,
    ]


def main(argv: list[str] | None = None) -> None:
    """Run the chosen rows, print the table and write it to --out."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", help="a train.py checkpoint (.pth / .ckpt); needed by the sppe rows")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--persons", type=int, default=10)
    parser.add_argument("--cameras", type=int, default=5)
    parser.add_argument("--rows", default=",".join(ROWS), help=f"comma-separated, of {', '.join(ROWS)}")
    parser.add_argument("--out", help="also write the table (markdown) here")
    parser.add_argument("--real", action="store_true", help="the real-image tables instead (needs requirements-models)")
    parser.add_argument("--set", action="append", default=[], help="an eval.yaml override for every row (repeatable)")
    args = parser.parse_args(argv)
    register_resolvers()
    if args.real:
        from benchmarks.real_images import real_tables

        text = real_tables(args.checkpoint)
        print(text)
        if args.out:
            atomic_write_text(args.out, text + "\n")
        return
    rows = [r.strip() for r in args.rows.split(",") if r.strip()]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        parser.error(f"unknown rows {unknown}; choose from {list(ROWS)}")
    if any(r.startswith("sppe") for r in rows) and not args.checkpoint:
        parser.error("the sppe rows need --checkpoint")
    scene = [
        f"dataset.num_frames={args.frames}",
        f"dataset.num_persons={args.persons}",
        f"dataset.num_cameras={args.cameras}",
    ]
    table = []
    for row in rows:
        name, overrides = ROWS[row]
        if row.startswith("sppe"):
            overrides = [*overrides, f"pose2d.checkpoint={args.checkpoint}"]
        metrics, timings = run_row(scene + overrides + args.set)
        table.append(table_row(name, metrics, timings, args.frames))
        print(f"{name}: done", flush=True)
    header = ["2D source", "AP all", "AP body", "AP foot", "MPJPE mm", "PCP %", "found %", "2D ms/frame", "3D ms/frame"]
    scene = f"{args.persons} persons, {args.cameras} ring cameras 1280 x 720, {args.frames} frames"
    text = f"Rendered synthetic scene: {scene}; default matching + MAP + tracking; AP per view (COCO-23 OKS), MPJPE "
    text += f"absolute (all 23 joints, GT-matched), PCP alpha 0.5\n\n{format_table(header, table, floatfmt='.2f')}"
    print(text)
    if args.out:
        atomic_write_text(args.out, text + "\n")


if __name__ == "__main__":
    main()
