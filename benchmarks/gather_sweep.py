"""One markdown table of Hydra multiruns: ``python -m benchmarks.gather_sweep DIR [DIR ...] [--out T.md]``."""

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from omegaconf import OmegaConf

from benchmarks import common
from evaluation.report import format_table

METRIC_COLUMNS = {  # name -> (column header, factor, format); fractions are shown as percentages
    "matching_precision": ("matching precision (%)", 100.0, ".1f"),
    "matching_recall": ("matching recall (%)", 100.0, ".1f"),
    "matching_recovered_share": ("persons recovered (%)", 100.0, ".1f"),
    "mpjpe_mm": ("MPJPE (mm)", 1.0, ".1f"),
    "pcp_average": ("PCP (%)", 1.0, ".1f"),
    "reprojection_mean_px": ("reproj. mean (px)", 1.0, ".2f"),
    "reprojection_min_px": ("reproj. min (px)", 1.0, ".3f"),
    "reprojection_max_px": ("reproj. max (px)", 1.0, ".1f"),
    "reprojection_var_px2": ("reproj. var (px^2)", 1.0, ".1f"),
}
DEFAULT_METRICS = ("matching_precision", "matching_recall", "matching_recovered_share", "mpjpe_mm", "pcp_average")
DEFAULT_METRICS += ("matching_ms",)


@dataclass
class Run:
    """One run directory of a sweep: its overrides, metrics, stage timings and frame count."""

    name: str
    overrides: dict[str, str]
    metrics: dict[str, float]
    timings_s: dict[str, float] = field(default_factory=dict)
    num_frames: int | None = None


def parse_overrides(lines: Sequence[str]) -> dict[str, str]:
    """``key=value`` override strings as {key: value}, without the ``+``/``++``/``~`` prefixes."""
    return {key.lstrip("+~"): value for key, _, value in (line.partition("=") for line in lines)}


def load_run(run_dir: Path) -> Run:
    """Read a run directory written by eval.py."""
    doc = json.loads((run_dir / "metrics.json").read_text())
    hydra_dir = run_dir / ".hydra"
    overrides_file, config_file = hydra_dir / "overrides.yaml", hydra_dir / "config.yaml"
    lines = OmegaConf.to_container(OmegaConf.load(overrides_file)) if overrides_file.exists() else []
    overrides = parse_overrides(lines)
    config = OmegaConf.load(config_file) if config_file.exists() else OmegaConf.create()
    frames = OmegaConf.select(config, "dataset.num_frames")
    return Run(run_dir.name, overrides, doc.get("metrics", {}), doc.get("timings_s", {}), frames)


def swept_keys(runs: Sequence[Run]) -> list[str]:
    """The override keys whose value is not the same in every run, in order of first appearance."""
    keys = list(dict.fromkeys(k for run in runs for k in run.overrides))
    return [k for k in keys if len({run.overrides.get(k, "") for run in runs}) > 1]


def _sort_value(value: str) -> tuple[int, float, str]:
    """Numbers before text, numbers by value."""
    try:
        return (0, float(value), "")
    except ValueError:
        return (1, 0.0, value)


def metric_cell(run: Run, name: str) -> str:
    """The formatted value of one metric of a run; "-" when the run lacks it."""
    if name.endswith("_ms") and name[:-3] in run.timings_s:
        return f"{1000.0 * run.timings_s[name[:-3]] / run.num_frames:.2f}" if run.num_frames else "-"
    if name not in run.metrics:
        return "-"
    _, factor, fmt = METRIC_COLUMNS.get(name, (name, 1.0, ".4g"))
    return f"{factor * run.metrics[name]:{fmt}}"


def metric_header(name: str) -> str:
    """The column header of a metric."""
    if name in METRIC_COLUMNS:
        return METRIC_COLUMNS[name][0]
    return f"{name[:-3]} ms/frame" if name.endswith("_ms") else name


def sweep_table(
    sweep_dirs: Path | Sequence[Path], metrics: Sequence[str] = DEFAULT_METRICS
) -> tuple[list[str], list[list[str]]]:
    """Headers and rows (one per run, sorted by the swept keys) of one or several sweep directories."""
    dirs = [Path(sweep_dirs)] if isinstance(sweep_dirs, (str, Path)) else [Path(d) for d in sweep_dirs]
    runs = [load_run(p.parent) for d in dirs for p in sorted(d.glob("*/metrics.json"))]
    if not runs:
        raise SystemExit(f"error: no */metrics.json under {', '.join(map(str, dirs))}")
    keys = swept_keys(runs)
    runs.sort(key=lambda r: ([_sort_value(r.overrides.get(k, "")) for k in keys], r.name))
    rows = [[r.overrides.get(k, "") for k in keys] + [metric_cell(r, m) for m in metrics] for r in runs]
    return keys + [metric_header(m) for m in metrics], rows


def main(argv: Sequence[str] | None = None) -> str:
    """Print (and with --out write) the table of a sweep directory; return it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path, nargs="+", help="Hydra multirun folders (hydra.sweep.dir)")
    parser.add_argument("--out", type=Path, help="also write the table to this markdown file")
    parser.add_argument("--metrics", default=",".join(DEFAULT_METRICS), help="metrics.json keys or <stage>_ms, commas")
    args = parser.parse_args(argv)
    table = format_table(*sweep_table(args.sweep_dir, [m for m in args.metrics.split(",") if m]))
    return common.emit(table, args.out)


if __name__ == "__main__":
    main()
