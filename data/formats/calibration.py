"""Other tools' calibration files (anipose, EasyMocap, OpenCV, any load_rig format) -> cameras.json.

``python -m data.formats.calibration FILE [FILE2] -o cameras.json [--format NAME] [--units m|cm|mm]
[--rotation world_to_camera|camera_to_world] [--ground poses2d.json]``"""

from __future__ import annotations

import argparse
import sys
import warnings
from typing import Sequence

from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import CalibrationError, detect_format, load_rig, save_cameras_json
from data.geometry.calibration_formats import FREE_FORMATS, GROUND_FRAMES, ROTATIONS, UNITS_M, fit_ground, orient
from data.geometry.camera import Rig
from data.geometry.check_rig import RigWarning, check_rig


def convert(args: argparse.Namespace) -> tuple[Rig, str, str]:
    """The rig of args.files in metres, world -> camera, on the fitted ground if asked; its format; the ground line."""
    (path, *second), stated = args.files, {"units": args.units, "rotation": args.rotation}
    fmt = detect_format(path) if args.format == "auto" else args.format
    if second and fmt not in ("easymocap", "opencv"):
        raise CalibrationError(f"{second[0]}: a second file is EasyMocap's extri.yml or OpenCV's extrinsics.yml")
    if fmt not in FREE_FORMATS + ("cameras_json",) and (args.units or args.rotation):
        raise CalibrationError(f"{path}: the {fmt} loader fixes the units and direction: drop --units and --rotation")
    if fmt in FREE_FORMATS:
        rig = load_rig(path, fmt, check=False, **stated, **({"second": second[0]} if second else {}))
    else:  # cameras.json states metres, world -> camera: the rules check it; the dataset loaders convert theirs
        rig = load_rig(path, fmt, check=False)
        rig = orient(rig, path, **stated) if fmt == "cameras_json" else rig
    if args.ground:
        views = read_poses2d(args.ground, rig.names, [c.size for c in rig])
        rig, fit = fit_ground(rig, views, args.ground, args.frames)
        return rig, fmt, f"{fit} ({args.ground})"
    if fmt in FREE_FORMATS:
        return rig, fmt, f"ground: not in {path}: the world frame is the file's (--ground poses2d.json fits z = 0)"
    return rig, fmt, f"ground: the file's, z = 0 (the {fmt} loader gives z up, metres)"


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (docs/usage.md): the warnings, the rig check's findings and the ground in one line each."""
    parser = argparse.ArgumentParser(prog="python -m data.formats.calibration", description=__doc__.split("\n")[0])
    parser.add_argument("files", nargs="+", help="calibration file or folder [EasyMocap extri.yml / OpenCV extrinsics]")
    parser.add_argument("-o", "--output", required=True, help="cameras.json to write")
    parser.add_argument("--format", default="auto", help="auto or a load_rig format (anipose, easymocap, opencv, ...)")
    parser.add_argument("--units", choices=list(UNITS_M), help="the unit of the file's translations")
    parser.add_argument("--rotation", choices=ROTATIONS, help="the direction of the file's R, t")
    parser.add_argument("--ground", help="poses2d.json whose feet fit the ground plane z = 0")
    parser.add_argument("--frames", type=int, default=GROUND_FRAMES, help="the first frames of --ground it uses")
    args = parser.parse_args(argv)
    if len(args.files) > 2:
        parser.error("at most two files: FILE [FILE2]")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RigWarning)
            rig, fmt, ground = convert(args)
            findings = check_rig(rig, args.output, warn=False)
        save_cameras_json(rig, args.output)
    except (ValueError, OSError) as err:  # CalibrationError and Poses2DError are ValueErrors
        print(f"error: {err}", file=sys.stderr)
        return 1
    print("\n".join([f"warning: {w.message}" for w in caught if w.category is RigWarning] + [""]), end="")
    print("\n".join([f"{f.level}: {args.output}: {f.message}" for f in findings] + [""]), end="")
    print(f"Wrote {args.output}: {len(rig)} cameras from {' + '.join(args.files)} ({fmt}), metres, world -> camera")
    print(ground)
    return 0


if __name__ == "__main__":
    sys.exit(main())
