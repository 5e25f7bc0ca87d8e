"""Per-frame time by stage of a tree's multi-view pipeline, this tree's or an older revision's."""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy loads; not benchmarks.common, which an older tree lacks

import argparse  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

STAGES = ("grouping", "matching", "reconstruction", "tracking")


def settings(data: str, crowd_frames: int = 3, quick: bool = True) -> dict[str, list[str]]:
    """Setting label -> eval.yaml overrides: Shelf, 100 people in 7 ring views, the crowd sweep (5 and 10 views)."""
    ring = ["dataset.num_persons=100", "dataset.num_cameras=7", "dataset.density=0.5", "dataset.num_frames=4"]
    out = {"Shelf 300-600": ["dataset=shelf", f"dataset.root={data}/shelf"], "100 people x 7 ring views": ring}
    for views in (5, 10):
        for n in (10, 100, 400) if quick else (10, 50, 100, 200, 400):
            sizes = [f"dataset.num_persons={n}", f"dataset.num_cameras={views}", f"dataset.num_frames={crowd_frames}"]
            out[f"crowd {n} x {views} views"] = ["dataset=crowd", *sizes]
    return out


def build_pipeline(cfg: Any, rig: Any) -> Any:
    """The tree's MultiViewPipeline of an eval config, with a tracker where the tree and the config have one."""
    from hydra.utils import instantiate

    from reconstruction.pipeline import MultiViewPipeline

    tracking = cfg.get("tracking")
    tracker = instantiate(tracking) if tracking is not None and tracking.get("_target_") else None
    parts = (rig, instantiate(cfg.matching), instantiate(cfg.reconstruction))
    return MultiViewPipeline(*parts, tracker) if tracker is not None else MultiViewPipeline(*parts)


def stage_times(sequence: Any, cfg: Any, repeats: int) -> np.ndarray:
    """Per-frame seconds of matching, reconstruction, tracking: (repeats * F, 3); a fresh pipeline per repeat."""
    rows = []
    for _ in range(repeats):
        build_pipeline(cfg, sequence.rig)(sequence.frames[0])
        pipe = build_pipeline(cfg, sequence.rig)
        if hasattr(pipe, "calibrate_noise"):  # the run's noise model fitted first (once per run, not timed here)
            pipe.calibrate_noise(sequence.frames)
        for frame in sequence.frames:
            before = [pipe.timings.get(s, 0.0) for s in STAGES[1:]]
            pipe(frame)
            rows.append([pipe.timings.get(s, 0.0) - b for s, b in zip(STAGES[1:], before)])
    return np.array(rows)


def stage_rows(
    data: str, only: str, repeats: int, crowd_frames: int = 3, quick: bool = True, grouping: Any = None
) -> list:
    """Rows (setting, frames, then ms of grouping, the stages, total; NaN: not timed) of the labels containing only."""
    from hydra import compose
    from hydra.errors import HydraException
    from hydra.utils import instantiate

    rows = []
    for label, overrides in settings(data, crowd_frames, quick).items():
        if only not in label:
            continue
        try:
            cfg = compose("eval", overrides=overrides)
        except HydraException as err:  # an older tree without this dataset or key
            print(f"{label}: skipped, this tree's configs do not compose it ({err})", file=sys.stderr)
            continue
        sequence = instantiate(cfg.dataset, _convert_="all")
        per_frame = stage_times(sequence, cfg, repeats)
        grouped = grouping(label, cfg, sequence) if grouping is not None else None
        grouped = np.full(len(per_frame), np.nan) if grouped is None else grouped
        total = np.nan_to_num(grouped) + per_frame.sum(axis=1)
        medians = [np.median(grouped), *np.median(per_frame, axis=0), np.median(total)]
        rows.append([label, len(sequence.frames), *(float(1e3 * m) for m in medians)])
    return rows


def markdown(header: list[str], rows: list[list]) -> str:
    """A markdown table, floats with 2 decimals, NaN as '-' (an older tree may lack evaluation.report.format_table)."""
    cells = [[("-" if v != v else f"{v:.2f}") if isinstance(v, float) else str(v) for v in row] for row in rows]
    lines = ["| " + " | ".join(row) + " |" for row in [header, *cells]]
    return "\n".join([lines[0], "|" + "|".join("---" for _ in header) + "|", *lines[1:]])


def main(argv: list[str] | None = None) -> str:
    """Print the table of the settings whose label contains --only."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="100 people", help="the settings whose label contains this text")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--cpu", type=int, default=None, help="pin the process to this CPU (Linux)")
    args = parser.parse_args(argv)
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    from hydra import initialize_config_dir

    with initialize_config_dir(os.path.abspath("configs"), version_base=None):
        rows = stage_rows(args.data, args.only, args.repeats)
    if not rows:
        parser.error(f"no setting that this tree composes has {args.only!r} in its label")
    text = markdown(["setting", "frames", *STAGES, "total"], rows)
    print(f"Per frame by stage, ms (median over frames x {args.repeats} repeats, one core)\n\n{text}")
    return text


if __name__ == "__main__":
    main()
