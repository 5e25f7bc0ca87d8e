"""Compiling numba kernels ahead, in a second process, on a run whose on-disk numba cache is cold.

numba compiles one kernel at a time per process (a global compiler lock), so the first run after an install
spends its start on one core. ``compile_ahead`` starts a warm-up function in a background Python process
when a kernel of it has no cached code; that process fills numba's cache while this one compiles other
kernels, and ``wait_for`` (called by the warm-up here before it needs those kernels) waits for it, after which
they load from the cache. With a warm cache nothing is started.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
from typing import Any

WAIT_LIMIT_S = 600.0  # a background compile still running after this is stopped; this process compiles instead

_RUNNING: dict[str, subprocess.Popen] = {}


def cache_is_cold(kernel: Any) -> bool:
    """Whether a numba dispatcher (cache=True) has no usable code in numba's on-disk cache (none, or stale
    after a change of its source). False where that cannot be told (no cache, another numba's internals)."""
    try:
        return not kernel._cache._cache_file._load_index()
    except Exception:  # numba's cache internals: without them, compile in this process as always
        return False


def compile_ahead(target: str, kernel: Any) -> bool:
    """Start ``target`` ("package.module:function", a warm-up without arguments) in a background Python process
    if ``kernel``, one of the kernels it compiles, is not cached and this process may use a second core -> started."""
    if target in _RUNNING or _usable_cores() < 2 or not cache_is_cold(kernel):
        return False
    if not _RUNNING:
        atexit.register(_stop_all)  # a run that stops early (bad input) leaves no compile behind
    module, function = target.split(":")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # this process's imports
    _RUNNING[target] = subprocess.Popen(
        [sys.executable, "-c", f"import {module}; {module}.{function}()"],
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return True


def _usable_cores() -> int:
    """Cores this process may run on (its affinity where the OS tells it: a process pinned to one core has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def wait_for(target: str) -> None:
    """Wait for the background compile of ``target`` if one was started (stopped after WAIT_LIMIT_S)."""
    process = _RUNNING.pop(target, None)
    if process is None:
        return
    try:
        process.wait(timeout=WAIT_LIMIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def _stop_all() -> None:
    """Stop the background compiles nobody waited for."""
    for process in _RUNNING.values():
        process.kill()
        process.wait()
    _RUNNING.clear()
