"""Compile (or load from numba's cache) every numba kernel a run uses: ``python -m reconstruction.precompile``."""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba.core.event import Event, Listener, install_listener

NOTICE = (
    "compiling the numba kernels once after an install: about 30 s (`python -m reconstruction.precompile` does it "
    "ahead); later runs load them from numba's cache ..."
)


def _group_people() -> None:
    """The PAF grouping's kernels on one person with one detection per joint."""
    from models.paf_grouping import BODY25_PAF_LIMBS, group_people

    one = np.array([[10.0, 10.0, 0.9]])
    group_people([one] * 25, [np.ones((1, 1))] * len(BODY25_PAF_LIMBS), min_joints=1)


def warm_ups() -> list[Callable[[], None]]:
    """The stages' warm-ups, each calling its module's kernels on tiny inputs: edit this list with the kernels."""
    from reconstruction import pipeline
    from reconstruction.matching import evidence
    from reconstruction.matching.sparse_assignment import linear_sum_assignment
    from reconstruction.solver import map_solver
    from tracking import tracker

    return [
        evidence.warm_up,
        pipeline.warm_up,
        map_solver.warm_up,
        tracker.warm_up,
        lambda: linear_sum_assignment(np.ones((2, 3))),
        _group_people,
    ]


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
    print("numba kernels compiled and cached" if precompile() else "numba kernels loaded from the cache")
