"""Pictures over time: the HTML viewer embeds every frame's poses and ids to the millimetre and needs no
network, the trajectories PNG has its size and the tracks' colours, the command line reads a
poses3d.json back, and eval.py with vis_sequence=true writes both pictures."""

from __future__ import annotations

import json
import re

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from data.formats.poses_io import read_poses3d, read_poses3d_frames, write_poses3d  # noqa: E402
from data.synthetic.body import mean_body, pose_joints  # noqa: E402
from data.synthetic.rigs import ring_rig  # noqa: E402
from evaluation.pictures.sequence_data import id_colors, pose_roots  # noqa: E402
from evaluation.pictures.sequence_html import UNTRACKED_NOTE, camera_glyph  # noqa: E402
from evaluation.pictures.sequence_view import main, plot_trajectories, write_sequence_html  # noqa: E402
from evaluation.pictures.vis_trajectories import DPI, FIGSIZE_IN, trajectories_figure  # noqa: E402
from tests.test_eval import run_eval  # noqa: E402

DATA = re.compile(r'<script type="application/json" id="sequence-data">(.*?)</script>', re.S)


def _walkers(num_frames: int = 6, ids=((4, 1), (4, 1, 30), (1, 30))) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Persons walking along +x: (frame, poses (P, 23, 4), ids (P,)); ids per frame cycle through ``ids``,
    person id k starts at y = k / 10; the left wrist is missing (score 0) in every pose."""
    body, frames = mean_body(), []
    for f in range(num_frames):
        frame_ids = np.array(ids[f % len(ids)])
        poses = np.zeros((len(frame_ids), 23, 4))
        for p, i in enumerate(frame_ids):
            poses[p, :, :3] = pose_joints(body, 0.3 * f - 1.0, i / 10.0, 0.0, (0.1 * f) % 1.0, walking=True)
            poses[p, :, 3] = 0.9
        poses[:, 9] = [5.0, 5.0, 5.0, 0.0]
        frames.append((100 + 2 * f, poses, frame_ids))
    return frames


def _page_data(path) -> dict:
    """The JSON embedded in a written viewer."""
    match = DATA.search(path.read_text(encoding="utf-8"))
    assert match, "no embedded sequence data"
    return json.loads(match.group(1))


def _assert_frames_equal(data: dict, frames) -> None:
    """Every frame, id and valid joint of the input is in the page to 1 mm; missing joints are null."""
    assert [f["frame"] for f in data["frames"]] == [f for f, _, _ in frames]
    for shown, (_, poses, ids) in zip(data["frames"], frames):
        assert shown["ids"] == [int(i) for i in ids]
        assert len(shown["poses"]) == len(poses)
        for pose_js, pose in zip(shown["poses"], poses):
            for joint_js, joint in zip(pose_js, pose):
                if joint[3] > 0:
                    assert np.abs(np.array(joint_js) - joint[:3]).max() <= 0.0005 + 1e-9
                else:
                    assert joint_js is None


def test_the_page_embeds_every_frame_with_its_ids_to_a_millimetre_and_needs_no_network(tmp_path):
    frames = _walkers()
    rig = ring_rig(3, 6.0, 2.5)
    path = write_sequence_html(tmp_path / "seq.html", frames, rig, title="walk <test>")
    text = path.read_text(encoding="utf-8")
    data = _page_data(path)
    _assert_frames_equal(data, frames)
    assert data["tracked"] and data["every"] == 1 and data["note"] == ""
    assert [c["name"] for c in data["cameras"]] == rig.names
    assert data["limbs"] and all(len(limb) == 2 for limb in data["limbs"])
    colors = data["colors"]
    assert sorted(colors, key=int) == ["1", "4", "30"] and len(set(colors.values())) == 3
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", text, re.I)
    assert "http://" not in text and "https://" not in text
    assert "<title>walk &lt;test&gt;</title>" in text
    for root, (_, poses, _) in zip(data["frames"], frames):  # the mid-hip, on the walking line
        assert np.allclose(root["roots"], pose_roots(poses), atol=1e-3)


def test_a_camera_named_like_a_closing_script_tag_cannot_break_the_page(tmp_path):
    rig = ring_rig(2, 5.0, 2.0)
    cams = [type(c)("</script><b>", c.K, c.dist, c.R, c.t, c.size) if i == 0 else c for i, c in enumerate(rig)]
    path = write_sequence_html(tmp_path / "seq.html", _walkers(2), type(rig).from_cameras(cams))
    assert _page_data(path)["cameras"][0]["name"] == "</script><b>"
    assert path.read_text().count("</script>") == 2  # the data element's and the code's


def test_without_tracking_ids_are_indices_in_the_frame_and_the_page_says_so(tmp_path):
    frames = [(f, poses, None) for f, poses, _ in _walkers(3)]
    data = _page_data(write_sequence_html(tmp_path / "seq.html", frames, ring_rig(2, 5.0, 2.0)))
    assert [f["ids"] for f in data["frames"]] == [list(range(len(p))) for _, p, _ in frames]
    assert not data["tracked"] and data["note"] == UNTRACKED_NOTE


def test_a_sequence_above_the_size_cap_is_shown_every_kth_frame_below_it(tmp_path):
    frames = _walkers(60)
    full = write_sequence_html(tmp_path / "full.html", frames, ring_rig(3, 6.0, 2.5))
    cap_mb = 0.4 * full.stat().st_size / 1e6
    capped = write_sequence_html(tmp_path / "capped.html", frames, ring_rig(3, 6.0, 2.5), max_mb=cap_mb)
    data = _page_data(capped)
    assert capped.stat().st_size <= cap_mb * 1e6
    assert data["every"] >= 3 and data["num_frames"] == 60 and f"one frame in {data['every']}" in data["note"]
    _assert_frames_equal(data, frames[:: data["every"]])


def test_camera_frustum_corners_project_to_the_image_corners_in_front_of_the_camera():
    cam = ring_rig(4, 6.0, 3.0, image_size=(640, 480))[1]
    glyph = camera_glyph(cam, depth=0.5)
    corners = np.array(glyph["corners"])
    assert np.allclose(cam.depth(corners), 0.5, atol=1e-3)
    assert np.allclose(cam.project(corners), [[0, 0], [640, 0], [640, 480], [0, 480]], atol=2.0)
    assert np.allclose(glyph["center"], cam.center, atol=1e-3)


def test_roots_are_the_mid_hip_else_the_mean_of_the_valid_trunk_joints():
    poses = np.zeros((3, 23, 4))
    poses[:, [11, 12, 5, 6], :3] = [[0, 0, 1], [2, 0, 1], [0, 0, 3], [2, 2, 3]]
    poses[:, [11, 12, 5, 6], 3] = 1.0
    poses[1, 12, 3] = 0.0  # one hip missing: the left hip and the shoulders
    poses[2, [5, 6, 11, 12], 3] = 0.0
    roots = pose_roots(poses)
    assert np.allclose(roots[0], [1, 0, 1]) and np.allclose(roots[1], [2 / 3, 2 / 3, 7 / 3])
    assert np.isnan(roots[2]).all()


def test_an_ids_colour_depends_on_the_id_alone():
    few, many = id_colors([0, 3, 20]), id_colors(range(40))
    for i in (0, 3, 20):
        assert np.allclose(few[i], many[i])
    palette = np.stack(list(many.values()))
    gaps = np.linalg.norm(palette[:, None] - palette[None], axis=-1) + np.eye(len(palette))
    assert gaps.min() > 0.01


def test_the_trajectories_png_has_its_size_and_each_tracks_colour(tmp_path):
    frames = _walkers(12)
    path = plot_trajectories(tmp_path / "traj.png", frames, ring_rig(4, 6.0, 2.5))
    image = mpimg.imread(path)
    assert image.shape[:2] == (round(FIGSIZE_IN[1] * DPI), round(FIGSIZE_IN[0] * DPI))
    rgb = image[..., :3].reshape(-1, 3)
    for i, color in id_colors([1, 4, 30]).items():
        assert (np.abs(rgb - color).max(axis=1) < 0.02).sum() > 50, f"id {i}'s colour is missing"


def test_the_command_line_reads_a_written_poses3d_back_with_its_ids(tmp_path):
    frames = _walkers(5)
    rig = ring_rig(3, 6.0, 2.5)
    write_poses3d(tmp_path / "poses3d.json", ((f, p, np.full((len(p), 3), -1), ids) for f, p, ids in frames), rig.names)
    read = read_poses3d_frames(tmp_path / "poses3d.json")
    assert [ids.tolist() for _, _, ids in read] == [ids.tolist() for _, _, ids in frames]
    assert sorted(read_poses3d(tmp_path / "poses3d.json")) == [f for f, _, _ in frames]
    (tmp_path / "cameras.json").write_text(json.dumps(rig.to_dict()))
    paths = main([str(tmp_path / "poses3d.json"), str(tmp_path / "cameras.json"), "--png", str(tmp_path / "t.png")])
    assert paths == [tmp_path / "sequence.html", tmp_path / "t.png"]
    _assert_frames_equal(_page_data(paths[0]), frames)
    assert mpimg.imread(paths[1]).ndim == 3


def test_the_command_line_stops_with_one_line_on_a_bad_file(tmp_path):
    (tmp_path / "poses3d.json").write_text("{}")
    with pytest.raises(SystemExit, match="not a poses3d.json"):
        main([str(tmp_path / "poses3d.json"), str(tmp_path / "cameras.json")])


def test_eval_with_vis_sequence_writes_the_viewer_and_the_trajectories(tmp_path):
    run_eval(tmp_path, ["dataset.num_frames=3", "vis_sequence=true"])
    html, png = tmp_path / "pictures" / "sequence.html", tmp_path / "pictures" / "trajectories.png"
    written = read_poses3d_frames(tmp_path / "poses3d.json")
    data = _page_data(html)
    assert [f["frame"] for f in data["frames"]] == [f for f, _, _ in written] and len(written) == 3
    assert [f["ids"] for f in data["frames"]] == [ids.tolist() for _, _, ids in written]
    assert data["tracked"] and mpimg.imread(png).shape[:2] == (800, 1000)


def test_without_tracking_the_trajectories_are_dots_not_paths_joining_different_persons(tmp_path):
    frames = _walkers(12)
    fig_tracked = trajectories_figure(frames, ring_rig(4, 6.0, 2.5))
    fig_untracked = trajectories_figure([(f, p, None) for f, p, _ in frames], ring_rig(4, 6.0, 2.5))
    styles = [
        {line.get_linestyle() for line in fig.axes[0].lines if line.get_marker() in ("None", ".")}
        for fig in (fig_tracked, fig_untracked)
    ]
    assert styles == [{"-"}, {"None"}]
    assert "tracking off" in fig_untracked.axes[0].get_title()
