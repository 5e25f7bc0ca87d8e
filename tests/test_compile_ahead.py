"""Compiling numba kernels ahead in a second process: started only for a cold cache, filling the cache here."""

import importlib
import textwrap

import numpy as np

from reconstruction.compile_ahead import cache_is_cold, compile_ahead, wait_for

KERNEL_MODULE = """
import numpy as np
from numba import njit


@njit(cache=True)
def twice(x):
    return 2.0 * x


def warm_up():
    twice(np.ones(3))
"""


def _fresh_module(tmp_path, monkeypatch, name: str):
    """A module of one cached kernel, never compiled: its numba cache (beside it) is empty."""
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(KERNEL_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    return importlib.import_module(name)


def test_a_second_process_fills_the_cache_of_a_cold_kernel(tmp_path, monkeypatch):
    module = _fresh_module(tmp_path, monkeypatch, "ahead_kernels_a")
    assert cache_is_cold(module.twice)
    target = "ahead_kernels_a:warm_up"
    assert compile_ahead(target, module.twice)
    assert not compile_ahead(target, module.twice)  # one process per target
    wait_for(target)
    assert not cache_is_cold(module.twice)  # the other process's code, loaded from the cache here
    np.testing.assert_array_equal(module.twice(np.arange(3.0)), [0.0, 2.0, 4.0])
    assert module.twice.stats.cache_hits and not module.twice.stats.cache_misses
    assert not compile_ahead(target, module.twice)  # warm: nothing started
    wait_for(target)  # nothing to wait for


def test_nothing_is_started_for_what_is_not_a_cached_kernel():
    assert not cache_is_cold(len)
    assert not compile_ahead("math:sqrt", len)


def test_the_map_solvers_ahead_target_names_its_warm_up():
    # eval.py starts this target by name in a second process: a rename must not leave it silently failing
    from reconstruction.solver import map_solver

    module, function = map_solver.SOLVES_WARM_UP.split(":")
    assert getattr(importlib.import_module(module), function) is map_solver.warm_up_solves
