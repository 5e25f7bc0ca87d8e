"""Paired speed runs: this tree against a git revision, alternately, each run's stage medians compared."""

from benchmarks import common  # isort: split

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from evaluation.report import format_table

ROOT = common.ROOT
COLUMNS = ("matching", "reconstruction", "tracking", "total")
DRIVERS = {"frames": "benchmarks/frame_times.py", "process": "python eval.py dataset=shelf"}
PROCESS_SETTING = "python eval.py dataset=shelf (warm), s"


def stage_medians(text: str) -> dict[str, dict[str, float]]:
    """The first table of frame_times.py's (or benchmarks.speed's) output -> setting -> stage column -> ms."""
    lines = [line for line in text.splitlines() if line.startswith("|")]
    if not lines:
        raise ValueError("no table in the benchmark's output")
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    where = {name: header.index(name) for name in ("setting", *COLUMNS)}
    out: dict[str, dict[str, float]] = {}
    for line in lines[1:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if len(cells) != len(header):  # the table ends where the next one (other columns) begins
            break
        if set(cells[0]) <= {"-"}:
            continue
        out[cells[where["setting"]]] = {c: float(cells[where[c]]) if cells[where[c]] != "-" else 0.0 for c in COLUMNS}
    return out


def paired_difference(baseline: list[float], ours: list[float]) -> tuple[float, float]:
    """Mean of ours - baseline over the pairs and its standard error (NaN with fewer than two pairs): (n,) x2."""
    if len(baseline) != len(ours) or not baseline:
        raise ValueError(f"need as many runs of each, at least one: {len(baseline)} and {len(ours)}")
    diff = [b - a for a, b in zip(baseline, ours)]
    se = statistics.stdev(diff) / len(diff) ** 0.5 if len(diff) > 1 else float("nan")
    return statistics.fmean(diff), se


@contextmanager
def worktree(rev: str) -> Iterator[Path]:
    """A temporary detached git worktree of rev (removed after): -> its path."""
    path = Path(tempfile.mkdtemp(prefix="paired_speed_")) / "tree"
    subprocess.run(["git", "worktree", "add", "--detach", str(path), rev], cwd=ROOT, check=True, capture_output=True)
    try:
        yield path
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(path)], cwd=ROOT, capture_output=True)


def run_frames(tree: Path, cache: Path, args: argparse.Namespace) -> str:
    """The output of this tree's benchmarks/frame_times.py run in tree, numba's cache in cache."""
    # run_path, not the script's path: that would put benchmarks/ first on sys.path, where
    # benchmarks/reconstruction.py would hide the tree's reconstruction package
    driver = f"import runpy; runpy.run_path({str(ROOT / 'benchmarks' / 'frame_times.py')!r}, run_name='__main__')"
    command = [sys.executable, "-c", driver, "--only", args.only]
    command += ["--repeats", str(args.repeats), "--data", str(Path(args.data).resolve())]
    command += ["--cpu", str(args.cpu)] if args.cpu is not None else []
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(tree)}
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"frame_times.py failed in {tree}:\n{done.stderr[-2000:]}")
    return done.stdout


def run_process(
    tree: Path, cache: Path, args: argparse.Namespace, repeats: int | None = None
) -> dict[str, dict[str, float]]:
    """Median wall seconds of ``repeats`` Shelf ``python eval.py`` runs in tree, as a setting (stages 0)."""
    threads = dict.fromkeys(common.THREAD_VARIABLES, "1")
    env = {**os.environ, **threads, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(tree)}
    pin = (lambda: os.sched_setaffinity(0, {args.cpu})) if args.cpu is not None else None
    command = [sys.executable, "eval.py", *common.shelf(str(Path(args.data).resolve())), "progress=false"]
    with tempfile.TemporaryDirectory(prefix="paired_speed_runs_") as runs:
        count = args.repeats if repeats is None else repeats
        seconds = [
            common.process_seconds([*command, f"hydra.run.dir={runs}/{k}"], tree, env, pin) for k in range(count)
        ]
    return {PROCESS_SETTING: {**dict.fromkeys(COLUMNS[:-1], 0.0), "total": statistics.median(seconds)}}


def run_once(tree: Path, cache: Path, args: argparse.Namespace) -> dict[str, dict[str, float]]:
    """One run of the driver in tree: setting -> stage -> ms per frame (seconds for the process driver)."""
    if args.driver == "process":
        return run_process(tree, cache, args)
    return stage_medians(run_frames(tree, cache, args))


def main(argv: list[str] | None = None) -> str:
    """Run the pairs; print (and with --out, write) the pairs and the paired differences."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare this tree with")
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--only", default="100 people", help="the settings whose label contains this text")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=None, help="pin each run to this CPU (Linux)")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--out", default=None, help="also write the tables to this markdown file")
    parser.add_argument("--driver", choices=tuple(DRIVERS), default="frames", help="what each run times (DRIVERS)")
    args = parser.parse_args(argv)
    if args.pairs < 1:
        parser.error("--pairs must be at least 1")
    runs: dict[str, list[dict[str, dict[str, float]]]] = {"baseline": [], "this tree": []}
    with worktree(args.baseline) as base, tempfile.TemporaryDirectory(prefix="paired_speed_cache_") as caches:
        trees = (("baseline", base), ("this tree", ROOT))
        if args.driver == "process":  # fill each tree's numba cache: the pairs time warm processes
            for name, tree in trees:
                run_process(tree, Path(caches) / name.replace(" ", "_"), args, repeats=1)
        for k in range(args.pairs):
            for name, tree in trees:
                runs[name].append(run_once(tree, Path(caches) / name.replace(" ", "_"), args))
            print(f"pair {k + 1}/{args.pairs} done", file=sys.stderr, flush=True)
    return common.emit(report(runs, args.baseline, args.driver), args.out)


def report(runs: dict[str, list[dict[str, dict[str, float]]]], baseline: str, driver: str = "frames") -> str:
    """The pairs' totals and, per setting and stage, the medians and the mean paired difference."""
    settings = [s for s in runs["baseline"][0] if all(s in r for rs in runs.values() for r in rs)]
    columns = ("total",) if driver == "process" else COLUMNS
    unit = "seconds per run, median of its repeats" if driver == "process" else "ms per frame, median over its frames"
    pairs = [
        [k + 1, setting, a[setting]["total"], b[setting]["total"]]
        for setting in settings
        for k, (a, b) in enumerate(zip(runs["baseline"], runs["this tree"]))
    ]
    rows = []
    for setting in settings:
        for column in columns:
            a = [r[setting][column] for r in runs["baseline"]]
            b = [r[setting][column] for r in runs["this tree"]]
            mean, se = paired_difference(a, b)
            both = min(statistics.median(a), statistics.median(b)) > 0  # a stage the baseline lacks has no ratio
            ratio = statistics.median(a) / statistics.median(b) if both else float("nan")
            rows.append([setting, column, statistics.median(a), statistics.median(b), ratio, mean, se])
    headers = ["setting", "stage", f"{baseline} median", "this tree median", "ratio", "difference", "standard error"]
    return "\n\n".join(
        [
            f"Each pair: {DRIVERS[driver]} at {baseline}, then in this tree ({unit})",
            format_table(["pair", "setting", f"{baseline} total", "this tree total"], pairs, floatfmt=".2f"),
            f"Over the {len(runs['baseline'])} pairs: medians, and this tree - {baseline} (mean paired difference)",
            format_table(headers, rows, floatfmt=".2f"),
        ]
    )


if __name__ == "__main__":
    main()
