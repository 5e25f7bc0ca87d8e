"""Per-frame latency of the streaming API (stream.Pipeline.step) on Shelf's 2D detections, beside the batch run:
``taskset -c 0 python -m benchmarks.stream_latency [--data ../shared/data] [--out table.md]``."""

from benchmarks import common  # isort: split

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig

import eval as eval_script
import stream
from evaluation.report import format_table
from run_folders import register_resolvers


def stream_times(cfg: DictConfig) -> tuple[dict[str, list[float]], list[float], float, int, float]:
    """Stream cfg's dataset: ({stage: ms per frame after the warm-up}, step() ms after it, ms of the warm-up's step,
    warm-up frames, Shelf's PAF grouping (done while loading) in mean ms per frame)."""
    sequence = instantiate(cfg.dataset, _convert_="all")
    pipe = stream.Pipeline.from_config(cfg, sequence)
    grouping = 1e3 * sequence.stage_seconds.get("grouping", 0.0) / len(sequence.frames)
    stages: dict[str, list[float]] = {}
    steps, warm_up = [], 0.0
    for frame in sequence.frames:
        t0 = time.perf_counter()
        results = pipe.step(frame)
        ms = 1e3 * (time.perf_counter() - t0)
        if len(results) > 1:
            warm_up = ms
        elif len(results) == 1:
            steps.append(ms)
            for stage, value in results[0].latency_ms.items():
                stages.setdefault(stage, []).append(value)
    return stages, steps, warm_up, stream.warmup_frames(pipe.pipeline), grouping


def batch_ms(cfg: DictConfig) -> tuple[float, float]:
    """eval.run's ms per frame of matching, reconstruction and tracking, and its noise calibration's ms (silenced)."""
    with tempfile.TemporaryDirectory() as out, contextlib.redirect_stdout(io.StringIO()):
        report = eval_script.run(cfg, Path(out))
    per_frame = 1e3 * sum(report.timings.get(k, 0.0) for k in common.PIPELINE_STAGES) / len(report.results)
    return per_frame, 1e3 * report.timings.get("noise calibration", 0.0)


def main() -> None:
    """Print (and --out: write) the table: per stage ms per frame, median and p95 after the warm-up."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default="../shared/data", help="the folder holding shelf/")
    parser.add_argument("--out", default=None, help="also write the table here")
    args = parser.parse_args()
    register_resolvers()
    with initialize_config_dir(config_dir=str(common.CONFIG_DIR), version_base="1.3"):
        cfg = compose("eval", overrides=[*common.shelf(args.data), "progress=false"])
    for _ in range(2):  # the first pass warms every cache; the second is timed
        stages, steps, warm_up, window, grouping = stream_times(cfg)
        batch = batch_ms(cfg)
    row = lambda name, v: [name, float(np.median(v)), float(np.percentile(v, 95)), float(np.mean(v))]
    rows = [["2D: PAF grouping (while loading)", "", "", grouping]]
    rows += [row(k, v) for k, v in stages.items()] + [row("step() total", steps)]
    rows += [["batch eval.run: matching + reconstruction + tracking", "", "", batch[0]]]
    rows += [[f"warm-up: the {window}th step() (calibrates, emits {window} frames)", warm_up, "", ""]]
    rows += [["batch eval.run: noise calibration (once)", batch[1], "", ""]]
    title = f"Shelf, {len(steps) + window} frames, stream.Pipeline.step after the {window}-frame warm-up (ms)"
    common.emit(
        f"{title}\n\n" + format_table(["stage", "median ms", "p95 ms", "mean ms"], rows, floatfmt=".2f"), args.out
    )


if __name__ == "__main__":
    main()
