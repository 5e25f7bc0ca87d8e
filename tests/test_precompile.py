"""reconstruction.precompile: every kernel a run calls is compiled (or loaded) once at start, with a notice."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from reconstruction.precompile import NOTICE

ROOT = Path(__file__).resolve().parents[1]
KERNEL_MODULE = """
import numpy as np
from numba import njit


@njit(cache=True)
def twice(x):
    return 2.0 * x


@njit(cache=True)
def square(x):
    return x * x


def warm_up_twice():
    twice(np.float64(2.0))


def warm_up_square():
    square(np.float64(2.0))
"""
PRECOMPILE_TWO = """
import sys
import precompile_kernels
from reconstruction import precompile

precompile.warm_ups = lambda: [precompile_kernels.warm_up_twice, precompile_kernels.warm_up_square]
if sys.argv[1] == "probe":
    print(precompile.kernels_ready(precompile.warm_ups()))
else:
    print(precompile.precompile(workers=int(sys.argv[1])))
"""


def run_precompile(tmp_path: Path, argument: str) -> list[str]:
    """PRECOMPILE_TWO in a fresh process with its own numba cache in tmp_path -> its stdout lines."""
    (tmp_path / "precompile_kernels.py").write_text(KERNEL_MODULE)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    done = subprocess.run(
        [sys.executable, "-c", PRECOMPILE_TWO, argument], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.splitlines()


def cached_kernels(tmp_path: Path) -> int:
    return len(list((tmp_path / "numba").rglob("*.nbi")))


@pytest.mark.parametrize("workers", [1, 2])
def test_the_first_call_compiles_with_the_notice_the_second_loads_quietly(tmp_path, workers):
    # workers=2: each warm-up compiles in a forked worker, which writes the cache this process loads from
    assert run_precompile(tmp_path, str(workers)) == [NOTICE, "True"]
    assert cached_kernels(tmp_path) == 2
    assert run_precompile(tmp_path, str(workers)) == ["False"]


def test_the_readiness_probe_compiles_nothing(tmp_path):
    assert run_precompile(tmp_path, "probe") == ["False"]
    assert cached_kernels(tmp_path) == 0
    run_precompile(tmp_path, "1")
    assert run_precompile(tmp_path, "probe") == ["True"]


SPECIALISATIONS = """
import sys
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from numba.core.registry import CPUDispatcher

from reconstruction.pipeline import MultiViewPipeline
from reconstruction.precompile import precompile


def counts():
    kernels = {}
    for name, module in list(sys.modules.items()):
        if module is not None and name.split(".")[0] in ("data", "models", "reconstruction", "tracking", "evaluation"):
            for obj in vars(module).values():
                if isinstance(obj, CPUDispatcher):
                    kernels[obj.py_func.__module__ + "." + obj.__name__] = len(obj.signatures)
    return kernels


precompile()
before = counts()
with initialize_config_dir(config_dir=sys.argv[1], version_base=None):
    for overrides in sys.argv[2:]:
        cfg = compose("eval", overrides=overrides.split())
        sequence = instantiate(cfg.dataset, _convert_="all")
        pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
        for frame in sequence.frames[:3]:
            pipeline(frame)
after = counts()
print({k: (before.get(k, 0), n) for k, n in after.items() if n != before.get(k, 0)})
"""


def test_the_warm_ups_compile_every_kernel_a_run_calls():
    # a kernel type the warm-ups miss would compile in the middle of a run, after the notice
    settings = [
        "dataset.num_frames=3",
        "dataset.num_persons=12 dataset.num_cameras=5 dataset.num_frames=3 dataset.miss_rate=0.2",
        "dataset=wildtrack",  # lens distortion
        "matching=feet_paper tracking=off dataset.num_frames=3",
        f"dataset=shelf paths.data_dir={ROOT.parent / 'shared' / 'data'}",
    ]
    done = subprocess.run(
        [sys.executable, "-c", SPECIALISATIONS, str(ROOT / "configs"), *settings],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().splitlines()[-1] == "{}"
