"""Pictures over time: the HTML viewer and the ground trajectories PNG of a sequence."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from data.formats.poses_io import read_poses3d_frames
from data.geometry.calibration import CalibrationError, load_rig
from data.geometry.camera import Rig
from evaluation.pictures.sequence_html import DEFAULT_MAX_MB, write_sequence_html
from evaluation.pictures.vis_trajectories import plot_trajectories
from reconstruction.pipeline import FrameResult

HTML_NAME = "sequence.html"
PNG_NAME = "trajectories.png"
FILE_ID_NOTE = "ids as written in {name}: track ids when the run tracked, else each person's index in its frame"


def save_sequence_pictures(
    out_dir: str | Path, results: Sequence[FrameResult], rig: Rig, title: str, max_mb: float
) -> list[Path]:
    """sequence.html and trajectories.png of an eval.py run's results into out_dir -> their paths."""
    frames = [(r.frame, r.poses3d, r.ids) for r in results]
    out_dir = Path(out_dir)
    return [
        write_sequence_html(out_dir / HTML_NAME, frames, rig, title=title, max_mb=max_mb),
        plot_trajectories(out_dir / PNG_NAME, frames, rig),
    ]


def main(argv: list[str] | None = None) -> list[Path]:
    """Command line: the viewer (and with --png the trajectories) of a poses3d.json -> the written paths."""
    prog = "python -m evaluation.pictures.sequence_view"
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("poses3d", type=Path, help="poses3d.json of an eval.py run")
    parser.add_argument("cameras", type=Path, help="the calibration (cameras.json or any format load_rig reads)")
    parser.add_argument("-o", "--output", type=Path, help=f"HTML file (default: {HTML_NAME} beside poses3d)")
    parser.add_argument("--png", type=Path, help="also write the ground trajectories to this PNG")
    every = "above this page size, show every k-th frame (default %(default)s)"
    parser.add_argument("--max-mb", type=float, default=DEFAULT_MAX_MB, help=every)
    parser.add_argument("--title", help="page title (default: the poses3d path)")
    args = parser.parse_args(argv)
    if not args.max_mb > 0:
        parser.error(f"--max-mb must be > 0, got {args.max_mb}")
    try:
        frames = read_poses3d_frames(args.poses3d)
        rig = load_rig(args.cameras)
    except (OSError, ValueError, KeyError, TypeError, CalibrationError) as err:
        raise SystemExit(f"error: {err}") from None
    output = args.output or args.poses3d.with_name(HTML_NAME)
    note = FILE_ID_NOTE.format(name=args.poses3d.name)
    title = args.title or str(args.poses3d)
    paths = [write_sequence_html(output, frames, rig, title=title, max_mb=args.max_mb, id_note=note)]
    if args.png:
        paths.append(plot_trajectories(args.png, frames, rig))
    print("Wrote " + ", ".join(str(p) for p in paths))
    return paths


if __name__ == "__main__":
    main()
