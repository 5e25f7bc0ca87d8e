"""Speed of the default pipeline: per-frame time by stage, and whole-process times."""

from benchmarks import common  # isort: split

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from hydra import initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig

from benchmarks.frame_times import STAGES, markdown, stage_rows
from data.formats.fourd_detections import load_4dassoc_detections
from data.multiview import Sequence
from evaluation.report import format_table


def shelf_grouping(label: str, cfg: DictConfig, sequence: Sequence, repeats: int) -> np.ndarray | None:
    """Seconds per Shelf frame of the configured PAF grouping of every view: (repeats * F,); None elsewhere."""
    if not label.startswith("Shelf"):
        return None
    folder, rig = Path(cfg.dataset.root) / cfg.dataset.detections, sequence.rig
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


def eval_seconds(args: list[str], env: dict[str, str], runs: str, all_cores: bool = False) -> float:
    """Wall seconds of one ``python eval.py ARGS``, outputs under runs; all_cores: not only the pinned (--cpu) cores."""
    command = [sys.executable, "eval.py", *args, f"hydra.run.dir={tempfile.mkdtemp(dir=runs)}"]
    every = set(range(os.cpu_count() or 1))
    unpin = (lambda: os.sched_setaffinity(0, every)) if all_cores and hasattr(os, "sched_setaffinity") else None
    return common.process_seconds(command, common.ROOT, env, unpin)


def process_rows(data: str, repeats: int) -> list[list]:
    """Table 2: (command, median seconds)."""
    env, shelf = dict(os.environ), [*common.shelf(data), "progress=false"]
    commands = {"python eval.py": ["progress=false"], "python eval.py dataset=shelf": shelf}
    runs: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as out:
        cold = lambda: {**env, "NUMBA_CACHE_DIR": tempfile.mkdtemp(dir=out)}
        for name, args in commands.items():
            eval_seconds(args, env, out)  # fills the numba cache of this checkout
            runs[f"{name} (warm)"] = [eval_seconds(args, env, out) for _ in range(repeats)]
        for name, args in commands.items():
            first = [eval_seconds(args, cold(), out, True) for _ in range(repeats)]  # a fresh install's first run
            runs[f"{name}, empty numba cache (all cores)"] = first
    return [[label, float(np.median(seconds))] for label, seconds in runs.items()]


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
    grouping = lambda label, cfg, sequence: shelf_grouping(label, cfg, sequence, args.repeats)
    with initialize_config_dir(str(common.CONFIG_DIR), version_base="1.3"):
        stages = stage_rows(args.data, args.only or "", args.repeats, args.crowd_frames, args.quick, grouping)
    parts = [
        "Per frame by stage, ms (median over frames x repeats, one core; tracking on)",
        markdown(["setting", "frames", *STAGES, "total"], stages),
    ]
    if not args.skip_process:
        parts += [
            f"Whole process, seconds (median of {args.repeats} fresh subprocesses)",
            format_table(["command", "seconds"], process_rows(args.data, args.repeats), floatfmt=".2f"),
        ]
    return common.emit("\n\n".join(parts), args.out)


if __name__ == "__main__":
    main()
