"""dataset=images: folders, videos and single images of a calibrated rig, read lazily at the calibration size."""

from __future__ import annotations

import json
import shutil
import warnings

import cv2
import numpy as np
import pytest

from data.datasets.images import ImageSizeWarning, load_images, main
from data.formats.image_sources import ImageSourceError
from data.geometry.calibration import save_cameras_json
from data.image_ids import coco_image_id
from data.pose2d.scene_render import render_sequence
from data.synthetic import SyntheticConfig, generate_sequence

SIZE = (160, 120)


@pytest.fixture(scope="module")
def scene():
    """A rendered synthetic sequence: 3 cameras of 160 x 120, 4 frames."""
    cfg = SyntheticConfig(seed=2, num_frames=4, num_persons=4, num_cameras=3, image_size=SIZE, focal_px=150.0)
    return render_sequence(generate_sequence(cfg), seed=5)


@pytest.fixture(scope="module")
def rendered(scene):
    """Every frame's rendered images, (F, V) of (120, 160, 3)."""
    return [frame.images() for frame in scene.frames]


def write_rig(scene, folder):
    path = folder / "cameras.json"
    save_cameras_json(scene.rig, path)
    return path


def write_folders(scene, rendered, root, names=None):
    for v, cam in enumerate(scene.rig):
        (root / cam.name).mkdir(parents=True)
        for f, images in enumerate(rendered):
            stem = f"{f:06d}" if names is None else names[v][f]
            cv2.imwrite(str(root / cam.name / f"{stem}.png"), images[v])
    return root


def write_videos(scene, rendered, root, fourcc="FFV1", frames=None):
    root.mkdir(parents=True, exist_ok=True)
    for v, cam in enumerate(scene.rig):
        writer = cv2.VideoWriter(str(root / f"{cam.name}.avi"), cv2.VideoWriter_fourcc(*fourcc), 5.0, SIZE)
        assert writer.isOpened()
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 100)  # MJPG: the best JPEG quality
        for images in rendered[: frames[v] if frames else None]:
            writer.write(images[v])
        writer.release()
    return root


def test_folder_and_video_give_the_rendered_images(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    folders = load_images(cameras, write_folders(scene, rendered, tmp_path / "folders"))
    videos = load_images(cameras, write_videos(scene, rendered, tmp_path / "videos"))
    mjpg = load_images(cameras, write_videos(scene, rendered, tmp_path / "mjpg", fourcc="MJPG"))
    assert [f.index for f in folders.frames] == [f.index for f in videos.frames] == [0, 1, 2, 3]
    for f, (a, b, c, source) in enumerate(zip(folders.frames, videos.frames, mjpg.frames, scene.frames)):
        assert a.image_ids == b.image_ids == source.image_ids  # the same ids as the render: a detections file fits both
        assert all(len(view) == 0 for view in a.views + b.views)
        for v, (x, y, z, truth) in enumerate(zip(a.images(), b.images(), c.images(), source.images())):
            assert x.shape == (120, 160, 3) and x.dtype == np.uint8
            np.testing.assert_array_equal(x, truth)  # PNG and FFV1 are lossless
            np.testing.assert_array_equal(y, truth)
            psnr = [cv2.PSNR(z, images[v]) for images in rendered]  # MJPG is lossy: nearest to its own frame
            assert psnr[f] > 25 and np.argmax(psnr) == f
    assert videos.coco_images[4] == {
        "id": coco_image_id(1, 1, 3),
        "frame": 1,
        "camera": "1",
        "file_name": str(tmp_path / "videos" / "1.avi"),
        "width": 160,
        "height": 120,
        "video_frame": 1,
    }


def test_the_render_truth_carries_over_to_images_read_back(scene, rendered, tmp_path):
    """Read-back images paired with the render's ground-truth views give the same arrays as the render itself."""
    cameras = write_rig(scene, tmp_path)
    loaded = load_images(cameras, write_videos(scene, rendered, tmp_path / "videos"))
    for frame, source in zip(loaded.frames, scene.frames):
        assert frame.image_ids == [coco_image_id(source.index, v, len(scene.rig)) for v in range(len(scene.rig))]
        crops = [_crops(im, view.bboxes) for im, view in zip(frame.images(), source.views)]
        truth = [_crops(im, view.bboxes) for im, view in zip(source.images(), source.views)]
        for a, b in zip(crops, truth):
            assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def _crops(image, boxes):
    return [image[int(y) : int(y + h), int(x) : int(x + w)] for x, y, w, h in boxes]


def test_shelf_images_are_rescaled_to_the_calibration_with_one_warning_per_camera(shared_data):
    calib = shared_data / "shelf" / "calibration_shelf.json"
    folder = shared_data / "shelf" / "images_000572"
    with pytest.warns(ImageSizeWarning) as caught:
        seq = load_images(calib, folder, pattern="cam{i}.png")
    messages = [str(w.message) for w in caught if issubclass(w.category, ImageSizeWarning)]
    assert len(messages) == 5
    assert all("1920x1080" in m and "1032x776" in m and "aspect ratios differ" in m for m in messages)
    assert "cam3.png" in messages[3]
    assert len(seq.frames) == 1 and [c.size for c in seq.rig] == [(1032, 776)] * 5
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImageSizeWarning)  # reading says nothing more
        images = seq.frames[0].images()
    original = cv2.imread(str(folder / "cam2.png"))
    expected = cv2.resize(original, (1032, 776), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(images[2], expected)
    assert seq.coco_images[2]["width"] == 1920 and seq.meta["image_sizes"]["2"] == [1920, 1080]


def test_same_aspect_ratio_warns_without_the_aspect_note(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    big = [[cv2.resize(im, (320, 240)) for im in images] for images in rendered]
    with pytest.warns(ImageSizeWarning) as caught:
        seq = load_images(cameras, write_folders(scene, big, tmp_path / "big"))
    assert len(caught) == 3 and not any("aspect ratios" in str(w.message) for w in caught)
    assert seq.frames[0].images()[0].shape == (120, 160, 3)


def test_mapping_pattern_glob_and_frame_selection(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    root = write_folders(scene, rendered, tmp_path / "folders")
    mapping = {cam.name: str(root / cam.name) for cam in scene.rig}
    by_map = load_images(cameras, mapping, frames="1:4:2")
    by_glob = load_images(cameras, root, pattern="{name}/0000*.png", frames=[3, 1])
    assert [f.index for f in by_map.frames] == [f.index for f in by_glob.frames] == [1, 3]
    for a, b in zip(by_map.frames, by_glob.frames):
        for x, y in zip(a.images(), b.images()):
            np.testing.assert_array_equal(x, y)
    single = tmp_path / "single"
    single.mkdir()
    for v in range(3):
        cv2.imwrite(str(single / f"cam{v}.png"), rendered[2][v])
    one = load_images(cameras, single, pattern="cam{i}.png")
    assert len(one.frames) == 1
    np.testing.assert_array_equal(one.frames[0].images()[1], rendered[2][1])


def test_align_by_name_keeps_the_common_stems(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    names = [["10", "20", "30", "40"], ["10", "20", "30", "40"], ["10", "20", "30", "45"]]
    root = write_folders(scene, rendered, tmp_path / "folders", names)
    with pytest.warns(UserWarning, match="keeps the 3 stems"):
        seq = load_images(cameras, root, align="name")
    assert [f.index for f in seq.frames] == [10, 20, 30]
    np.testing.assert_array_equal(seq.frames[1].images()[2], rendered[1][2])
    with pytest.raises(ValueError, match="unequal frame counts"):
        load_images(cameras, write_videos(scene, rendered, tmp_path / "videos", frames=[4, 4, 3]))


def test_images_are_read_only_when_called(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    root = write_folders(scene, rendered, tmp_path / "folders")
    seq = load_images(cameras, root)
    (root / "1" / "000002.png").unlink()
    seq.frames[1].images()
    with pytest.raises(ImageSourceError, match=r"1/000002\.png"):
        seq.frames[2].images()


def test_bad_input_names_the_path(scene, rendered, tmp_path):
    cameras = write_rig(scene, tmp_path)
    with pytest.raises(ImageSourceError, match="nowhere"):
        load_images(cameras, tmp_path / "nowhere")
    root = write_folders(scene, rendered, tmp_path / "folders")
    shutil.rmtree(root / "2")
    with pytest.raises(ImageSourceError, match="camera '2' needs one sub-folder"):
        load_images(cameras, root)
    videos = write_videos(scene, rendered, tmp_path / "videos")
    (videos / "1.avi").write_bytes(b"not a video")
    with pytest.raises(ImageSourceError, match=r"1\.avi: OpenCV cannot open"):
        load_images(cameras, videos)
    broken = write_folders(scene, rendered, tmp_path / "broken")
    (broken / "0" / "000003.png").write_bytes(b"not a png")
    seq = load_images(cameras, broken)
    with pytest.raises(ImageSourceError, match=r"0/000003\.png: cannot read"):
        seq.frames[3].images()
    with pytest.raises(ValueError, match="frame 9 is not among"):
        load_images(cameras, broken, frames=[9])
    with pytest.raises(ValueError, match=r"pattern='\{cam\}.png': only \{name\} and \{i\}"):
        load_images(cameras, broken, pattern="{cam}.png")
    with pytest.raises(ImageSourceError, match=r"0\.avi: align=name needs folders"):
        load_images(cameras, write_videos(scene, rendered, tmp_path / "v2"), align="name")
    with pytest.raises(ValueError, match="camera 'x' is not in the calibration"):
        load_images(cameras, {"0": "a", "1": "b", "2": "c", "x": "d"})


def test_cli_writes_the_coco_images_list(scene, rendered, tmp_path, capsys):
    cameras = write_rig(scene, tmp_path)
    root = write_folders(scene, rendered, tmp_path / "folders")
    main(["--cameras", str(cameras), "--images", str(root), "--frames", "0:2", "-o", str(tmp_path / "ids.json")])
    doc = json.loads((tmp_path / "ids.json").read_text())
    assert [(i["frame"], i["camera"]) for i in doc["images"]] == [(f, c) for f in (0, 1) for c in ("0", "1", "2")]
    assert [i["id"] for i in doc["images"]] == [coco_image_id(f, v, 3) for f in (0, 1) for v in range(3)]
    with pytest.raises(SystemExit):
        main(["--cameras", str(cameras), "--images", str(tmp_path / "none"), "-o", str(tmp_path / "x.json")])
    assert "none: no such folder" in capsys.readouterr().err
