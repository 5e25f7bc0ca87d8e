"""stream.py: Pipeline.step gives eval.py's poses3d.json byte for byte (Shelf, tracking=off, a stream shorter than the
noise calibration's window, videos through a 2D stage, live cameras); python -m stream stops cleanly on Ctrl-C."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import eval as eval_script
import stream
from data.formats.poses_io import write_poses3d
from data.geometry.calibration import load_rig
from data.pose2d.scene_render import render_sequence
from data.synthetic import SyntheticConfig, generate_sequence
from models.front_end import Pose2DFrontEnd
from reconstruction.pipeline import MultiViewPipeline
from run_folders import register_resolvers
from tests.test_images_dataset import SIZE, write_rig
from tests.test_sppe_stage import write_tiny_checkpoint
from tests.test_videos_dataset import write_videos

REPO = Path(__file__).resolve().parents[1]


def config(*overrides: str):
    """eval.yaml with these overrides, no progress bar."""
    register_resolvers()
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        return compose("eval", overrides=["progress=false", *overrides])


def batch_bytes(cfg, out: Path) -> bytes:
    """poses3d.json of eval.run on cfg."""
    eval_script.run(cfg, out)
    return (out / cfg.output.poses3d).read_bytes()


def stream_bytes(pipe: stream.Pipeline, frames, path: Path, fill: bool = False) -> tuple[bytes, list[list]]:
    """poses3d.json of pipe stepped over frames then flushed (written as eval.py writes it), and each step's results."""
    steps = [pipe.step(frame) for frame in frames] + [pipe.flush()]
    results = [s.result for step in steps for s in step]
    write_poses3d(path, eval_script.poses3d_rows(results), pipe.pipeline.rig.names, fill=fill)
    return path.read_bytes(), steps


def stream_results(cfg, path: Path) -> tuple[bytes, list[int]]:
    """Stream cfg's dataset frame by frame -> (its poses3d.json, the number of results each step returned)."""
    sequence = instantiate(cfg.dataset, _convert_="all")
    got, steps = stream_bytes(stream.Pipeline.from_config(cfg, sequence), sequence.frames, path, cfg.output.fill)
    return got, [len(step) for step in steps]


def test_shelf_stream_gives_the_batch_runs_poses3d_json_byte_for_byte(shared_data, tmp_path):
    cfg = config("dataset=shelf", f"dataset.root={shared_data}/shelf")
    got, counts = stream_results(cfg, tmp_path / "stream.json")
    assert counts[:29] == [0] * 29 and counts[29] == 30 and counts[30:] == [1] * 271 + [0]  # warm-up, then at once
    assert got == batch_bytes(cfg, tmp_path / "batch")


@pytest.mark.parametrize(
    "overrides, counts",
    [
        (("tracking=off", "dataset.frames=0:60"), [0] * 29 + [30] + [1] * 30 + [0]),
        (("dataset.frames=0:12",), [0] * 12 + [12]),
    ],
)
def test_tracking_off_and_a_stream_shorter_than_the_calibration_window(shared_data, tmp_path, overrides, counts):
    cfg = config("dataset=shelf", f"dataset.root={shared_data}/shelf", *overrides)
    got, per_step = stream_results(cfg, tmp_path / "stream.json")
    assert per_step == counts and got == batch_bytes(cfg, tmp_path / "batch")


def test_a_fixed_noise_model_returns_every_frame_at_once_with_its_latencies():
    cfg = config("noise_model=fixed", "dataset.num_frames=5")
    sequence = instantiate(cfg.dataset, _convert_="all")
    pipe = stream.Pipeline.from_config(cfg, sequence)
    steps = [pipe.step(frame) for frame in sequence.frames]
    assert [len(s) for s in steps] == [1] * 5 and pipe.flush() == []
    assert set(steps[0][0].latency_ms) == {"matching", "reconstruction", "tracking"}
    with pytest.raises(ValueError, match="tracking needs increasing"):
        pipe.step(sequence.frames[0])


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    """cameras.json, a folder of <camera>.avi (4 frames of 3 rendered cameras), boxes.json and a tiny SPPE."""
    cfg = SyntheticConfig(seed=2, num_frames=4, num_persons=3, num_cameras=3, image_size=SIZE, focal_px=150.0)
    scene, root = render_sequence(generate_sequence(cfg), seed=5), tmp_path_factory.mktemp("stream")
    write_videos([f.images() for f in scene.frames], root / "videos", scene.rig.names)
    boxes = [
        {"image_id": i, "category_id": 1, "bbox": [float(x) for x in box], "score": 1.0}
        for frame in scene.frames
        for i, view in zip(frame.image_ids, frame.views)
        for box in view.bboxes
    ]
    (root / "boxes.json").write_text(json.dumps(boxes))
    stage = ["pose2d=sppe", f"pose2d.checkpoint={write_tiny_checkpoint(root / 'best.pth', 1.25)}", "pose2d.device=cpu"]
    return write_rig(scene, root), root / "videos", [*stage, "detector=file", f"detector.path={root / 'boxes.json'}"]


def test_cli_on_video_files_and_live_cameras_writes_eval_py_dataset_videos_output(videos, tmp_path, monkeypatch):
    cameras, folder, stage = videos
    cfg = config("dataset=videos", f"dataset.cameras={cameras}", f"dataset.videos={folder}", *stage)
    expected = batch_bytes(cfg, tmp_path / "batch")
    assert any(f["poses"] for f in json.loads(expected)["frames"])
    stream.main([f"cameras={cameras}", f"sources={folder}", *stage, f"out={tmp_path / 'cli.json'}"])
    assert (tmp_path / "cli.json").read_bytes() == expected
    listed = stream.compose_config(
        [f"cameras={cameras}", f"sources=[{','.join(str(folder / f'{n}.avi') for n in '012')}]"]
    )
    assert [f.image_ids for f in stream.open_frames(listed)[1]] == [
        f.image_ids for f in instantiate(cfg.dataset).frames
    ]
    real, rig = cv2.VideoCapture, load_rig(cameras)
    monkeypatch.setattr(cv2, "VideoCapture", lambda i: real(str(folder / f"{i}.avi")))  # camera i: its video
    front_end = Pose2DFrontEnd(instantiate(cfg.pose2d), instantiate(cfg.detector))  # no dataset to check ids against
    pipe = stream.Pipeline(MultiViewPipeline.from_config(cfg, rig), front_end)
    got, steps = stream_bytes(pipe, stream.live_frames(rig, [0, 1, 2]), tmp_path / "live.json")
    assert json.loads(got) | {"fps": 5.0} == json.loads(expected)  # stream_bytes writes no rate; eval.py's 5 fps
    assert [len(s) for s in steps] == [0, 0, 0, 0, 4]  # 4 frames: flushed, calibrated on them
    assert {"2D", "noise calibration", "matching"} <= set(steps[-1][-1].latency_ms)


def test_ctrl_c_writes_the_frames_so_far_as_valid_json(monkeypatch, tmp_path, capsys):
    cfg = config("dataset.num_frames=40")
    sequence = instantiate(cfg.dataset, _convert_="all")

    def interrupted(frames, n):  # a source whose user presses Ctrl-C after n frames
        yield from frames[:n]
        raise KeyboardInterrupt

    for n in (12, 35):  # within and after the noise calibration's 30 frames
        monkeypatch.setattr(stream, "open_frames", lambda cfg: (sequence, interrupted(sequence.frames, n)))
        results = stream.main([f"out={tmp_path / 'out.json'}", "dataset.num_frames=40"])
        doc = json.loads((tmp_path / "out.json").read_text())
        assert len(results) == len(doc["frames"]) == n and [f["frame"] for f in doc["frames"]] == list(range(n))
        out, err = capsys.readouterr()
        assert f"stopped (Ctrl-C) after {n} frames" in err and f"{n} frames, " in out.splitlines()[-1]
        assert out.splitlines()[0].startswith("frame 0: ") and " ms matching " in out.splitlines()[0]


def test_python_m_stream_runs_from_the_repository_root(tmp_path):
    cmd = [sys.executable, "-m", "stream", "dataset.num_frames=3", "quiet=true", f"out={tmp_path / 'p.json'}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("3 frames, ") and len(json.loads((tmp_path / "p.json").read_text())["frames"]) == 3
    bad = subprocess.run([*cmd[:3], "sources=[0]"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert (
        bad.returncode == 1
        and bad.stderr == "error: cameras= and sources= go together: a calibration and one source per camera\n"
    )


def test_the_file_is_rewritten_while_streaming(monkeypatch, tmp_path):
    cfg = config("dataset.num_frames=6", "noise_model=fixed")
    sequence = instantiate(cfg.dataset, _convert_="all")
    out, seen = tmp_path / "live.json", []

    def watched(frames):  # records how many frames the file holds before each new frame arrives
        for frame in frames:
            seen.append(len(json.loads(out.read_text())["frames"]) if out.exists() else 0)
            yield frame

    monkeypatch.setattr(stream, "open_frames", lambda cfg: (sequence, watched(sequence.frames)))
    stream.main([f"out={out}", "dataset.num_frames=6", "noise_model=fixed", "save_every=0", "quiet=true"])
    assert seen == [0, 1, 2, 3, 4, 5]  # each frame was on disk before the next one came
    with_end_only = tmp_path / "end.json"
    seen.clear()
    out = with_end_only
    stream.main([f"out={out}", "dataset.num_frames=6", "noise_model=fixed", "save_every=null", "quiet=true"])
    assert seen == [0] * 6 and len(json.loads(out.read_text())["frames"]) == 6
