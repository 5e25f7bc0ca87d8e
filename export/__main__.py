"""python -m export bvh|trc|csv poses3d.json [-o OUT] [--fps FPS] [--fill] [--track ID]; bad input: one line."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import NoReturn, Sequence

from export.bvh import write_bvh
from export.csv_export import write_csv
from export.tracks import fill_gaps, read_tracks
from export.trc import write_trc

WRITERS = {"bvh": write_bvh, "trc": write_trc, "csv": write_csv}


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        """A usage error: one line 'error: ...', exit status 2."""
        sys.exit(print(f"error: {message}", file=sys.stderr) or 2)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (docs/usage.md); returns the exit status."""
    parser = _Parser(prog="python -m export", description="poses3d.json -> BVH / TRC per track id, or one CSV")
    parser.add_argument("format", help="bvh, trc or csv")
    parser.add_argument("poses3d", help="a run's poses3d.json")
    parser.add_argument("-o", "--output", help="output name without suffix (default: the input's); bvh, trc: _id<k>")
    parser.add_argument("--fps", type=float, help="frames per second of the frame numbers (the file's fps, else 30)")
    parser.add_argument("--fill", action="store_true", help="interpolate each joint linearly over gaps in its track")
    parser.add_argument("--track", type=int, help="only this track id")
    args = parser.parse_args(argv)
    try:
        if args.format not in WRITERS:
            raise ValueError(f"unknown format {args.format!r} (bvh, trc or csv)")
        if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
            raise ValueError(f"--fps {args.fps:g}: must be a positive number")
        tracks = read_tracks(args.poses3d, args.track)
        fps = args.fps or tracks[0].fps
        if fps is None:
            fps = 30.0
            print(f'note: {args.poses3d} has no "fps": 30 frames per second assumed (--fps sets it)', file=sys.stderr)
        tracks = [fill_gaps(t) for t in tracks] if args.fill else tracks
        base = Path(args.output or args.poses3d)
        base = base.with_suffix("") if base.suffix.lower() in (".json", ".bvh", ".trc", ".csv") else base
        base.parent.mkdir(parents=True, exist_ok=True)
        print("\n".join(WRITERS[args.format](tracks, base, fps)))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    except OSError as err:
        print(f"error: cannot write {err.filename}: {err.strerror}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
