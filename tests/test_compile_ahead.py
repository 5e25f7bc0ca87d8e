"""A first run with numba's cache cold: kernels run as Python while a background process compiles them."""

import importlib
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from numba.core.dispatcher import Dispatcher

import eval as eval_script
from reconstruction import compile_ahead
from reconstruction.compile_ahead import (
    cache_is_cold,
    interpret_until_compiled,
    kernels_interpreted,
    wait_for_background_compile,
)

ROOT = Path(__file__).resolve().parents[1]
KERNEL_MODULE = """
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def inverse(x):
    return 1.0 / x


@njit(cache=True)
def twice_inverse(x):
    return 2.0 * inverse(x)


def warm_up():
    twice_inverse(np.float64(2.0))
"""
USER_MODULE = "from {kernels} import twice_inverse\n"


def _fresh_package(tmp_path, monkeypatch, name: str):
    """A package of two cached kernels (one calling the other), never compiled, and a module that imported one."""
    package = tmp_path / name
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "kernels.py").write_text(textwrap.dedent(KERNEL_MODULE))
    (package / "user.py").write_text(USER_MODULE.format(kernels=f"{name}.kernels"))
    monkeypatch.syspath_prepend(str(tmp_path))
    return importlib.import_module(f"{name}.kernels"), importlib.import_module(f"{name}.user")


def _wait_until(condition, seconds: float = 120.0) -> None:
    end = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < end, "the background compile did not end"
        time.sleep(0.05)


@pytest.mark.skipif(compile_ahead._usable_cores() < 2, reason="interpreted only with a second usable core")
def test_kernels_run_as_python_until_the_background_compile_fills_the_cache(tmp_path, monkeypatch):
    kernels, user = _fresh_package(tmp_path, monkeypatch, "ahead_pkg_a")
    compiled = kernels.twice_inverse
    assert cache_is_cold(compiled)
    assert interpret_until_compiled("ahead_pkg_a.kernels:warm_up", compiled, ("ahead_pkg_a",))
    assert kernels_interpreted()
    assert not interpret_until_compiled("ahead_pkg_a.kernels:warm_up", compiled, ("ahead_pkg_a",))  # one at a time
    # every holder of a kernel, its own module and the importer, holds Python now; numpy's x / 0 gives inf, silently
    assert not isinstance(kernels.twice_inverse, Dispatcher) and not isinstance(user.twice_inverse, Dispatcher)
    assert not isinstance(kernels.inverse, Dispatcher)
    assert user.twice_inverse(np.float64(4.0)) == 0.5 and user.twice_inverse(np.float64(0.0)) == np.inf
    assert not compiled.signatures  # nothing compiled here
    _wait_until(lambda: not kernels_interpreted())
    assert user.twice_inverse is compiled and kernels.twice_inverse is compiled
    assert compiled(np.float64(4.0)) == 0.5
    assert compiled.stats.cache_hits and not compiled.stats.cache_misses  # the other process's code, from the cache
    assert not interpret_until_compiled("ahead_pkg_a.kernels:warm_up", compiled, ("ahead_pkg_a",))  # warm now


@pytest.mark.skipif(compile_ahead.fcntl is None or compile_ahead._usable_cores() < 2, reason="POSIX locks, 2 cores")
def test_a_second_first_run_waits_for_the_compile_that_holds_the_lock(tmp_path, monkeypatch):
    import fcntl

    kernels, user = _fresh_package(tmp_path, monkeypatch, "ahead_pkg_c")
    (tmp_path / "cache").mkdir()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))  # the lock's folder (numba read it at import)
    started = []
    monkeypatch.setattr(compile_ahead, "_start_detached", lambda *args: started.append(args))
    held = os.open(compile_ahead.lock_path("ahead_pkg_c.kernels:warm_up"), os.O_RDWR | os.O_CREAT)
    fcntl.flock(held, fcntl.LOCK_EX)  # another first run's background compile
    compiled = kernels.twice_inverse
    assert interpret_until_compiled("ahead_pkg_c.kernels:warm_up", compiled, ("ahead_pkg_c",))
    assert not started and not wait_for_background_compile("ahead_pkg_c.kernels:warm_up", timeout_s=0.2)  # held
    assert kernels_interpreted() and user.twice_inverse(np.float64(2.0)) == 1.0
    os.close(held)  # that compile ends
    _wait_until(lambda: not kernels_interpreted())
    assert wait_for_background_compile("ahead_pkg_c.kernels:warm_up", timeout_s=1.0)
    assert user.twice_inverse is compiled


def test_nothing_is_started_with_a_warm_cache_or_for_what_is_not_a_cached_kernel(tmp_path, monkeypatch):
    kernels, _ = _fresh_package(tmp_path, monkeypatch, "ahead_pkg_b")
    kernels.warm_up()  # compiled and cached here
    assert not cache_is_cold(kernels.twice_inverse)
    assert not interpret_until_compiled("ahead_pkg_b.kernels:warm_up", kernels.twice_inverse, ("ahead_pkg_b",))
    assert not cache_is_cold(len)
    assert not interpret_until_compiled("math:sqrt", len, ("math",))
    assert not kernels_interpreted()


def test_the_map_stage_takes_its_numpy_solver_while_kernels_are_interpreted(monkeypatch):
    from reconstruction.solver import map_solver

    poses2d, proj = map_solver._tiny_problem()
    boxes = np.tile([0.0, 0.0, 200.0, 400.0], (len(proj), 1, 1))
    reference = map_solver.MAPReconstruction(solver="numpy").solve(poses2d, boxes, proj, (False, True))[0]

    def compiled(*args, **kwargs):
        raise AssertionError("the compiled solver was called while the kernels are interpreted")

    monkeypatch.setattr(map_solver, "solve_poses_compiled", compiled)
    monkeypatch.setattr(map_solver, "kernels_interpreted", lambda: True)
    np.testing.assert_array_equal(
        map_solver.MAPReconstruction().solve(poses2d, boxes, proj, (False, True))[0], reference
    )


def test_a_first_run_reports_as_a_warm_one_and_leaves_the_cache_filled(tmp_path):
    # README command 1's run with an empty numba cache, then again: the same report, the second from the cache
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "PYTHONPATH": str(ROOT)}
    command = [sys.executable, "eval.py", "progress=false", "dataset.num_frames=3"]
    runs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        done = subprocess.run(
            [*command, f"hydra.run.dir={out}"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr
        runs.append((done.stdout, (out / "poses3d.json").read_text()))
        if k == 0:  # the background compile outlives the first run: wait for its cache
            assert wait_for_background_compile(eval_script.FIRST_RUN_COMPILE, tmp_path / "numba", 300.0)
    first, second = runs
    if compile_ahead._usable_cores() >= 2:
        assert "compile in a background process" in first[0]
    assert "background process" not in second[0]
    assert first[1] == second[1]  # poses3d.json, to its 1e-6 m rounding
    metrics = lambda text: text[text.index("Synthetic crowd") : text.index("Frames:")]  # noqa: E731 (not timings)
    assert metrics(first[0]) == metrics(second[0])


def test_a_module_that_imports_eval_keeps_its_kernels(monkeypatch):
    # the tests run eval.run() in-process: they must not swap this process's kernels for Python behind its back
    from omegaconf import OmegaConf

    calls = []
    monkeypatch.setattr(eval_script, "interpret_until_compiled", lambda *args: calls.append(args) or True)
    eval_script.start_compiles(OmegaConf.create({"compile_ahead": True}))
    assert not eval_script.AS_SCRIPT and not calls
    monkeypatch.setattr(eval_script, "AS_SCRIPT", True)  # as `python eval.py` runs it
    eval_script.start_compiles(OmegaConf.create({"compile_ahead": True}))
    eval_script.start_compiles(OmegaConf.create({"compile_ahead": False}))
    assert len(calls) == 1 and calls[0][0] == "eval:compile_kernels"


def test_a_stage_warms_its_kernels_up_only_when_they_are_compiled(monkeypatch):
    from reconstruction import compile_notice

    calls = []
    compile_notice.warm_up_kernels("test", lambda: calls.append("warm"))
    monkeypatch.setattr(compile_notice, "kernels_interpreted", lambda: True)  # a first run's Python kernels
    compile_notice.warm_up_kernels("test", lambda: calls.append("interpreted"))
    assert calls == ["warm"]


SPECIALISATIONS = """
import sys
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from numba.core.registry import CPUDispatcher

import eval as ev
from reconstruction.pipeline import MultiViewPipeline


def counts():
    kernels = {}
    for name, module in list(sys.modules.items()):
        if module is not None and name.split(".")[0] in ev.KERNEL_PACKAGES:
            for obj in vars(module).values():
                if isinstance(obj, CPUDispatcher):
                    kernels[obj.py_func.__module__ + "." + obj.__name__] = len(obj.signatures)
    return kernels


ev.compile_kernels()
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
    # the background compile of a first run is the stages' warm-ups: a kernel type they miss would compile in the run
    settings = [
        "dataset.num_frames=3",
        "dataset.num_persons=12 dataset.num_cameras=5 dataset.num_frames=3 dataset.miss_rate=0.2",
        "dataset=wildtrack",  # lens distortion
        f"dataset=shelf dataset.root={ROOT.parent / 'shared' / 'data' / 'shelf'}",
    ]
    assert _last_line(SPECIALISATIONS, *settings) == "{}"


LATE_KERNELS = """
import sys
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from numba.core.registry import CPUDispatcher

import eval as ev
from reconstruction.pipeline import MultiViewPipeline


def holders():
    return {
        name
        for name, module in list(sys.modules.items())
        if module is not None and name.split(".")[0] in ev.KERNEL_PACKAGES
        and any(isinstance(obj, CPUDispatcher) for obj in vars(module).values())
    }


with initialize_config_dir(config_dir=sys.argv[1], version_base=None):
    cfg = compose("eval", overrides=sys.argv[2:])
for module in ev.stage_modules(cfg):
    __import__(module)
loaded = holders()
sequence = instantiate(cfg.dataset, _convert_="all")
MultiViewPipeline.from_config(cfg, sequence.rig)(sequence.frames[0])
print(sorted(holders() - loaded))
"""


@pytest.mark.parametrize("overrides", [[], ["dataset=wildtrack", "tracking=off", "matching=feet_paper"]])
def test_the_stages_kernels_are_loaded_before_a_first_run_swaps_them(overrides):
    # a module first imported after the swap would compile its kernels in the run instead (4 s of the first run)
    assert _last_line(LATE_KERNELS, *overrides) == "[]"


def _last_line(script: str, *args: str) -> str:
    """The last line a script prints, run in a fresh interpreter with the configs folder and args."""
    done = subprocess.run(
        [sys.executable, "-c", script, str(ROOT / "configs"), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.strip().splitlines()[-1]
