"""Calibration loaders and savers: every dataset's camera format to one `Rig`; a bad file is a `CalibrationError`."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.formats.strict_json import DuplicateKey, unique_keys
from data.geometry.camera import Camera, Rig

WILDTRACK_CAMERAS = ("CVLab1", "CVLab2", "CVLab3", "CVLab4", "IDIAP1", "IDIAP2", "IDIAP3")
WILDTRACK_SIZE = (1920, 1080)
WILDTRACK_GRID_ORIGIN = (-3.0, -9.0)  # metres: world (X, Y) of grid cell (0, 0) in gt_positions_mvdet.txt
WILDTRACK_GRID_STEP = 0.025  # metres per grid cell
SHELF_SIZE = (1032, 776)
# Image sides (px) outside this range are a typo or a unit mistake (e.g. [10, 10], 1e308), not a camera.
IMAGE_SIDE_RANGE_PX = (32, 100_000)
# Panoptic world (cm, y down) -> ours (m, z up): x_ours = (x, z, -y) / 100; a proper rotation (det +1).
_PANOPTIC_M = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))


class CalibrationError(ValueError):
    """A calibration file that is missing, malformed or inconsistent."""


def _error(path: str | Path, camera: str | None, key: str | None, what: str) -> CalibrationError:
    """One message naming the file, the camera and the key: 'file: camera 'c': key 'k' what'."""
    where = [str(path)] + ([f"camera {camera!r}"] if camera is not None else [])
    where += [f"key {key!r} {what}" if key is not None else what]
    return CalibrationError(": ".join(where))


def _non_number(value: Any) -> Any | None:
    """The first leaf of nested lists that is not a JSON number (str, bool, None, object), else None."""
    if isinstance(value, (list, tuple)):
        for item in value:
            bad = _non_number(item)
            if bad is not None:
                return bad
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return (value,)  # wrapped, so that a bad None is still reported
    return None


def _missing_key(entry: Mapping, key: str) -> str:
    """'is missing', with a hint when the key is there in another case ('t' -> 'T')."""
    other = [k for k in entry if isinstance(k, str) and k.lower() == key.lower() and k != key]
    return f"is missing (found {other[0]!r}: keys are case-sensitive)" if other else "is missing"


def _array(entry: Any, key: str, shape: tuple[int, ...], path: str | Path, camera: str) -> np.ndarray:
    """entry[key] as a finite float array of `shape` (any nesting of that many numbers; no strings or booleans)."""
    if not isinstance(entry, Mapping):
        raise _error(path, camera, None, f"entry is a {type(entry).__name__}, expected an object")
    if key not in entry:
        raise _error(path, camera, key, _missing_key(entry, key))
    bad = _non_number(entry[key])
    if bad is not None:
        what = f"{bad[0]!r} ({type(bad[0]).__name__})"
        raise _error(path, camera, key, f"is not an array of numbers: {what} where a number belongs")
    try:
        value = np.array(entry[key], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise _error(path, camera, key, "is not an array of numbers") from None
    if value.size != math.prod(shape):
        raise _error(path, camera, key, f"has shape {value.shape}, expected {shape}")
    if not np.all(np.isfinite(value)):
        raise _error(path, camera, key, "has a non-finite value")
    return value.reshape(shape)


def _rotation(R: np.ndarray, path: str | Path, camera: str, key: str) -> np.ndarray:
    """The nearest rotation (SVD) of a rounded rotation matrix R (3, 3); CalibrationError when far from one: (3, 3)."""
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) <= 0:
        raise _error(path, camera, key, "is not a rotation matrix (orthonormal, det +1)")
    if np.allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12):
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _camera(
    name: str,
    K: np.ndarray,
    dist: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    size: Sequence[float],
    path: str | Path,
    keys: tuple[str, str, str],
) -> Camera:
    """A Camera after consistency checks of K (3, 3), R (3, 3), size (w, h); keys = names of K, R, size."""
    if not np.allclose(K[2], (0.0, 0.0, 1.0), atol=1e-9) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise _error(path, name, keys[0], "is not an intrinsic matrix (positive focal lengths, last row 0 0 1)")
    R = _rotation(R, path, name, keys[1])
    w, h = (float(s) for s in size)
    if w != int(w) or h != int(h) or w <= 0 or h <= 0:
        raise _error(path, name, keys[2], f"is not a positive integer image size: {list(size)}")
    lo, hi = IMAGE_SIDE_RANGE_PX
    if not (lo <= w <= hi and lo <= h <= hi):
        what = f"is not a plausible image size (w, h) = ({w:g}, {h:g}) px: each side must lie in [{lo}, {hi}]"
        raise _error(path, name, keys[2], f"{what} (IMAGE_SIDE_RANGE_PX)")
    return Camera(name, K, dist, R, t, (int(w), int(h)))


def _read_json(path: str | Path) -> Any:
    """Parsed JSON of a calibration file; CalibrationError when missing, unreadable or with a key twice."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f, object_pairs_hook=unique_keys)
    except FileNotFoundError:
        raise _error(path, None, None, "calibration file not found") from None
    except DuplicateKey as exc:  # its message: key 'k' appears twice in one object
        hint = "a camera or a parameter given twice; JSON would keep only the last"
        raise _error(path, None, None, f"{exc} ({hint})") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise _error(path, None, None, f"cannot read calibration JSON ({exc})") from None


def _camera_entries(data: Any, path: str | Path, numeric_order: bool) -> list[tuple[str, Any]]:
    """(name, entry) pairs of a {name: entry} file in file order, or numeric order if asked and possible."""
    if not isinstance(data, Mapping) or not data:
        raise _error(path, None, None, "expected a non-empty object {camera name: parameters}")
    items = [(str(k), v) for k, v in data.items()]
    if numeric_order and all(re.fullmatch(r"-?\d+", k) for k, _ in items):
        items.sort(key=lambda kv: int(kv[0]))
    return items


# --- the repository's cameras.json -----------------------------------------------------------------
def load_cameras_json(path: str | Path) -> Rig:
    """The repository's cameras.json (docs/formats.md): {name: {K, dist, R, t, size}}, metres, in file order."""
    cameras = []
    for name, entry in _camera_entries(_read_json(path), path, numeric_order=False):
        K, dist = _array(entry, "K", (3, 3), path, name), _array(entry, "dist", (5,), path, name)
        R, t = _array(entry, "R", (3, 3), path, name), _array(entry, "t", (3,), path, name)
        size = _array(entry, "size", (2,), path, name)
        cameras.append(_camera(name, K, dist, R, t, size, path, ("K", "R", "size")))
    return Rig(tuple(cameras))


def save_cameras_json(rig: Rig, path: str | Path) -> None:
    """Write a rig as cameras.json atomically (temporary file in the same folder, then os.replace)."""
    atomic_write_text(path, json.dumps(rig.to_dict(), indent=2) + "\n")


# --- Shelf / Campus: 4D Association, VoxelPose, original P matrices ---------------------------------
def load_4dassoc(path: str | Path) -> Rig:
    """4D Association calibration.json: K (9,), RT (12,) world->camera in m, imgSize [w, h], distCoeff(s)/dist (5,)."""
    cameras = []
    for name, entry in _camera_entries(_read_json(path), path, numeric_order=True):
        K = _array(entry, "K", (3, 3), path, name)
        RT = _array(entry, "RT", (3, 4), path, name)
        size = _array(entry, "imgSize", (2,), path, name)
        dist = np.zeros(5)
        for key in ("distCoeff", "distCoeffs", "dist"):
            if isinstance(entry, Mapping) and key in entry:
                dist = _array(entry, key, (5,), path, name)
        cameras.append(_camera(name, K, dist, RT[:, :3], RT[:, 3], size, path, ("K", "RT", "imgSize")))
    return Rig(tuple(cameras))


def load_voxelpose(path: str | Path, image_size: tuple[int, int] = SHELF_SIZE) -> Rig:
    """VoxelPose calibration_*.json (x_cam = R (X - T), T the centre in mm); no image size: Shelf's unless given."""
    cameras = []
    for name, entry in _camera_entries(_read_json(path), path, numeric_order=True):
        R = _rotation(_array(entry, "R", (3, 3), path, name), path, name, "R")
        T = _array(entry, "T", (3,), path, name)
        fx, fy, cx, cy = (float(_array(entry, key, (1,), path, name)[0]) for key in ("fx", "fy", "cx", "cy"))
        k, p = _array(entry, "k", (3,), path, name), _array(entry, "p", (2,), path, name)
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        dist = np.array([k[0], k[1], p[0], p[1], k[2]])
        cameras.append(_camera(name, K, dist, R, -R @ T / 1000.0, image_size, path, ("fx", "R", "image_size")))
    return Rig(tuple(cameras))


def _read_projection(path: Path) -> np.ndarray:
    """The 3x4 projection matrix of a Shelf/Campus P*.txt (3 lines of 4 comma-separated numbers): (3, 4)."""
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()][:3]
        P = np.array([[float(v) for v in re.split(r"[,\s]+", ln.strip())] for ln in lines])
    except FileNotFoundError:
        raise _error(path, None, None, "calibration file not found") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise _error(path, path.stem[1:], "P", f"cannot be read as 3 lines of 4 numbers ({exc})") from None
    if P.shape != (3, 4):
        raise _error(path, path.stem[1:], "P", f"has shape {P.shape}, expected (3, 4)")
    if not np.all(np.isfinite(P)):
        raise _error(path, path.stem[1:], "P", "has a non-finite value")
    return P


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P (3, 4) = s K [R | t] -> K (3, 3) with K[2, 2] = 1 and positive focals, R (3, 3) det +1, t (3,)."""
    P = np.asarray(P, dtype=np.float64)
    P = P * np.sign(np.linalg.det(P[:, :3]))  # det(K R) > 0 is needed for det(R) = +1
    K, R, C, *_ = cv2.decomposeProjectionMatrix(P)
    flip = np.diag(np.sign(np.diag(K)))
    K, R = K @ flip, flip @ R
    centre = C[:3, 0] / C[3, 0]
    return K / K[2, 2], R, -R @ centre


def load_shelf_projections(calib_dir: str | Path, image_size: tuple[int, int] = SHELF_SIZE) -> Rig:
    """Original Shelf/Campus Calibration/P{0..}.txt, decomposed into K, R, t (no distortion); names "0"..."""
    calib_dir = Path(calib_dir)
    files = [f for f in calib_dir.glob("P*.txt") if re.fullmatch(r"P\d+", f.stem)]
    files.sort(key=lambda f: int(f.stem[1:]))
    if not files:
        raise _error(calib_dir, None, None, "no projection matrix files P*.txt")
    cameras = []
    for file in files:
        K, R, t = decompose_projection(_read_projection(file))
        cameras.append(_camera(file.stem[1:], K, np.zeros(5), R, t, image_size, file, ("P", "P", "image_size")))
    return Rig(tuple(cameras))


# --- CMU Panoptic ----------------------------------------------------------------------------------
def panoptic_world_to_ours(points_cm: np.ndarray) -> np.ndarray:
    """Panoptic world points (cm, y down) to ours (m, z up): (..., 3) -> (..., 3), x_ours = M x_pan / 100."""
    return np.asarray(points_cm, dtype=np.float64) @ np.array(_PANOPTIC_M).T / 100.0


def load_panoptic(path: str | Path, cameras: Sequence[str] | None = None) -> Rig:
    """CMU Panoptic calibration_<seq>.json: HD cameras in file order, or the named ones; R M^T, t / 100 (metres)."""
    data = _read_json(path)
    if not isinstance(data, Mapping) or not isinstance(data.get("cameras"), list):
        raise _error(path, None, "cameras", "is missing or not a list")
    entries = {str(e.get("name")): e for e in data["cameras"] if isinstance(e, Mapping)}
    if cameras is None:
        names = [n for n, e in entries.items() if e.get("type") == "hd"]
    else:
        names = [str(n) for n in cameras]
        missing = [n for n in names if n not in entries]
        if missing:
            raise _error(path, missing[0], None, f"not in the calibration (cameras {sorted(entries)})")
    M = np.array(_PANOPTIC_M)
    rig = []
    for name in names:
        entry = entries[name]
        K, dist = _array(entry, "K", (3, 3), path, name), _array(entry, "distCoef", (5,), path, name)
        R, t = _array(entry, "R", (3, 3), path, name), _array(entry, "t", (3,), path, name)
        size = _array(entry, "resolution", (2,), path, name)
        rig.append(_camera(name, K, dist, R @ M.T, t / 100.0, size, path, ("K", "R", "resolution")))
    return Rig(tuple(rig))


# --- Wildtrack -------------------------------------------------------------------------------------
def _xml_array(path: Path, tag: str, shape: tuple[int, ...], camera: str) -> np.ndarray:
    """The whitespace-separated numbers in <tag>...</tag> (or its <data> child) of an XML file: shape."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise _error(path, None, None, "calibration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _error(path, camera, tag, f"cannot be read ({exc})") from None
    match = re.search(rf"<{tag}\b[^>]*>(.*?)</{tag}>", text, re.S)
    if match is None:
        raise _error(path, camera, tag, "is missing")
    body = re.search(r"<data>(.*?)</data>", match.group(1), re.S)
    try:
        values = [float(v) for v in (body.group(1) if body else match.group(1)).split()]
    except ValueError:
        raise _error(path, camera, tag, "is not a list of numbers") from None
    return _array({tag: values}, tag, shape, path, camera)


def load_wildtrack(root: str | Path) -> Rig:
    """Wildtrack calibrations/{intrinsic/intr_*, extrinsic/extr_*}.xml of the 7 cameras, tvec cm -> m (world z up)."""
    root = Path(root)
    calib = root / "calibrations" if (root / "calibrations").is_dir() else root
    cameras = []
    for name in WILDTRACK_CAMERAS:
        intr, extr = calib / "intrinsic" / f"intr_{name}.xml", calib / "extrinsic" / f"extr_{name}.xml"
        K = _xml_array(intr, "camera_matrix", (3, 3), name)
        dist = _xml_array(intr, "distortion_coefficients", (5,), name)
        rvec, tvec = _xml_array(extr, "rvec", (3,), name), _xml_array(extr, "tvec", (3,), name)
        R = cv2.Rodrigues(rvec)[0]
        cameras.append(_camera(name, K, dist, R, tvec / 100.0, WILDTRACK_SIZE, intr, ("camera_matrix", "rvec", "size")))
    return Rig(tuple(cameras))


def load_wildtrack_positions(path: str | Path) -> dict[int, np.ndarray]:
    """gt_positions_mvdet.txt rows 'frame grid_x grid_y' -> {frame: ground positions (N, 2) metres}."""
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read 'frame grid_x grid_y' rows ({exc})") from None
    if rows.shape[1] != 3 or not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: expected finite rows 'frame grid_x grid_y', got shape {rows.shape}")
    xy = np.asarray(WILDTRACK_GRID_ORIGIN) + WILDTRACK_GRID_STEP * rows[:, 1:3]
    frames = rows[:, 0].astype(np.int64)
    return {int(f): xy[frames == f] for f in np.unique(frames)}


# --- dispatch --------------------------------------------------------------------------------------
_SIGNATURES = (("4dassoc", {"K", "RT"}), ("voxelpose", {"R", "T", "fx"}), ("cameras_json", {"K", "R", "t"}))
_ALL_KEYS = {
    "cameras_json": {"K", "dist", "R", "t", "size"},
    "4dassoc": {"K", "RT", "imgSize"},
    "voxelpose": {"R", "T", "fx", "fy", "cx", "cy", "k", "p"},
}
# Without a complete camera, the format whose keys make up at least this fraction of the cameras' keys wins.
FORMAT_MIN_KEY_OVERLAP = 0.5


def detect_format(path: str | Path) -> str:
    """The calibration format name of a file or folder (see load_rig)."""
    from data.geometry.calibration_formats import detect_file_format  # it imports this module

    path = Path(path)
    other = detect_file_format(path)  # anipose TOML, EasyMocap or OpenCV YAML
    if other is not None:
        return other
    if path.is_dir():
        if (path / "calibrations").is_dir() or (path / "intrinsic").is_dir():
            return "wildtrack"
        if any(path.glob("P*.txt")):
            return "shelf_p"
        raise _error(path, None, None, "cannot detect the calibration format of this folder")
    data = _read_json(path)
    if isinstance(data, Mapping) and isinstance(data.get("cameras"), list):
        return "panoptic"
    entries = [e for e in data.values() if isinstance(e, Mapping)] if isinstance(data, Mapping) else []
    for fmt, required in _SIGNATURES:  # a camera with every required key decides; the loader names the others
        if any(required <= set(e) for e in entries):
            return fmt
    # No camera is complete (a typo 't' -> 'T'?): the format sharing most keys, whose loader names the missing one.
    keys = set().union(*(set(e) for e in entries)) if entries else set()
    overlap = {fmt: len(keys & every) / len(every) for fmt, every in _ALL_KEYS.items()}
    best = max(overlap, key=overlap.get)
    if overlap[best] >= FORMAT_MIN_KEY_OVERLAP:
        return best
    expected = "cameras.json {name: {K, dist, R, t, size}}, 4D Association, VoxelPose or Panoptic JSON; or .toml, .yml"
    raise _error(path, None, None, f"cannot detect the calibration format of this file (expected {expected})")


def load_rig(path: str | Path, fmt: str = "auto", check: bool = True, **kwargs: Any) -> Rig:
    """A calibration of format fmt (a key of ``loaders``, or auto), kwargs to its loader; check: run check_rig on it."""
    from data.geometry.calibration_formats import LOADERS  # it imports this module

    loaders = {
        "cameras_json": load_cameras_json,
        "4dassoc": load_4dassoc,
        "voxelpose": load_voxelpose,
        "panoptic": load_panoptic,
        "wildtrack": load_wildtrack,
        "shelf_p": load_shelf_projections,
        **LOADERS,
    }
    fmt = detect_format(path) if fmt == "auto" else fmt
    if fmt not in loaders:
        raise CalibrationError(f"{path}: unknown calibration format {fmt!r}, expected auto or one of {list(loaders)}")
    rig = loaders[fmt](path, **kwargs)
    if check:
        from data.geometry.check_rig import check_rig  # it imports this module

        check_rig(rig, path)
    return rig
