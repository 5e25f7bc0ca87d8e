"""Compile (or load from numba's cache) every numba kernel a run uses: ``python -m reconstruction.precompile``."""

from __future__ import annotations

import argparse
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Callable

from numba.core.event import Event, Listener, install_listener

NOTICE = (
    "compiling the numba kernels once after an install, one stage per core (`python -m reconstruction.precompile` "
    "does it ahead); later runs load them from numba's cache ..."
)


def warm_ups() -> list[Callable[[], None]]:
    """The stages' warm-ups, each calling its module's kernels on tiny inputs (picklable: module-level functions)."""
    from models import paf_grouping
    from reconstruction.matching import evidence
    from reconstruction.solver import map_solver
    from tracking import tracker

    return [map_solver.warm_up, evidence.warm_up, tracker.warm_up, paf_grouping.warm_up]  # longest first


class NotCached(Exception):
    """A kernel missed numba's cache (raised by StopAtCompile before anything is compiled)."""


class StopAtCompile(Listener):
    """Listens to numba's compile events: stops the calling warm-up when a kernel starts compiling."""

    def on_start(self, event: Event) -> None:
        """A kernel is not in the cache: abort its compile (the dispatcher is left as it was)."""
        raise NotCached(event.data["dispatcher"].py_func.__qualname__)

    def on_end(self, event: Event) -> None:
        """Nothing at the end of a compile."""


def run_all(jobs: list[Callable[[], None]]) -> None:
    """Call each warm-up in this process."""
    for job in jobs:
        job()


def kernels_ready(jobs: list[Callable[[], None]]) -> bool:
    """Whether every kernel the warm-ups call loads from numba's cache (they are loaded; nothing is compiled)."""
    try:
        with install_listener("numba:compile", StopAtCompile()):
            run_all(jobs)
    except NotCached:
        return False
    return True


def precompile(workers: int | None = None) -> bool:
    """Load every kernel from numba's cache, or compile the missing ones under NOTICE -> whether any was compiled."""
    jobs = warm_ups()
    if kernels_ready(jobs):
        return False
    print(NOTICE, flush=True)
    workers = min(len(jobs), workers or os.cpu_count() or 1)
    if workers > 1 and "fork" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("fork")  # the workers inherit the imported modules: no re-import
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            for compiling in [pool.submit(job) for job in jobs]:
                compiling.result()
    run_all(jobs)
    return True


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__).parse_args()
    print("numba kernels compiled and cached" if precompile() else "numba kernels loaded from the cache")
