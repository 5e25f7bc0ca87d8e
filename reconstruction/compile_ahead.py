"""A first run that does not wait for numba: the kernels compile in a background process, run as Python meanwhile.

With numba's on-disk cache cold (the first run after an install or a change of the kernels), compiling every
kernel costs about 20 s of CPU, most of it numba's own Python (typing and lowering), not LLVM. A small job runs
faster than that with the kernels as the Python functions they are written as. ``interpret_until_compiled`` starts
a warm-up that compiles every kernel in a background process, which outlives this one so that the next run finds
the cache filled, and meanwhile gives every module that holds a kernel its Python function (numba's ``py_func``,
numpy's floating-point and overflow errors ignored, as the kernels' error_model does); when that process ends, the
modules get their kernels back and later calls load the compiled code from the cache. The MAP stage uses its numpy
solver while the kernels are interpreted (:func:`kernels_interpreted`). With a warm cache nothing is started.

The background process holds an exclusive lock (POSIX ``flock``) on a file named after its target in numba's cache
folder while it compiles: a second first run of that target on the same cache starts no compile of its own, runs its
kernels as Python too and takes the compiled ones when the lock is released; :func:`wait_for_background_compile`
waits for it likewise.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

import numpy as np

_INTERPRETED: dict[tuple[ModuleType, str], Any] = {}  # (module, name) -> the numba dispatcher it held
_SWAP = threading.Lock()

try:
    import fcntl
except ImportError:  # Windows: no lock; each first run compiles in a background process of its own
    fcntl = None


def cache_is_cold(kernel: Any) -> bool:
    """Whether a numba dispatcher (cache=True) has no usable code in numba's on-disk cache (none, or stale
    after a change of its source). False where that cannot be told (no cache, another numba's internals)."""
    try:
        return not kernel._cache._cache_file._load_index()
    except Exception:  # numba's cache internals: without them, compile in this process as always
        return False


def interpret_until_compiled(target: str, kernel: Any, packages: tuple[str, ...]) -> bool:
    """On a first run (``kernel`` not cached) with a second usable core: start ``target`` ("package.module:function",
    a warm-up that compiles every kernel a run uses) in a background process that outlives this one (unless another
    first run's holds the cache's lock), and run the numba kernels of the loaded modules of ``packages`` as Python
    until that process ends -> True."""
    if _INTERPRETED or _usable_cores() < 2 or not cache_is_cold(kernel):
        return False
    lock = _open_lock(target)
    if lock is not None and not _try_lock(lock):  # another first run's background compile holds it: wait for that
        waiter = functools.partial(_wait_lock, lock)
    else:
        process = _start_detached(target, lock)
        waiter = process.wait
    with _SWAP:
        for holder, name, dispatcher in _dispatchers(packages):
            _INTERPRETED[holder, name] = dispatcher
            setattr(holder, name, _as_python(dispatcher))
    threading.Thread(target=_compiled_when_done, args=(waiter,), daemon=True).start()
    return True


def wait_for_background_compile(target: str, cache_dir: str | Path | None = None, timeout_s: float = 600.0) -> bool:
    """Wait until no background compile of ``target`` holds its lock in numba's cache folder ``cache_dir`` (None: this
    process's, NUMBA_CACHE_DIR or the default) -> whether released within timeout_s (True at once if none, or no lock)."""
    lock = _open_lock(target, cache_dir)
    if lock is None:
        return True
    try:
        end = time.monotonic() + timeout_s
        while not _try_lock(lock):
            if time.monotonic() > end:
                return False
            time.sleep(0.05)
        return True
    finally:
        os.close(lock)


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


def _compiled_when_done(wait: Callable[[], Any]) -> None:
    """Wait for the background compile, then give every module its kernels back (they load from the cache)."""
    wait()
    with _SWAP:
        for (holder, name), kernel in _INTERPRETED.items():
            setattr(holder, name, kernel)
        _INTERPRETED.clear()


def _start_detached(target: str, lock: int | None) -> subprocess.Popen:
    """``target`` ("package.module:function") in a Python process of its own session, which inherits the lock (held
    until it exits) and outlives this one (nor does this one's Ctrl-C stop it): the next run finds the cache full."""
    module, function = target.split(":")
    try:
        return subprocess.Popen(
            [sys.executable, "-c", f"import {module}; {module}.{function}()"],
            env={**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)},  # this process's imports
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            pass_fds=() if lock is None else (lock,),
        )
    finally:
        if lock is not None:
            os.close(lock)  # the child's copy keeps the lock


def lock_path(target: str, cache_dir: str | Path | None = None) -> Path:
    """The lock file of target's background compile in numba's cache folder: cache_dir, else NUMBA_CACHE_DIR, else
    this package's __pycache__ (numba's default keeps each kernel's cache beside its source)."""
    folder = cache_dir or os.environ.get("NUMBA_CACHE_DIR") or Path(__file__).resolve().parent / "__pycache__"
    return Path(folder) / f"background_compile.{target.replace(':', '.')}.lock"


def _open_lock(target: str, cache_dir: str | Path | None = None) -> int | None:
    """A descriptor of the lock file (created if needed), None where there is no locking or the folder is not
    writable."""
    if fcntl is None:
        return None
    path = lock_path(target, cache_dir)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        return None


def _try_lock(fd: int) -> bool:
    """Take the exclusive lock of fd without waiting -> taken."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except OSError:
        return False


def _wait_lock(fd: int) -> None:
    """Wait for the exclusive lock of fd (another process's compile to end), then release it and close fd."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
    finally:
        os.close(fd)
