"""What the one-core benchmarks share: thread pinning (import it before numpy), timers, dev sets, runs, output."""

import os

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))

import copy  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import numpy as np  # noqa: E402

from data.formats.atomic_io import atomic_write_text  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = ROOT / "configs"
PIPELINE_STAGES = ("matching", "reconstruction", "tracking")
WILDTRACK_AREA = (-3.0, 9.0, -9.0, 27.0)


def shelf(data: str) -> list[str]:
    """eval.yaml overrides of Shelf 300-600 (real OpenPose BODY_25)."""
    return ["dataset=shelf", f"dataset.root={data}/shelf"]


def crowd(persons: int, frames: int) -> list[str]:
    """eval.yaml overrides of the synthetic crowd on the surveillance rig of configs/dataset/crowd.yaml."""
    return ["dataset=crowd", f"dataset.num_persons={persons}", f"dataset.num_frames={frames}"]


def panoptic_sets(data: str, noises: tuple[float, ...]) -> dict[str, list[str]]:
    """Label -> eval.yaml overrides of panoptic_seq's band1 and band2 at every noise level (px)."""
    sets = {}
    for sequence in ("160906_band1", "160906_band2"):
        for noise in noises:
            where = [f"dataset.root={data}/panoptic_seq", f"dataset.sequence={sequence}"]
            sets[f"Panoptic {sequence[-5:]} {noise} px"] = ["dataset=panoptic", *where, f"dataset.noise_px={noise}"]
    return sets


def wildtrack_scene(root: Path, positions: list, noise: float, seed: int) -> Any:
    """Synthetic bodies at Wildtrack's annotated positions (a list per frame), its 7 cameras, noise px: a Sequence."""
    from data.geometry.calibration import load_wildtrack
    from data.synthetic import SyntheticConfig, generate_sequence

    rig = dict(rig=str(root), rig_format="wildtrack")
    cfg = SyntheticConfig(seed=seed, positions=positions, area=WILDTRACK_AREA, min_spacing_m=0.0, noise_px=noise, **rig)
    return generate_sequence(cfg, rig=load_wildtrack(root))


def evaluate(sequence: Any, cfg: Any, grouping: bool = False) -> tuple[Any, float]:
    """cfg's pipeline on a copy of sequence -> (SequenceReport, ms per frame of the stages [+ PAF grouping])."""
    from evaluation.pose3d import Pose3DEvaluator
    from evaluation.sequence_eval import evaluate_sequence
    from reconstruction.pipeline import MultiViewPipeline
    from reconstruction.precompile import precompile

    precompile()  # the kernels compiled or loaded before the first frame is timed
    sequence = copy.deepcopy(sequence)
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    report = evaluate_sequence(sequence, pipeline, Pose3DEvaluator(**cfg.evaluation), progress=False)
    seconds = sum(report.timings.get(k, 0.0) for k in PIPELINE_STAGES)
    if grouping:
        seconds += sequence.stage_seconds.get("grouping", 0.0)
    return report, 1e3 * seconds / max(len(sequence.frames), 1)


def timed(fn: Callable[[], Any], repeats: int = 1) -> tuple[float, Any]:
    """Median ms over repeats calls of fn, and its last output."""
    times, out = [], None
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        out = fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times)), out


def process_seconds(command: list[str], cwd: Path, env: dict[str, str], preexec: Callable | None = None) -> float:
    """Wall seconds of one subprocess; RuntimeError with its stderr's tail when it fails."""
    t0 = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, preexec_fn=preexec)
    seconds = time.perf_counter() - t0
    if done.returncode:
        raise RuntimeError(f"{' '.join(command)} failed in {cwd}:\n{done.stderr[-2000:]}")
    return seconds


def emit(text: str, out: str | Path | None) -> str:
    """Print text and, given a path, write it there too; -> text."""
    print(text)
    if out:
        atomic_write_text(Path(out), text + "\n")
    return text
