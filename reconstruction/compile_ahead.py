"""A first run that does not wait for numba: the kernels compile in a background process, run as Python meanwhile.

With numba's on-disk cache cold (the first run after an install or a change of the kernels), compiling every
kernel costs about 15 s of CPU, most of it numba's own Python (typing and lowering), not LLVM. A small job runs
faster than that with the kernels as the Python functions they are written as. ``interpret_until_compiled`` starts
a warm-up that compiles every kernel in a background process, which outlives this one so that the next run finds
the cache filled, and meanwhile gives every module that holds a kernel its Python function (numba's ``py_func``,
numpy's floating-point and overflow errors ignored, as the kernels' error_model does); when that process ends, the
modules get their kernels back and later calls load the compiled code from the cache. The MAP stage uses its numpy
solver while the kernels are interpreted (:func:`kernels_interpreted`). With a warm cache nothing is started.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import threading
from types import ModuleType
from typing import Any, Callable

import numpy as np

_INTERPRETED: dict[tuple[ModuleType, str], Any] = {}  # (module, name) -> the numba dispatcher it held
_SWAP = threading.Lock()


def cache_is_cold(kernel: Any) -> bool:
    """Whether a numba dispatcher (cache=True) has no usable code in numba's on-disk cache (none, or stale
    after a change of its source). False where that cannot be told (no cache, another numba's internals)."""
    try:
        return not kernel._cache._cache_file._load_index()
    except Exception:  # numba's cache internals: without them, compile in this process as always
        return False


def interpret_until_compiled(target: str, kernel: Any, packages: tuple[str, ...]) -> bool:
    """On a first run (``kernel`` not cached) with a second usable core: start ``target`` ("package.module:function",
    a warm-up that compiles every kernel a run uses) in a background process that outlives this one, and run the
    numba kernels of the loaded modules of ``packages`` as Python until it ends -> started."""
    if _INTERPRETED or _usable_cores() < 2 or not cache_is_cold(kernel):
        return False
    module, function = target.split(":")
    process = subprocess.Popen(
        [sys.executable, "-c", f"import {module}; {module}.{function}()"],
        env={**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)},  # this process's imports
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # not stopped with this process (nor by its Ctrl-C): the next run finds the cache full
    )
    with _SWAP:
        for holder, name, dispatcher in _dispatchers(packages):
            _INTERPRETED[holder, name] = dispatcher
            setattr(holder, name, _as_python(dispatcher))
    threading.Thread(target=_compiled_when_done, args=(process,), daemon=True).start()
    return True


def kernels_interpreted() -> bool:
    """Whether this process runs its numba kernels as Python at present (:func:`interpret_until_compiled`)."""
    return bool(_INTERPRETED)


def _usable_cores() -> int:
    """Cores this process may run on (its affinity where the OS tells it: a process pinned to one core has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def _dispatchers(packages: tuple[str, ...]) -> list[tuple[ModuleType, str, Any]]:
    """(module, name, dispatcher) of every numba dispatcher held by a loaded module of ``packages``: a kernel's own
    module (where the other kernels find it) and every module that imported it by name."""
    from numba.core.dispatcher import Dispatcher

    out = []
    for module_name, module in list(sys.modules.items()):
        if module is not None and module_name.split(".")[0] in packages:
            out += [(module, k, v) for k, v in list(vars(module).items()) if isinstance(v, Dispatcher)]
    return out


def _as_python(kernel: Any) -> Callable:
    """The kernel's Python function with numpy's errors ignored (error_model "numpy": x / 0 is inf; the bit tricks
    rely on int64 multiplication wrapping around)."""

    @functools.wraps(kernel.py_func)
    def call(*args: Any) -> Any:
        with np.errstate(all="ignore"):
            return kernel.py_func(*args)

    return call


def _compiled_when_done(process: subprocess.Popen) -> None:
    """Wait for the background compile, then give every module its kernels back (they load from the cache)."""
    process.wait()
    with _SWAP:
        for (holder, name), kernel in _INTERPRETED.items():
            setattr(holder, name, kernel)
        _INTERPRETED.clear()
