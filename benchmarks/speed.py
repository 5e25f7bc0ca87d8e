"""Speed of the default pipeline: per-frame time by stage, and whole-process times.

    python -m benchmarks.speed [--repeats 3] [--crowd-frames 3] [--skip-process] [--quick] [--only TEXT]
                               [--cpu N] [--out FILE.md]

Table 1, per frame by stage (median over frames x repeats, ms, one core, the default ``configs/eval.yaml`` with
tracking): Shelf 300-600 (real OpenPose BODY_25: PAF grouping, then matching, MAP, tracking), 100 people in 7
ring views and the crowd sweep on the surveillance rig of ``configs/dataset/crowd.yaml`` (10-400 people, 5 and
10 views); settings and timing as benchmarks/frame_times.py. Table 2, whole process in fresh subprocesses:
``python eval.py`` and the Shelf evaluation warm (numba cache filled; median of ``--repeats``; on ``--cpu``) and
the first run of a fresh install (a new, empty ``NUMBA_CACHE_DIR``; on every core, as a user runs it).
"""

from benchmarks import common  # isort: split

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from benchmarks.frame_times import STAGES, settings, stage_times
from data.formats.fourd_detections import load_4dassoc_detections
from evaluation.report import format_table


def shelf_grouping_times(cfg, rig, repeats: int) -> np.ndarray:
    """Seconds per Shelf frame of the configured PAF grouping of every view: (repeats * F,)."""
    folder = Path(cfg.dataset.root) / cfg.dataset.detections
    views = [load_4dassoc_detections(folder / f"{name}.txt", rig.cameras[v].size) for v, name in enumerate(rig.names)]
    ds, grouper = cfg.dataset, instantiate(cfg.dataset.grouper)
    keys = dict(min_paf=ds.min_paf, min_joints=ds.min_joints, min_mean_score=ds.min_mean_score, margin=ds.bbox_margin)
    frames = list(zip(*views))
    grouper(frames[0][0], **keys)
    out = []
    for _ in range(repeats):
        for frame in frames:
            t0 = time.perf_counter()
            for view in frame:
                grouper(view, **keys)
            out.append(time.perf_counter() - t0)
    return np.array(out)


def stage_rows(data: str, crowd_frames: int, repeats: int, quick: bool, only: str | None = None) -> list[list]:
    """Table 1's rows: setting, frames, grouping, matching, reconstruction, tracking, total (ms; NaN: none)."""
    rows = []
    for label, overrides in settings(data, crowd_frames, quick).items():
        if only is not None and only not in label:
            continue
        cfg = compose("eval", overrides=overrides)
        sequence = instantiate(cfg.dataset, _convert_="all")
        per_frame = stage_times(sequence, cfg, repeats)
        grouping = np.full(len(per_frame), np.nan)
        if label.startswith("Shelf"):
            grouping = shelf_grouping_times(cfg, sequence.rig, repeats)
        total = np.nan_to_num(grouping) + per_frame.sum(axis=1)
        medians = [np.median(grouping), *np.median(per_frame, axis=0), np.median(total)]
        rows.append([label, len(sequence.frames), *(1e3 * m for m in medians)])
    return rows


def eval_seconds(args: list[str], env: dict[str, str], runs: str, all_cores: bool = False) -> float:
    """Wall seconds of one ``python eval.py ARGS`` from the repository root, its outputs in a new folder under runs;
    all_cores: on every core of the machine, not only those this process is pinned to (--cpu)."""
    command = [sys.executable, "eval.py", *args, f"hydra.run.dir={tempfile.mkdtemp(dir=runs)}"]
    every = set(range(os.cpu_count() or 1))
    unpin = (lambda: os.sched_setaffinity(0, every)) if all_cores and hasattr(os, "sched_setaffinity") else None
    return common.process_seconds(command, common.ROOT, env, unpin)


def process_rows(data: str, repeats: int) -> list[list]:
    """Table 2: (command, median seconds)."""
    env, commands = dict(os.environ), {"python eval.py": ["progress=false"]}
    commands["python eval.py dataset=shelf"] = [*common.shelf(data), "progress=false"]
    runs: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as out:
        cold = lambda: {**env, "NUMBA_CACHE_DIR": tempfile.mkdtemp(dir=out)}
        for name, args in commands.items():
            eval_seconds(args, env, out)  # fills the numba cache of this checkout
            runs[f"{name} (warm)"] = [eval_seconds(args, env, out) for _ in range(repeats)]
        for name, args in commands.items():
            runs[f"{name}, empty numba cache (all cores)"] = [
                eval_seconds(args, cold(), out, True) for _ in range(repeats)
            ]
    return [[label, float(np.median(seconds))] for label, seconds in runs.items()]


def dashes(rows: list[list]) -> list[list]:
    """Rows with NaN cells shown as '-'."""
    return [["-" if isinstance(c, float) and np.isnan(c) else c for c in row] for row in rows]


def main(argv: list[str] | None = None) -> str:
    """Print (and with --out, write) the tables."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--crowd-frames", type=int, default=3)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--cpu", type=int, default=None, help="pin the process to this CPU (Linux)")
    parser.add_argument("--quick", action="store_true", help="crowd sweep at 10, 100 and 400 people only")
    parser.add_argument("--skip-process", action="store_true", help="no whole-process table")
    parser.add_argument("--only", default=None, help="only the settings whose label contains this text")
    parser.add_argument("--out", default=None, help="also write the tables to this markdown file")
    args = parser.parse_args(argv)
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    with initialize_config_dir(str(common.CONFIG_DIR), version_base="1.3"):
        stages = stage_rows(args.data, args.crowd_frames, args.repeats, args.quick, args.only)
    parts = [
        "Per frame by stage, ms (median over frames x repeats, one core; tracking on)",
        format_table(["setting", "frames", *STAGES, "total"], dashes(stages), floatfmt=".2f"),
    ]
    if not args.skip_process:
        parts += [
            f"Whole process, seconds (median of {args.repeats} fresh subprocesses)",
            format_table(["command", "seconds"], process_rows(args.data, args.repeats), floatfmt=".2f"),
        ]
    return common.emit("\n\n".join(parts), args.out)


if __name__ == "__main__":
    main()
