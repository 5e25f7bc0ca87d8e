"""Matching + reconstruction time per frame of the default pipeline beside the earlier configurations, one core.

    python -m benchmarks.pipeline_speed [--repeats 5] [--data ../shared/data]

Settings: Shelf (frames 300-399, real OpenPose, PAF grouping done before timing) and 100 people in 7
ring views (0.5 per m^2, 4 frames). Configurations, timed interleaved in one process so that the
machine's state is shared: the default; the paper's (``matching=feet_paper reconstruction=paper``); the
earlier Shelf default (``matching=feet_epipolar reconstruction=paper``). Each pipeline runs a frame first
(compiled kernels loaded), then every configuration runs all frames ``--repeats`` times in turn; the
table holds the median ms per frame and the ratio to each earlier configuration.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from hydra.utils import instantiate  # noqa: E402

from evaluation.report import format_table  # noqa: E402
from reconstruction.pipeline import MultiViewPipeline  # noqa: E402

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
CONFIGS = {
    "default": [],
    "paper": ["matching=feet_paper", "reconstruction=paper"],
    "earlier Shelf default": ["matching=feet_epipolar", "reconstruction=paper"],
}


def settings(data: str) -> dict[str, list[str]]:
    """Setting label -> dataset overrides."""
    return {
        "Shelf 300-399": ["dataset=shelf", f"dataset.root={data}/shelf", "dataset.frames=0:100"],
        "100 people x 7 ring views": [
            "dataset.num_persons=100",
            "dataset.num_cameras=7",
            "dataset.density=0.5",
            "dataset.num_frames=4",
        ],
    }


def time_setting(overrides: list[str], repeats: int) -> dict[str, tuple[float, float]]:
    """Median (matching, reconstruction) ms per frame of every configuration on one setting."""
    sequence = instantiate(compose("eval", overrides=overrides).dataset, _convert_="all")
    pipes = {}
    for name, extra in CONFIGS.items():
        cfg = compose("eval", overrides=[*overrides, *extra])
        pipes[name] = MultiViewPipeline(sequence.rig, instantiate(cfg.matching), instantiate(cfg.reconstruction))
        pipes[name](sequence.frames[0])
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in pipes}
    for _ in range(repeats):
        for name, pipe in pipes.items():
            pipe.timings.clear()
            for frame in sequence.frames:
                pipe(frame)
            n = len(sequence.frames)
            runs[name].append((1e3 * pipe.timings["matching"] / n, 1e3 * pipe.timings["reconstruction"] / n))
    return {name: tuple(np.median(np.array(r), axis=0)) for name, r in runs.items()}


def main(argv: list[str] | None = None) -> str:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--data", default="../shared/data")
    args = parser.parse_args(argv)
    rows = []
    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        for label, overrides in settings(args.data).items():
            times = time_setting(overrides, args.repeats)
            total = {k: m + r for k, (m, r) in times.items()}
            for name, (m, r) in times.items():
                rows.append([label, name, m, r, total[name], total["default"] / total[name]])
    text = format_table(
        ["setting", "configuration", "matching ms", "reconstruction ms", "total ms", "default / this"],
        rows,
        floatfmt=".2f",
    )
    print(text)
    return text


if __name__ == "__main__":
    main()
