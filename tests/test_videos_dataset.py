"""dataset=videos: one video per camera with frame offsets, read forward as a stream; the same frames, coco images and
poses3d.json as dataset=images; bad input stops with one line naming the file, camera or key."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.config_checks import ConfigError
from data.datasets.images import load_images
from data.datasets.videos import VideoLengthWarning, load_videos
from data.formats.image_sources import ImageSourceError, VideoReader, open_source
from data.formats.poses2d_io import Poses2DError
from data.geometry.calibration import CalibrationError
from data.image_ids import coco_image_id
from data.pose2d.scene_render import render_sequence
from data.synthetic import SyntheticConfig, generate_sequence
from run_folders import one_line_errors, register_resolvers
from tests.test_images_dataset import SIZE, write_folders, write_rig
from tests.test_sppe_stage import write_tiny_checkpoint

REPO = Path(__file__).resolve().parents[1]
FRAMES = 6


@pytest.fixture(scope="module")
def scene():
    """A rendered synthetic sequence: 3 cameras of 160 x 120, 6 frames, 3 persons."""
    cfg = SyntheticConfig(seed=2, num_frames=FRAMES, num_persons=3, num_cameras=3, image_size=SIZE, focal_px=150.0)
    return render_sequence(generate_sequence(cfg), seed=5)


@pytest.fixture(scope="module")
def rendered(scene):
    """Every frame's rendered images, (F, V) of (120, 160, 3)."""
    return [frame.images() for frame in scene.frames]


@pytest.fixture(scope="module")
def rig_and_videos(scene, rendered, tmp_path_factory):
    """cameras.json and a folder of lossless (FFV1) <camera>.avi, the aligned set."""
    root = tmp_path_factory.mktemp("videos")
    return write_rig(scene, root), write_videos(rendered, root / "aligned", scene.rig.names)


def write_videos(rendered, root: Path, names, lead=None, frames=None, suffix="avi") -> Path:
    """<camera>.<suffix> per camera (FFV1, or mp4v for .mp4) of its rendered frames, lead[v] black frames first,
    the first frames[v] only."""
    root.mkdir(parents=True, exist_ok=True)
    fourcc = cv2.VideoWriter_fourcc(*("mp4v" if suffix == "mp4" else "FFV1"))
    for v, name in enumerate(names):
        writer = cv2.VideoWriter(str(root / f"{name}.{suffix}"), fourcc, 5.0, SIZE)
        pictures = [np.zeros_like(rendered[0][v])] * (lead[v] if lead else 0) + [im[v] for im in rendered]
        for picture in pictures[: (lead[v] if lead else 0) + frames[v] if frames else None]:
            writer.write(picture)
        writer.release()
    return root


def assert_same_frames(a, b) -> None:
    assert [f.index for f in a.frames] == [f.index for f in b.frames]
    for x, y in zip(a.frames, b.frames):
        assert x.image_ids == y.image_ids
        for p, q in zip(x.images(), y.images()):
            np.testing.assert_array_equal(p, q)


def test_videos_give_the_images_and_coco_images_of_dataset_images(scene, rendered, rig_and_videos, tmp_path):
    cameras, videos = rig_and_videos
    seq = load_videos(cameras, videos)
    assert_same_frames(seq, load_images(cameras, write_folders(scene, rendered, tmp_path / "png")))  # FFV1 lossless
    assert seq.coco_images == load_images(cameras, videos).coco_images
    assert seq.coco_images[4]["id"] == coco_image_id(1, 1, 3) and seq.coco_images[4]["video_frame"] == 1
    by_map = load_videos(cameras, {int(n): str(videos / f"{n}.avi") for n in scene.rig.names})  # Hydra: int keys
    assert_same_frames(seq, by_map)
    assert seq.meta["offsets"] == {"0": 0, "1": 0, "2": 0} and "6 frames of 3 cameras (video)" in seq.description


def test_an_offset_aligns_a_camera_whose_video_has_three_frames_more_at_the_start(scene, rendered, rig_and_videos):
    cameras, aligned = rig_and_videos
    late = write_videos(rendered, aligned.parent / "late", scene.rig.names, lead=[0, 0, 3])
    seq = load_videos(cameras, late, offsets={2: 3})
    assert_same_frames(seq, load_videos(cameras, aligned))
    assert seq.coco_images[2]["video_frame"] == 3 and seq.coco_images[5]["video_frame"] == 4
    with pytest.warns(VideoLengthWarning, match=r"'0': 6, '1': 6, '2': 9\): frames 0\.\.5 used"):
        load_videos(cameras, late)  # no offset: camera 2 is 3 frames longer


def test_stride_range_and_list(rig_and_videos, rendered):
    cameras, videos = rig_and_videos
    assert [f.index for f in load_videos(cameras, videos, frames="1:6:2").frames] == [1, 3, 5]
    assert [f.index for f in load_videos(cameras, videos, frames="2:").frames] == [2, 3, 4, 5]
    listed = load_videos(cameras, videos, frames=[4, 0, 4])
    assert [f.index for f in listed.frames] == [0, 4]
    np.testing.assert_array_equal(listed.frames[1].images()[2], rendered[4][2])


def test_unequal_lengths_warn_in_one_line_or_stop_an_explicit_range(scene, rendered, rig_and_videos):
    cameras, aligned = rig_and_videos
    short = write_videos(rendered, aligned.parent / "short", scene.rig.names, frames=[6, 6, 4])
    with pytest.warns(VideoLengthWarning) as caught:
        seq = load_videos(cameras, short)
    assert [f.index for f in seq.frames] == [0, 1, 2, 3]
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert "('0': 6, '1': 6, '2': 4): frames 0..3 used" in str(caught[0].message)
    with pytest.raises(ValueError, match=r"frames='0:6': camera '2' has no frame 4 \(.*short/2\.avi, offset 0"):
        load_videos(cameras, short, frames="0:6")


def one_line(cameras: Path, videos, *overrides: str) -> str:
    """The message eval.py prints for dataset=videos on these files (one line, asserted), as eval.main stops."""
    cfg = config("dataset=videos", f"dataset.cameras={cameras}", f"dataset.videos={videos}", *overrides)
    with pytest.raises(SystemExit) as stop, one_line_errors(ConfigError, CalibrationError, Poses2DError, config=cfg):
        eval_script.run(cfg, cameras.parent / "run")
    message = str(stop.value)
    assert message.startswith("error: ") and "\n" not in message
    return message


@pytest.mark.parametrize(
    "case, overrides, expected",
    [
        ("missing", (), r"error: dataset: .*missing: no such folder of images"),
        ("mapping", (), r"error: dataset: .*nowhere\.mp4: no such folder, video or image"),
        ("corrupt", (), r"error: dataset: .*1\.mp4: OpenCV cannot open this video"),
        ("folder", (), r"error: dataset: .*/1: dataset=videos reads one video per camera, this is a folder"),
        ("aligned", ("dataset.offsets={1: 1.5}",), r"error: dataset: offsets: camera '1': 1.5 is not an int"),
        ("aligned", ("dataset.offsets={1: x}",), r"error: dataset: offsets: camera '1': 'x' is not an int"),
        ("aligned", ("dataset.offsets={7: 1}",), r"error: dataset: offsets: camera '7' is not in the calibration"),
        ("aligned", ("dataset.offsets={0: -1}",), r"camera '0': -1 puts frame 0 before the start of .*0\.avi"),
        ("aligned", ("dataset.offsets={0: 6}",), r"camera '0': 6 puts frame 0 past the end of .*0\.avi \(6 frames"),
        ("aligned", ("dataset.offsets=3",), r"error: dataset.offsets=3: a mapping camera -> frames"),
        ("aligned", ("dataset.frames='4:9'",), r"error: dataset.frames='4:9': camera '0' has no frame 6 \(.*0\.avi"),
        ("aligned", ("dataset.frames=[7]",), r"error: dataset.frames=\[7\]: camera '0' has no frame 7"),
    ],
)
def test_bad_input_stops_with_one_line_naming_the_file_camera_or_key(case, overrides, expected, rig_and_videos):
    cameras, aligned = rig_and_videos
    videos = {
        "aligned": aligned,
        "missing": aligned.parent / "missing",
        "mapping": f"{{0:'{aligned / '0.avi'}',1:'{aligned / 'nowhere.mp4'}',2:'{aligned / '2.avi'}'}}",
    }.get(case) or broken_set(aligned, case)  # fmt: skip
    assert re.search(expected, one_line(cameras, videos, *overrides))


def broken_set(aligned: Path, case: str) -> Path:
    """A folder with the aligned videos of cameras 0 and 2, and for camera 1 a text file named 1.mp4 (corrupt) or a
    folder of images (folder)."""
    root = aligned.parent / case
    if not root.exists():
        root.mkdir()
        for name in "02":
            (root / f"{name}.mp4").symlink_to(aligned / f"{name}.avi")
        if case == "corrupt":
            (root / "1.mp4").write_text("not a video")
        else:
            (root / "1").mkdir()
            cv2.imwrite(str(root / "1" / "0.png"), np.zeros((120, 160, 3), np.uint8))
    return root


def test_a_corrupt_video_prints_exactly_one_line_from_eval_py(rig_and_videos):
    """The whole process: FFmpeg's own complaint (e.g. 'moov atom not found') is silenced, eval.py's line stands."""
    cameras, aligned = rig_and_videos
    videos = broken_set(aligned, "corrupt")
    run_dir = f"hydra.run.dir={cameras.parent / 'proc'}"
    cmd = [sys.executable, "eval.py", "dataset=videos", f"dataset.cameras={cameras}", f"dataset.videos={videos}"]
    proc = subprocess.run([*cmd, run_dir], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert re.fullmatch(r"error: (dataset: )?.*corrupt/1\.mp4: OpenCV cannot open this video.*\n", proc.stderr)


def test_frames_are_streamed_through_one_open_capture_per_camera(rig_and_videos, rendered, monkeypatch):
    cameras, videos = rig_and_videos
    seq = load_videos(cameras, videos, frames=[0, 2, 3, 5])
    reader = VideoReader(open_source(videos / "0.avi"), max_skip=1)  # opens the video when it first reads
    opens, seeks = [], []

    real = cv2.VideoCapture

    class Counting:  # a proxy: a Python subclass of cv2.VideoCapture crashes the garbage collector
        def __init__(self, path: str) -> None:
            opens.append(path)
            self.capture = real(path)

        def set(self, prop: int, value: float) -> bool:
            seeks.append(value) if prop == cv2.CAP_PROP_POS_FRAMES else None
            return self.capture.set(prop, value)

        def __getattr__(self, name: str):
            return getattr(self.capture, name)

    monkeypatch.setattr(cv2, "VideoCapture", Counting)
    for f, frame in zip([0, 2, 3, 5], seq.frames):
        for v, image in enumerate(frame.images()):
            np.testing.assert_array_equal(image, rendered[f][v])
    assert len(opens) == 3 and seeks == []  # one capture per camera, the gaps grabbed over
    np.testing.assert_array_equal(seq.frames[1].images()[0], rendered[2][0])  # backwards: one seek per camera
    assert len(opens) == 3 and seeks == [2, 2, 2]
    np.testing.assert_array_equal(reader.read(4), rendered[4][0])  # far ahead: a seek
    assert len(opens) == 4 and seeks == [2, 2, 2, 4]
    with pytest.raises(ImageSourceError, match=r"0\.avi: no frame 6 \(it has 6\)"):
        reader.read(6)


def config(*overrides: str):
    register_resolvers()
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        return compose("eval", overrides=list(overrides))


def test_eval_on_videos_writes_the_poses3d_json_of_dataset_images_with_a_frames_per_second_bar(
    scene, rendered, rig_and_videos, tmp_path, capfd
):
    """The 2D stage: a random tiny SPPE (no weights to download) on the scene's ground-truth boxes (detector=file)."""
    cameras, videos = rig_and_videos
    boxes = [
        {"image_id": i, "category_id": 1, "bbox": [float(x) for x in box], "score": 1.0}
        for frame in scene.frames[0:6:2]
        for i, view in zip(frame.image_ids, frame.views)
        for box in view.bboxes
    ]
    (tmp_path / "boxes.json").write_text(json.dumps(boxes))
    checkpoint = write_tiny_checkpoint(tmp_path / "best.pth", padding=1.25)
    stage = ["pose2d=sppe", f"pose2d.checkpoint={checkpoint}", "pose2d.device=cpu", "detector=file"]
    stage += [f"detector.path={tmp_path / 'boxes.json'}"]
    folders = write_folders(scene, rendered, tmp_path / "png")
    runs = {
        "videos": ["dataset=videos", f"dataset.videos={videos}", "dataset.frames='0:6:2'"],
        "images": ["dataset=images", f"dataset.images={folders}", "dataset.frames='0:6:2'"],
    }
    for name, dataset in runs.items():
        capfd.readouterr()
        eval_script.run(config(*dataset, f"dataset.cameras={cameras}", *stage), tmp_path / name)
        bar = capfd.readouterr().err
        assert re.search(r"2D poses: 100%.* 3/3 .*(frame/s|s/frame)", bar), bar[-500:]
    doc = json.loads((tmp_path / "videos" / "poses3d.json").read_text())
    assert [f["frame"] for f in doc["frames"]] == [0, 2, 4] and any(f["poses"] for f in doc["frames"])
    assert doc.pop("fps") == 5.0  # the videos' frame rate; image folders have none
    assert doc == json.loads((tmp_path / "images" / "poses3d.json").read_text())
