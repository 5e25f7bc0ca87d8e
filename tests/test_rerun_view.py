"""viewer=rerun: eval.py writes recording.rrd, read back here with the rerun SDK's own reader (rerun.chunk.RrdReader):
the cameras' poses and pinholes, one row per frame of the 3D skeletons in the track ids' colours, the 2D detections,
the images of a rendered scene; without the package, one line naming pip install rerun-sdk."""

from __future__ import annotations

import sys
from collections import defaultdict
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from data.config_checks import ConfigError
from data.formats.poses_io import read_poses3d_frames
from evaluation.pictures.rerun_view import IMAGE_SIDE, RRD_NAME, save_rerun_recording
from evaluation.pictures.sequence_data import id_colors
from tests.test_eval import run_eval

SMALL = ["dataset.num_frames=3", "dataset.num_persons=3", "viewer=rerun"]


def read_rrd(path) -> dict[str, dict[str, list]]:
    """entity path -> column name -> one value per row (a list of instances), rows of all its chunks by frame."""
    from rerun.chunk import RrdReader

    columns: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for name in set(batch.schema.names) - {"log_time", "rerun.controls.RowId"}:  # log_time: wall clock
            columns[chunk.entity_path][name] += batch.column(name).to_pylist()
    for entity in columns.values():
        order = np.argsort(entity.get("frame", []), kind="stable")
        for name in entity if len(order) else ():
            entity[name] = [entity[name][i] for i in order]
    return columns


def rgba(rgb: np.ndarray) -> int:
    """(3,) RGB in [0, 1] -> rerun's packed 0xRRGGBBAA colour."""
    r, g, b = (int(round(255 * float(c))) for c in rgb)
    return (r << 24) | (g << 16) | (b << 8) | 255


def test_a_run_with_viewer_rerun_writes_the_scene_over_time(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun", reason="optional: pip install rerun-sdk")
    monkeypatch.setattr(sys, "platform", "linux")  # no display: viewer_spawn=true says so in one line
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    run_eval(tmp_path, [*SMALL, "viewer_spawn=true"])
    path = tmp_path / "pictures" / RRD_NAME
    assert "viewer_spawn=true: no display" in capsys.readouterr().out
    rrd, written = read_rrd(path), read_poses3d_frames(tmp_path / "poses3d.json")
    colors = id_colors(i for _, _, ids in written for i in ids)
    skeletons, ids = rrd["/world/skeletons/joints"], rrd["/world/skeletons/ids"]
    assert skeletons["frame"] == [f for f, _, _ in written] and len(written) == 3  # one row per frame
    for (_, poses, frame_ids), joint_colors, labels in zip(
        written, skeletons["Points3D:colors"], ids["Points3D:labels"]
    ):
        assert set(joint_colors) == {rgba(colors[i]) for i in frame_ids}  # each track id in its colour
        assert labels == [f"id {i}" for i in frame_ids]
        assert len(joint_colors) == int((poses[..., 3] > 0).sum())
    assert rrd["/world/skeletons"]["frame"] == rrd["/world/cameras/0/detections"]["frame"] == [0, 1, 2]
    assert "/world/ground" in rrd and not any(p.endswith("/image") for p in rrd)  # no images: detections only


def test_cameras_project_like_the_rig_and_each_skeleton_has_its_track_id_colour(tmp_path):
    pytest.importorskip("rerun", reason="optional: pip install rerun-sdk")
    from data.datasets.synthetic import load_synthetic

    sequence = load_synthetic(num_frames=1, num_persons=2)
    gt = sequence.frames[0].gt_poses
    results = [SimpleNamespace(frame=0, poses3d=gt, ids=np.array([7, 2]))]  # ids that are not the indices
    rrd = read_rrd(save_rerun_recording(tmp_path, sequence, results, "rerun", False))
    colors = id_colors([7, 2])
    joint_colors = rrd["/world/skeletons/joints"]["Points3D:colors"][0]
    n = int((gt[0, :, 3] > 0).sum())
    assert set(joint_colors[:n]) == {rgba(colors[7])} and set(joint_colors[n:]) == {rgba(colors[2])}
    for camera in sequence.rig:
        entity = {k: v[0][0] for k, v in rrd[f"/world/cameras/{camera.name}"].items()}
        R_world = np.reshape(entity["Transform3D:mat3x3"], (3, 3), order="F")  # camera -> world, column-major
        K = np.reshape(entity["Pinhole:image_from_camera"], (3, 3), order="F")
        w, h = entity["Pinhole:resolution"]
        point = np.array([0.3, -0.2, 1.1])
        x_cam = R_world.T @ (point - np.asarray(entity["Transform3D:translation"]))
        uv = (K @ x_cam)[:2] / x_cam[2] * np.array(camera.size) / [w, h]  # back to calibration pixels
        np.testing.assert_allclose(uv, camera.project(point), atol=1e-2)
        assert max(w, h) == min(IMAGE_SIDE, max(camera.size))


def test_a_rendered_scene_logs_each_camera_image_as_a_small_jpeg(tmp_path):
    pytest.importorskip("rerun", reason="optional: pip install rerun-sdk")
    run_eval(tmp_path, [*SMALL, "dataset.render=true", "dataset.image_size=[640,360]"])
    rrd = read_rrd(tmp_path / "pictures" / RRD_NAME)
    images = rrd["/world/cameras/0/image"]
    assert images["frame"] == [0, 1, 2] and images["EncodedImage:media_type"][0] == ["image/jpeg"]
    image = cv2.imdecode(np.frombuffer(bytes(images["EncodedImage:blob"][0][0]), np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (270, 480, 3) and image.std() > 10  # 640 x 360 at IMAGE_SIDE 480, not blank
    assert (tmp_path / "pictures" / RRD_NAME).stat().st_size < 2_000_000


def test_without_the_package_the_run_stops_with_one_line_naming_pip(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    with pytest.raises(ConfigError, match="pip install rerun-sdk") as err:
        run_eval(tmp_path, SMALL)
    assert "\n" not in str(err.value) and not (tmp_path / "poses3d.json").exists()  # stopped before the frames ran


@pytest.mark.parametrize(
    ("viewer", "spawn", "key"), [("rviz", False, "viewer='rviz'"), ("rerun", "yes", "viewer_spawn")]
)
def test_a_bad_viewer_value_names_its_key(tmp_path, viewer, spawn, key):
    with pytest.raises(ConfigError, match=key):
        save_rerun_recording(tmp_path, None, [], viewer, spawn)
    with pytest.raises(ConfigError, match=key):  # eval.py checks it before the frames run
        run_eval(tmp_path, [*SMALL, f"viewer={viewer}", f"viewer_spawn={spawn}"])
    assert not (tmp_path / "poses3d.json").exists()
