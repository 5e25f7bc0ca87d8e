"""Identity metrics and cost of the tracker (``tracking=on``) beside ``tracking=off``, same frames, one process."""

from benchmarks import common  # isort: split

import argparse

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig

from data.multiview import Sequence
from evaluation.report import format_table

HEADERS = ("set", "ID switches (per 100)", "IDF1-like (%)", "fragmentations", "MPJPE / PCP on", "MPJPE / PCP off")
HEADERS += ("tracker ms / frame", "pipeline ms / frame on", "off", "tracking adds ms")


def dev_sets(names: list[str], data: str, crowd_frames: int) -> dict[str, list[str]]:
    """Set label -> dataset overrides."""
    sets = {"Shelf (PCP)": common.shelf(data)} if "shelf" in names else {}
    if "panoptic" in names:
        sets.update(common.panoptic_sets(data, (5,)))
    if "crowd" in names:
        for n in (10, 100):
            sets[f"crowd {n} people, {crowd_frames} frames"] = common.crowd(n, crowd_frames)
    return sets


def run(sequence: Sequence, cfg: DictConfig) -> tuple[dict, dict, float, float]:
    """Metrics, Shelf summary, tracker ms and pipeline (matching + reconstruction + tracking) ms per frame."""
    report, ms = common.evaluate(sequence, cfg)
    tracker_ms = 1e3 * report.timings.get("tracking", 0.0) / max(len(sequence.frames), 1)
    return report.metrics, report.protocols.get("shelf", {}), tracker_ms, ms


def table_row(label: str, on: dict, off: dict, shelf_on: dict, shelf_off: dict, ms: np.ndarray) -> list:
    """One printed row: identity metrics, MPJPE (Shelf: PCP) on and off, ms of tracker, on, off, on - off."""
    if shelf_on:
        ident = shelf_on["tracking"]
        quality = [shelf["ours"]["strict"]["average"]["average"] for shelf in (shelf_on, shelf_off)]
    else:
        ident = {k[len("tracking_") :]: v for k, v in on.items() if k.startswith("tracking_")}
        quality = [on["mpjpe_mm"], off["mpjpe_mm"]]
    switches = f"{ident['id_switches']} ({ident['id_switches_per_100']:.2f})"
    return [label, switches, ident["idf1_like"], ident["fragmentations"], *quality, *ms, ms[1] - ms[2]]


def main(argv: list[str] | None = None) -> list[list]:
    """Print the table; returns its rows."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--sets", default="shelf,panoptic,crowd")
    parser.add_argument("--crowd-frames", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=3, help="on / off runs, interleaved, for the timing medians")
    parser.add_argument("overrides", nargs="*", help="eval.yaml overrides added to every run (noise_model=fixed ...)")
    args = parser.parse_args(argv)
    rows = []
    with initialize_config_dir(str(common.CONFIG_DIR), version_base="1.3"):
        for label, overrides in dev_sets(args.sets.split(","), args.data, args.crowd_frames).items():
            overrides = [*overrides, *args.overrides]
            sequence = instantiate(compose("eval", overrides=overrides).dataset, _convert_="all")
            cfg_on = compose("eval", overrides=[*overrides, "tracking=on"])
            cfg_off = compose("eval", overrides=[*overrides, "tracking=off"])
            timings = []
            for _ in range(max(args.repeats, 1)):  # interleaved: the machine's state is shared by both
                on, shelf_on, ms_track, ms_on = run(sequence, cfg_on)
                off, shelf_off, _, ms_off = run(sequence, cfg_off)
                timings.append((ms_track, ms_on, ms_off))
            rows.append(table_row(label, on, off, shelf_on, shelf_off, np.median(np.array(timings), axis=0)))
    print("Tracking (tracking=on) beside tracking=off; one core; identity metrics against persistent GT ids")
    print(format_table(HEADERS, rows, floatfmt=".2f"))
    return rows


if __name__ == "__main__":
    main()
