"""One line for the user while numba compiles: the first run after an install (or a change of the kernels'
code) compiles them for about 24 s of CPU (README; with two cores, in a background process while the run uses
them as Python, reconstruction/compile_ahead.py), silently; later runs load them from numba's cache in ~0.2 s."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Callable, Iterator

from reconstruction.compile_ahead import kernels_interpreted

# loading the cached kernels takes ~0.2 s, compiling them about 24 s of CPU in all (warm-ups with an empty
# NUMBA_CACHE_DIR: MAP solver 9.1 s, evidence matcher 7.4 s, tracker 2.8 s): a block still running after 1 s is compiling
NOTICE_AFTER_S = 1.0


@contextmanager
def compile_notice(what: str, after_s: float = NOTICE_AFTER_S) -> Iterator[None]:
    """Print one line (stdout) if the block, a warm-up of numba kernels, is still running after after_s seconds."""
    timer = threading.Timer(
        after_s,
        print,
        [
            f"Compiling the {what} numba kernels (once after an install or a code "
            "change, 10-30 s in all; later runs load them from numba's cache) ..."
        ],
        {"flush": True},
    )
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def warm_up_kernels(what: str, warm_up: Callable[[], None]) -> None:
    """Run a stage's warm-up of its numba kernels under :func:`compile_notice`; nothing while the kernels run as
    Python (a first run's background compile, reconstruction/compile_ahead.py: nothing to compile here)."""
    if kernels_interpreted():
        return
    with compile_notice(what):
        warm_up()
