"""One line for the user while numba compiles: the first run after an install (or a change of the kernels'
code) compiles them for about 13 s on one core (README), silently; later runs load them from numba's on-disk
cache in ~0.2 s."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

# loading the cached kernels takes ~0.2 s, compiling them ~13 s CPU in all (MAP solver ~7, evidence matcher ~5,
# measured with an empty NUMBA_CACHE_DIR): a block still running after 1 s is compiling
NOTICE_AFTER_S = 1.0


@contextmanager
def compile_notice(what: str, after_s: float = NOTICE_AFTER_S) -> Iterator[None]:
    """Print one line (stdout) if the block, a warm-up of numba kernels, is still running after after_s seconds."""
    timer = threading.Timer(
        after_s,
        print,
        [
            f"Compiling the {what} numba kernels (once after an install or a code "
            "change, about 15 s in all; later runs load them from numba's cache) ..."
        ],
        {"flush": True},
    )
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
