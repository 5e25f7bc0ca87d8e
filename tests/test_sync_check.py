"""dataset.offsets of dataset=files and the rig check's sync part: a camera whose 2D poses fit the others' best
shifted by a few frames is named with the offsets that fix it; in-sync rigs (the example, Shelf, Panoptic) are not."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.datasets.files import load_files, shifted
from data.datasets.panoptic import load_panoptic_sequence
from data.datasets.shelf import load_shelf
from data.formats.poses2d_io import poses2d_entries, read_poses2d
from data.formats.poses_io import read_poses3d
from data.geometry.calibration import load_rig
from data.geometry.camera import Rig
from data.geometry.check_rig import RigWarning, main
from data.geometry.sync_check import sync_findings
from data.synthetic import SyntheticConfig, generate_sequence
from models.paf_grouping import group_view

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_rig"
CAMERAS = EXAMPLE / "cameras.json"
RIG = load_rig(CAMERAS, check=False)
VIEWS = read_poses2d(EXAMPLE / "poses2d.json", RIG.names)


def shifted_copy(tmp_path: Path, camera: str = "cam_b", by: int = 3) -> Path:
    """The example's poses2d.json with camera's frame numbers + by: its detections of frame f filed as f + by."""
    entries = json.loads((EXAMPLE / "poses2d.json").read_text())
    for e in entries:
        e["frame"] += by if e["camera"] == camera else 0
    path = tmp_path / "poses2d.json"
    path.write_text(json.dumps(entries))
    return path


def load_warnings(poses2d: Path, **options) -> list[str]:
    """The RigWarning messages of loading the example's cameras with poses2d."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_files(CAMERAS, poses2d, **options)
    return [str(w.message) for w in caught if issubclass(w.category, RigWarning)]


def test_the_example_is_the_synthetic_crowd_of_seed_7():
    """How examples/own_rig/poses2d.json was made: 3 persons, a ring of 3 cameras, frames renumbered from 100."""
    seq = generate_sequence(SyntheticConfig(seed=7, num_persons=3, num_cameras=3, num_frames=40))
    assert [c.name for c in seq.rig] == ["0", "1", "2"] and all(np.allclose(a.P, b.P) for a, b in zip(seq.rig, RIG))
    entries = poses2d_entries({f.index + 100: f.views for f in seq.frames}, list(RIG.names))
    text = json.dumps([{k: v for k, v in e.items() if k != "id"} for e in entries])
    assert text == (EXAMPLE / "poses2d.json").read_text()


def test_a_camera_offset_by_3_frames_is_named_with_the_offsets_that_fix_it(tmp_path, capsys):
    assert main([str(CAMERAS), str(shifted_copy(tmp_path))]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].endswith("0 errors, 1 warnings")  # the sync warning stands in for "does not fit the others"
    assert lines[0].startswith(f"warning: {CAMERAS}: camera 'cam_b': out of sync by 3 frames? its frame f + 3 fits")
    assert lines[0].endswith('"dataset.offsets={cam_b: 3}"')
    (early,) = load_warnings(shifted_copy(tmp_path, "cam_c", -3))  # at load time too, the other way round
    assert "camera 'cam_c': out of sync by 3 frames? its frame f - 3 fits" in early
    assert early.endswith('"dataset.offsets={cam_c: -3}"')


def test_the_in_sync_example_gives_no_warning(capsys):
    assert sync_findings(list(RIG), VIEWS) == {}
    assert main([str(CAMERAS), str(EXAMPLE / "poses2d.json")]) == 0
    assert capsys.readouterr().out.endswith("0 errors, 0 warnings\n")


def test_an_offset_already_given_is_part_of_the_fix(tmp_path):
    path = shifted_copy(tmp_path)
    assert load_warnings(path, offsets={"cam_b": 3}) == []
    (text,) = load_warnings(path, offsets={"cam_b": 1, "cam_a": 0})  # 2 frames left: the fix is the whole offset
    assert "'cam_b': out of sync by 2 frames? its frame f + 2" in text and '"dataset.offsets={cam_b: 3}"' in text


def test_of_two_cameras_only_one_is_named():
    two = Rig(tuple(list(RIG)[:2]))
    found = sync_findings(list(two), shifted({f: v[:2] for f, v in VIEWS.items()}, [0, -3]))
    assert [f.message.split(":")[0] for f in found.values()] in (["camera 'cam_a'"], ["camera 'cam_b'"])


def _poses(tmp_path: Path, poses2d: Path, *overrides: str) -> dict[int, np.ndarray]:
    """poses3d.json of eval.py on the example's cameras and poses2d: {frame: (P, 23, 4)}."""
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        cfg = compose(
            "eval",
            ["progress=false", "dataset=files", f"dataset.cameras={CAMERAS}", f"dataset.poses2d={poses2d}", *overrides],
        )
    eval_script.run(cfg, tmp_path)
    return read_poses3d(tmp_path / "poses3d.json")


def test_the_offsets_of_the_warning_restore_the_reconstruction(tmp_path):
    want = _poses(tmp_path / "example", EXAMPLE / "poses2d.json")
    got = _poses(tmp_path / "fixed", shifted_copy(tmp_path), "dataset.offsets={cam_b: 3}")
    assert sorted(got) == sorted(want) == list(range(100, 140))
    assert all(np.array_equal(got[f], want[f]) for f in want)


def test_negative_offsets_move_a_camera_later_and_keep_its_frames():
    with pytest.warns(RigWarning, match=r"'cam_a': out of sync by 2 frames\? .*\"dataset.offsets=\{cam_a: 0\}\"$"):
        seq = load_files(CAMERAS, EXAMPLE / "poses2d.json", offsets={"cam_a": -2})  # the check undoes it
    counts = {f.index: [len(v) for v in f.views] for f in seq.frames}
    assert sorted(counts) == list(range(100, 142)) and seq.meta["offsets"] == {"cam_a": -2, "cam_b": 0, "cam_c": 0}
    assert counts[100] == counts[101] == [0, 3, 3] and counts[140] == counts[141] == [3, 0, 0]
    assert np.array_equal(seq.frames[5].views[0].keypoints, VIEWS[103][0].keypoints)  # cam_a's 103 is frame 105


@pytest.mark.parametrize(
    "offsets,message",
    [
        ({"cam_b": 3.5}, "offsets: camera 'cam_b': 3.5 is not an int number of frames"),
        ({"cam_b": "3"}, "offsets: camera 'cam_b': '3' is not an int number of frames"),
        ({"cam_b": True}, "offsets: camera 'cam_b': True is not an int number of frames"),
        ({"cam_z": 3}, "offsets: camera 'cam_z' is not in the calibration (cameras ['cam_a', 'cam_b', 'cam_c'])"),
        (3, "offsets=3: a mapping camera -> frames (e.g. {cam_c: 3}), or null"),
    ],
)
def test_bad_offsets_stop_with_the_lines_of_dataset_videos(offsets, message):
    with pytest.raises(ValueError) as err:
        load_files(CAMERAS, EXAMPLE / "poses2d.json", offsets=offsets)
    assert str(err.value) == message


def test_shelf_real_detections_in_sync_give_no_sync_warning(shared_data):
    seq = load_shelf(shared_data / "shelf", grouper=group_view)
    views = {f.index: f.views for f in seq.frames}
    for start in (0, 120, 240):  # three windows of 60 frames of the 301
        assert sync_findings(list(seq.rig), {f: views[f] for f in sorted(views)[start:]}) == {}


def test_panoptic_in_sync_gives_no_warning_and_a_camera_3_frames_late_is_named(shared_data):
    for name in ("160906_band2", "160906_band1"):  # band1 last: its people move enough to show a shift
        seq = load_panoptic_sequence(shared_data / "panoptic_seq", name)
        views = {f.index: f.views for f in seq.frames}
        assert sync_findings(list(seq.rig), views) == {}
    found = sync_findings(list(seq.rig), shifted(views, [0, 0, 3, 0, 0]))  # camera 2's frame f - 3 is frame f
    assert list(found) == [2] and f'"dataset.offsets={{{seq.rig.names[2]}: -3}}"' in found[2].message
