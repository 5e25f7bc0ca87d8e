"""python -m data.formats.openpose_json: OpenPose BODY_25 folders (one per camera) -> a poses2d.json dataset=files reads."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from data.datasets.files import load_files
from data.formats.openpose_json import camera_folders, main
from data.keypoints import BODY25_TO_COCO23

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_rig"


def coco23_to_body25(kps: np.ndarray) -> np.ndarray:
    """COCO-23 keypoints (23, 3) -> BODY_25 (25, 3), neck and mid-hip left at score 0."""
    out = np.zeros((25, 3))
    out[BODY25_TO_COCO23] = kps
    return out


def write_openpose_folders(root: Path) -> dict[tuple[int, str], list[np.ndarray]]:
    """The example's poses2d.json as OpenPose --write_json folders root/<camera>/: {(frame, camera): poses (23, 3)}."""
    poses: dict[tuple[int, str], list[np.ndarray]] = {}
    for e in json.loads((EXAMPLE / "poses2d.json").read_text()):
        poses.setdefault((e["frame"], e["camera"]), []).append(np.array(e["keypoints"]).reshape(23, 3))
    for (frame, camera), people in poses.items():
        folder = root / camera
        folder.mkdir(parents=True, exist_ok=True)
        doc = {
            "version": 1.3,
            "people": [{"person_id": [-1], "pose_keypoints_2d": coco23_to_body25(p).ravel().tolist()} for p in people],
        }
        (folder / f"{camera}_{frame:012d}_keypoints.json").write_text(json.dumps(doc))
    (root / "cam_a" / "notes.txt").write_text("not an OpenPose file")  # ignored
    return poses


def test_openpose_folders_round_trip_into_a_poses2d_json_dataset_files_reads(tmp_path, capsys):
    poses = write_openpose_folders(tmp_path / "openpose")
    out = tmp_path / "poses2d.json"
    assert main([str(tmp_path / "openpose" / "*"), "-o", str(out), "--cameras", str(EXAMPLE / "cameras.json")]) == 0
    assert "Wrote" in capsys.readouterr().out
    seq = load_files(EXAMPLE / "cameras.json", out)
    assert [f.index for f in seq.frames] == sorted({frame for frame, _ in poses})  # 100..139
    for frame in seq.frames:
        for v, name in enumerate(seq.rig.names):
            got = frame.views[v].keypoints
            want = np.stack(poses[(frame.index, name)])
            assert got.shape == want.shape and np.allclose(got, want, atol=1e-4)
            assert np.all(frame.views[v].bboxes[:, 2:] > 0) and np.all(frame.views[v].scores > 0)


def test_named_folders_and_scores_above_one_are_clipped(tmp_path):
    folder = tmp_path / "x"
    folder.mkdir()
    pose = np.tile([600.0, 300.0, 1.3], (25, 1))
    (folder / f"img_{7:012d}_keypoints.json").write_text(
        json.dumps({"people": [{"pose_keypoints_2d": pose.ravel().tolist()}]})
    )
    assert camera_folders([f"cam_b={folder}"]) == {"cam_b": folder}
    out = tmp_path / "p.json"
    assert main([f"cam_b={folder}", "-o", str(out)]) == 0
    (entry,) = json.loads(out.read_text())
    assert entry["frame"] == 7 and entry["camera"] == "cam_b" and max(entry["keypoints"][2::3]) == 1.0


def test_bad_folder_stops_with_one_line(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "data.formats.openpose_json",
        str(tmp_path / "missing"),
        "-o",
        str(tmp_path / "p.json"),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert (
        proc.returncode == 1
        and proc.stderr.strip() == f"error: {tmp_path / 'missing'}: not a folder of OpenPose JSON files"
    )
