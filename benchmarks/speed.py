"""Speed of the default pipeline: per-frame time by stage, in-run references, whole-process times.

Run from the repository root (one core: BLAS / numba threads are pinned to 1 before numpy is imported,
and the process to one CPU with ``--cpu``):

    python -m benchmarks.speed [--repeats 3] [--crowd-frames 3] [--skip-process] [--quick] [--only TEXT]
                               [--cpu N] [--out FILE.md]

Tables:

1. Per frame, by stage (median over frames x repeats, ms; the default configuration of ``configs/eval.yaml``,
   tracking on): Shelf 300-600 (real OpenPose BODY_25: PAF grouping per frame, then matching, MAP,
   tracking), 100 people in 7 ring views (the issues' speed setting) and the crowd sweep on the
   surveillance rig of ``configs/dataset/crowd.yaml`` (10-400 people, 5 and 10 views). Beside each, the
   stages issue 16's target counts ("counted": Shelf's every stage, the crowds' matching + MAP), the target and
   the figure the issue measured (at a9f9a65, which had no tracker; the C++ peer's 4.73 ms on Shelf).
2. References measured in the same run, same inputs: the PAF grouping against the frozen pure-Python
   grouping (``benchmarks/reference_grouping.py``).
3. Whole process, in fresh subprocesses: README command 1's ``python eval.py`` and the Shelf evaluation,
   warm (numba cache filled; median of ``--repeats``; on ``--cpu``), and the first run of a fresh clone (empty
   numba cache, ``NUMBA_CACHE_DIR`` set to a new folder; on every core, as a user runs it: every kernel compiles
   once at start, reconstruction/precompile.py).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from hydra.utils import instantiate  # noqa: E402

from benchmarks import reference_grouping  # noqa: E402
from benchmarks.frame_times import STAGES, settings, stage_times  # noqa: E402
from data.formats.atomic_io import atomic_write_text  # noqa: E402
from data.formats.fourd_detections import load_4dassoc_detections  # noqa: E402
from evaluation.report import format_table  # noqa: E402
from models.paf_grouping import group_people  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# Issue 16's targets (ms per frame, one core) and the figures it measured at a9f9a65.
TARGETS = {"Shelf 300-600": 2.4, "100 people x 7 ring views": 15.0, "crowd 400 x 10 views": 120.0}
ISSUE_FIGURES = {"Shelf 300-600": 4.86, "100 people x 7 ring views": 37.0}
# The stages each target counts: Shelf's grouping + matching + reconstruction + tracking; the crowds' "default
# matching + MAP" (a9f9a65, where the issue measured 37 ms = matching 12 + MAP 25, had no tracker).
TARGET_STAGES = {"Shelf 300-600": STAGES, "100 people x 7 ring views": STAGES[1:3], "crowd 400 x 10 views": STAGES[1:3]}
CPP_PEER_SHELF_MS = 4.73  # 4D Association's C++ (-O3), median ms per Shelf frame, as measured in issue 16
FIRST_RUN = "python eval.py, empty numba cache (all cores)"
PROCESS_TARGETS = {"python eval.py dataset=shelf (warm)": 2.0, FIRST_RUN: 30.0}
PROCESS_FIGURES = {"python eval.py dataset=shelf (warm)": 3.58, FIRST_RUN: 17.7}


def shelf_candidates(cfg, rig) -> list[list]:
    """The Shelf frames' ungrouped candidates: per frame, the cameras' FrameCandidates."""
    folder = Path(cfg.dataset.root) / cfg.dataset.detections
    cameras = [load_4dassoc_detections(folder / f"{name}.txt", rig.cameras[v].size) for v, name in enumerate(rig.names)]
    return [list(views) for views in zip(*cameras)]


def shelf_grouper(cfg):
    """The configured grouper with the dataset's grouping keys: FrameCandidates -> ViewDetections."""
    ds, grouper = cfg.dataset, instantiate(cfg.dataset.grouper)
    keys = dict(min_paf=ds.min_paf, min_joints=ds.min_joints, min_mean_score=ds.min_mean_score, margin=ds.bbox_margin)
    return lambda view: grouper(view, **keys)


def grouping_times(frames: list[list], grouper, repeats: int) -> np.ndarray:
    """Seconds per frame of grouping every view with grouper(FrameCandidates): (repeats * F,)."""
    grouper(frames[0][0])
    out = []
    for _ in range(repeats):
        for views in frames:
            t0 = time.perf_counter()
            for view in views:
                grouper(view)
            out.append(time.perf_counter() - t0)
    return np.array(out)


def counted_times(label: str, grouping: np.ndarray, per_frame: np.ndarray) -> np.ndarray:
    """Per frame, the sum of the stages the setting's target counts (TARGET_STAGES; the row shows its median, not a
    sum of medians): grouping (F,) (NaN: none), per_frame (F, 3) matching, reconstruction, tracking -> (F,), NaN
    for a setting without a target."""
    if label not in TARGET_STAGES:
        return np.full(len(per_frame), np.nan)
    times = np.nan_to_num(np.column_stack([grouping, per_frame]))
    return times[:, [STAGES.index(s) for s in TARGET_STAGES[label]]].sum(axis=1)


def stage_rows(
    data: str, crowd_frames: int, repeats: int, quick: bool, only: str | None = None
) -> tuple[list[list], dict]:
    """Table 1's rows, and the sequences and overrides of Shelf and the 100 x 7 setting for table 2."""
    rows, kept = [], {}
    for label, overrides in settings(data, crowd_frames, quick).items():
        if only is not None and only not in label:
            continue
        cfg = compose("eval", overrides=overrides)
        sequence = instantiate(cfg.dataset, _convert_="all")
        per_frame = stage_times(sequence, cfg, repeats)
        grouping = np.full(len(per_frame), np.nan)
        if label.startswith("Shelf"):
            grouping = grouping_times(shelf_candidates(cfg, sequence.rig), shelf_grouper(cfg), repeats)
            kept["shelf"] = (sequence, overrides)
        if label.startswith("100 people"):
            kept["ring100"] = (sequence, overrides)
        total = np.nan_to_num(grouping) + per_frame.sum(axis=1)
        counted = counted_times(label, grouping, per_frame)
        medians = [np.median(grouping), *np.median(per_frame, axis=0), np.median(total), np.median(counted)]
        figure = ISSUE_FIGURES.get(label, np.nan)
        target = TARGETS.get(label, np.nan)
        rows.append(
            [label, len(sequence.frames), *(1e3 * m for m in medians), target, figure, figure / (1e3 * medians[-1])]
        )
    return rows, kept


def reference_rows(kept: dict, repeats: int) -> list[list]:
    """Table 2: (what, setting, ours ms, reference ms, reference / ours)."""
    rows = []
    if "shelf" in kept:
        frames = shelf_candidates(compose("eval", overrides=kept["shelf"][1]), kept["shelf"][0].rig)
        ours, ref = interleaved(
            lambda: grouping_times(frames, lambda v: group_people(v.candidates, v.pafs), 1),
            lambda: grouping_times(frames, lambda v: reference_grouping.group_people(v.candidates, v.pafs), 1),
            repeats,
        )
        rows.append(["PAF grouping vs frozen pure Python", "Shelf 300-600", 1e3 * ours, 1e3 * ref, ref / ours])
    return rows


def interleaved(
    ours: Callable[[], np.ndarray], reference: Callable[[], np.ndarray], repeats: int
) -> tuple[float, float]:
    """Median seconds per frame of two timers run in turn `repeats` times (the machine's state shared)."""
    a, b = [], []
    for _ in range(repeats):
        a.append(ours())
        b.append(reference())
    return float(np.median(np.concatenate(a))), float(np.median(np.concatenate(b)))


def dashes(rows: list[list]) -> list[list]:
    """Rows with NaN cells (no figure, no target) shown as '-'."""
    return [["-" if isinstance(c, float) and np.isnan(c) else c for c in row] for row in rows]


def process_seconds(args: list[str], env: dict[str, str], runs: str, all_cores: bool = False) -> float:
    """Wall seconds of one `python eval.py ...` subprocess from the repository root, its outputs in a new folder
    under runs; all_cores: on every core of the machine, not only this process's (--cpu)."""
    command = [sys.executable, "eval.py", *args, f"hydra.run.dir={tempfile.mkdtemp(dir=runs)}"]
    every = set(range(os.cpu_count() or 1))
    unpin = (lambda: os.sched_setaffinity(0, every)) if all_cores and hasattr(os, "sched_setaffinity") else None
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, preexec_fn=unpin)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr[-2000:]}")
    return seconds


def process_rows(data: str, repeats: int) -> list[list]:
    """Table 3: (command, seconds, target, issue's figure, figure / this)."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as out:
        common = ["progress=false"]
        shelf = ["dataset=shelf", f"dataset.root={data}/shelf", *common]
        process_seconds(common, env, out)  # fills the numba cache of this checkout
        process_seconds(shelf, env, out)
        runs = {
            "python eval.py (warm)": [process_seconds(common, env, out) for _ in range(repeats)],
            "python eval.py dataset=shelf (warm)": [process_seconds(shelf, env, out) for _ in range(repeats)],
        }
        for name, args in (("python eval.py", common), ("python eval.py dataset=shelf", shelf)):
            cold = [{**env, "NUMBA_CACHE_DIR": tempfile.mkdtemp(dir=out)} for _ in range(repeats)]
            runs[f"{name}, empty numba cache (all cores)"] = [process_seconds(args, c, out, True) for c in cold]
    rows = []
    for label, seconds in runs.items():
        median = float(np.median(seconds))
        figure = PROCESS_FIGURES.get(label, np.nan)
        rows.append([label, median, PROCESS_TARGETS.get(label, np.nan), figure, figure / median])
    return rows


def main(argv: list[str] | None = None) -> str:
    """Print (and with --out, write) the three tables."""
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
    with initialize_config_dir(str(ROOT / "configs"), version_base="1.3"):
        stages, kept = stage_rows(args.data, args.crowd_frames, args.repeats, args.quick, args.only)
        references = reference_rows(kept, args.repeats)
    parts = [
        "Per frame by stage, ms (median over frames x repeats, one core; tracking on; target and figure: issue 16, "
        f"measured there at a9f9a65; the C++ peer 4D Association: {CPP_PEER_SHELF_MS} ms per Shelf frame; "
        "counted: the stages the target counts, Shelf all, the crowds matching + reconstruction)",
        format_table(
            ["setting", "frames", *STAGES, "total", "counted", "target", "issue's figure", "figure / counted"],
            dashes(stages),
            floatfmt=".2f",
        ),
    ]
    if references:
        parts += [
            "References in the same run, same inputs (ms per frame, median)",
            format_table(["what", "setting", "ours", "reference", "reference / ours"], references, floatfmt=".2f"),
        ]
    if not args.skip_process:
        parts += [
            f"Whole process, seconds (median of {args.repeats} fresh subprocesses)",
            format_table(
                ["command", "seconds", "target", "issue's figure", "figure / this"],
                dashes(process_rows(args.data, args.repeats)),
                floatfmt=".2f",
            ),
        ]
    text = "\n\n".join(parts)
    print(text)
    if args.out:
        atomic_write_text(args.out, text + "\n")
    return text


if __name__ == "__main__":
    main()
