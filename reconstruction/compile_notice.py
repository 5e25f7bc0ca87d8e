"""One line for the user while numba compiles: the first run after an install (or a change of the kernels'
code) compiles them for 15-35 s, silently; later runs load them from numba's on-disk cache in ~0.2 s."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

# loading the cached kernels took 0.17 s, compiling them 14.7 s (MAP) + 1.6 s (evidence) on a shared 2-core CPU:
# a block still running after 1 s is compiling
NOTICE_AFTER_S = 1.0


@contextmanager
def compile_notice(what: str, after_s: float = NOTICE_AFTER_S) -> Iterator[None]:
    """Print one line (stdout) if the block, a warm-up of numba kernels, is still running after after_s seconds."""
    timer = threading.Timer(
        after_s,
        print,
        [
            f"Compiling the {what} numba kernels (once after an install or a code "
            "change, 15-35 s; later runs load them from numba's cache) ..."
        ],
        {"flush": True},
    )
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
