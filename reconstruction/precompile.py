"""Compile (or load from numba's cache) every numba kernel a run uses: ``python -m reconstruction.precompile``."""

from __future__ import annotations

import argparse
from typing import Callable

from numba.core.event import Event, Listener, install_listener

NOTICE = (
    "compiling the numba kernels once after an install: about 30 s (`python -m reconstruction.precompile` does it "
    "ahead); later runs load them from numba's cache ..."
)


def warm_ups() -> list[Callable[[], None]]:
    """The stages' warm-ups, each calling its module's kernels on tiny inputs: edit this list with the kernels."""
    from models import paf_grouping
    from reconstruction.matching import evidence
    from reconstruction.solver import map_solver
    from tracking import tracker

    return [evidence.warm_up, map_solver.warm_up, tracker.warm_up, paf_grouping.warm_up]


class CompileNotice(Listener):
    """Listens to numba's compile events: prints NOTICE when the first kernel misses numba's cache."""

    compiled = False

    def on_start(self, event: Event) -> None:
        """A kernel starts compiling (it was not in the cache): the notice, once."""
        if not self.compiled:
            print(NOTICE, flush=True)
        self.compiled = True

    def on_end(self, event: Event) -> None:
        """Nothing at the end of a compile."""


def precompile() -> bool:
    """Run every warm-up, with NOTICE printed if a kernel has to be compiled -> whether one was."""
    notice = CompileNotice()
    with install_listener("numba:compile", notice):
        for warm_up in warm_ups():
            warm_up()
    return notice.compiled


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__).parse_args()
    print("numba kernels compiled and cached" if precompile() else "numba kernels loaded from the cache")
