"""Streaming: ``Pipeline.step(frame)`` reconstructs synchronised multi-view frames one at a time, with the batch run's
config and results; ``python -m stream [cameras=... sources=...] [eval.yaml overrides]`` runs it on cameras or videos."""

from __future__ import annotations

import itertools
import sys
import time
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from hydra import compose, initialize_config_dir
from hydra.errors import HydraException
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from data.config_checks import ConfigError
from data.datasets.images import read_frame_images
from data.datasets.videos import load_videos
from data.formats.atomic_io import exit_on_sigterm
from data.formats.image_sources import ImageSourceError
from data.formats.poses2d_io import Poses2DError
from data.formats.poses_io import write_poses3d
from data.frame_inputs import EXACT, clean_frames
from data.geometry.calibration import CalibrationError, load_rig
from data.geometry.camera import Rig
from data.image_ids import coco_image_id
from data.multiview import Frame, Sequence, ViewDetections
from eval import check_config, check_sequence, one_line_warning, poses3d_rows
from models.front_end import Pose2DFrontEnd
from reconstruction.pipeline import FrameResult, MultiViewPipeline
from reconstruction.precompile import precompile
from run_folders import one_line_errors, register_resolvers

REPO = Path(__file__).resolve().parent
# beside eval.yaml's keys; save_every: seconds between rewrites of `out` while streaming (null: at the end only)
STREAM_KEYS = {"cameras": None, "sources": None, "out": "poses3d.json", "quiet": False, "save_every": 10.0}


@dataclass
class StepResult:
    """A frame's FrameResult; latency_ms: its ms per stage (2D, matching, reconstruction, tracking; noise calibration on
    the frame that ends the warm-up); wait_ms: from its step() call until returned (the warm-up's buffering)."""

    result: FrameResult
    latency_ms: dict[str, float]
    wait_ms: float


def warmup_frames(pipeline: MultiViewPipeline) -> int:
    """The frames the calibrated noise model fits on (noise_model.frames), buffered before the first result; 0: fixed."""
    model = pipeline.calibrated_model()
    return 0 if model is None else model.frames


class Pipeline:
    """One synchronised frame at a time -> the results ready, identical to eval.py's on the same frames: the first
    warmup_frames are buffered, calibrate the noise model, then come out together; each later frame at once."""

    def __init__(
        self,
        pipeline: MultiViewPipeline,
        front_end: Pose2DFrontEnd | None = None,
        max_detections: int = 10000,
        near: float = 0.01,
    ) -> None:
        self.pipeline, self.front_end, self.max_detections, self.near = pipeline, front_end, max_detections, near
        self.window = warmup_frames(pipeline)  # 0 once calibrated (or for a fixed noise model)
        self.buffer: list[tuple[Frame, dict[str, float], float]] = []  # (frame with its 2D, seconds per stage, t0)
        self.inputs: Counter = Counter()  # detections dropped or merged before matching, by reason
        self.noise_model: str | None = None  # the calibrated model in words, once fitted
        self.last: int | None = None

    @classmethod
    def from_config(cls, cfg: DictConfig, sequence: Sequence) -> Pipeline:
        """The stream of an eval.yaml config; sequence: the rig and the frames known ahead (the front end's checks)."""
        check_config(cfg)
        check_sequence(cfg, sequence)
        precompile()
        front_end = Pose2DFrontEnd.from_config(cfg, sequence)
        pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
        return cls(pipeline, front_end, cfg.inputs.max_detections_per_frame, cfg.inputs.near_duplicate)

    def step(self, frame: Frame) -> list[StepResult]:
        """One frame (V views, or images for the 2D stage) -> the results ready: [] during the warm-up, then >= 1."""
        t0 = time.perf_counter()
        if self.pipeline.tracker is not None and self.last is not None and frame.index <= self.last:
            raise ValueError(f"frame {frame.index} comes after frame {self.last}: tracking needs increasing numbers")
        self.last, spent = frame.index, {}
        frame = self._clean(frame)
        if self.front_end is not None:
            before = sum(self.front_end.timings.values())
            frame = replace(frame, views=self.front_end(frame))
            spent["2D"] = sum(self.front_end.timings.values()) - before
        self.buffer.append((frame, spent, t0))
        return [] if len(self.buffer) < self.window else self.flush()

    def flush(self) -> list[StepResult]:
        """The buffered frames' results (the noise model calibrated on them first, as eval.py on so short a run)."""
        if self.window and self.buffer:
            t0 = time.perf_counter()
            self.noise_model = self.pipeline.calibrate_noise([frame for frame, _, _ in self.buffer])
            self.buffer[-1][1]["noise calibration"] = time.perf_counter() - t0
            self.window = 0
        out = []
        while self.buffer:
            out.append(self._run(*self.buffer.pop(0)))
        return out

    close = flush

    def _clean(self, frame: Frame) -> Frame:
        """eval.py's input checks on one frame (inputs.*): repeats merged, the first exact repeat warned of once."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sequence, counts = clean_frames(Sequence(self.pipeline.rig, [frame]), self.max_detections, self.near)
        if caught and not self.inputs[EXACT]:
            warnings.warn(caught[0].message, stacklevel=3)
        self.inputs += counts
        return sequence.frames[0]

    def _run(self, frame: Frame, spent: dict[str, float], t0: float) -> StepResult:
        """Match, reconstruct and track one buffered frame -> its StepResult."""
        before = dict(self.pipeline.timings)
        result = self.pipeline(frame)
        spent |= {k: v - before.get(k, 0.0) for k, v in self.pipeline.timings.items()}
        latency = {k: 1e3 * v for k, v in spent.items()}
        return StepResult(result, latency, 1e3 * (time.perf_counter() - t0))


# --- python -m stream -------------------------------------------------------------------------------
class Camera:
    """A live camera, cv2.VideoCapture(index), with VideoReader's read(position): its next image (H, W, 3)."""

    def __init__(self, index: int) -> None:
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(
            cv2.utils.logging.LOG_LEVEL_ERROR
        )  # a missing camera: our one line, not its WARNs
        try:
            self.capture = cv2.VideoCapture(index)
        finally:
            cv2.utils.logging.setLogLevel(level)
        if not self.capture.isOpened():
            raise ImageSourceError(f"camera {index}: cv2.VideoCapture({index}) cannot open it")

    def read(self, position: int) -> np.ndarray:
        """The next image (position ignored); EOFError when the camera gives none."""
        ok, image = self.capture.read()
        if not ok or image is None:
            raise EOFError
        return image


def live_frames(rig: Rig, indices: list[int]) -> Iterator[Frame]:
    """Frames 0, 1, ... of cameras cv2.VideoCapture(i) (V, rig order), images rescaled to the calibration's sizes."""
    cameras = [Camera(i) for i in indices]
    sizes, ids = [cam.size for cam in rig], lambda n: [coco_image_id(n, v, len(rig)) for v in range(len(rig))]
    try:
        for n in itertools.count():
            try:
                images = read_frame_images(cameras, [n] * len(rig), sizes)
            except EOFError:
                return
            empty = [ViewDetections.empty() for _ in rig]
            yield Frame(n, empty, images=lambda images=images: images, image_ids=ids(n))
    finally:
        for camera in cameras:
            camera.capture.release()


def open_frames(cfg: DictConfig) -> tuple[Sequence, Iterable[Frame]]:
    """(the Sequence the checks read, the frames to stream): camera indices, videos (dataset=videos) or cfg.dataset."""
    if cfg.sources is None or cfg.cameras is None:
        if cfg.sources is not None or cfg.cameras is not None:
            raise ConfigError("cameras= and sources= go together: a calibration and one source per camera")
        sequence = instantiate(cfg.dataset, _convert_="all")
        return sequence, sequence.frames
    rig, sources = load_rig(cfg.cameras), cfg.sources
    sources = OmegaConf.to_container(sources) if isinstance(sources, ListConfig) else sources
    if isinstance(sources, list) and len(sources) != len(rig):
        raise ConfigError(f"sources: {len(sources)} given, the calibration has {len(rig)} cameras {rig.names}")
    if isinstance(sources, list) and all(isinstance(s, int) for s in sources):
        frames = live_frames(rig, sources)
        first = next(frames, None)
        if first is None:
            raise ImageSourceError(f"cameras {sources}: no image read")
        return Sequence(rig, [first]), itertools.chain([first], frames)
    sequence = load_videos(cfg.cameras, dict(zip(rig.names, sources)) if isinstance(sources, list) else sources)
    return sequence, sequence.frames


def frame_line(step: StepResult, fps: float) -> str:
    """One printed line: frame, persons, ids, ms per stage, the warm-up's wait, frames per second."""
    r = step.result
    ids = (r.ids if r.ids is not None else np.arange(len(r.poses3d))).tolist()
    stages = " ".join(f"{k} {v:.1f}" for k, v in step.latency_ms.items())
    return f"frame {r.frame}: {len(r.poses3d)} persons, ids {ids} | ms {stages} | waited {step.wait_ms:.1f} | {fps:.1f} frame/s"


def run_stream(
    stream: Pipeline, frames: Iterable[Frame], cfg: DictConfig, fps: float | None = None
) -> list[FrameResult]:
    """Step through frames, a line per result; at the end or Ctrl-C flush; always write cfg.out atomically (fps: the
    input's frame rate, written into it; None: unknown)."""
    results: list[FrameResult] = []
    t0 = saved = time.perf_counter()

    def emit(steps: list[StepResult]) -> None:
        nonlocal saved
        for step in steps:
            results.append(step.result)
            if not cfg.quiet:
                print(frame_line(step, len(results) / (time.perf_counter() - t0)), flush=True)
        if cfg.save_every is not None and time.perf_counter() - saved >= cfg.save_every:  # the file so far, complete
            write_results(cfg, results, stream.pipeline.rig.names, fps)
            saved = time.perf_counter()

    try:
        try:
            for frame in frames:
                emit(stream.step(frame))
        except KeyboardInterrupt:
            print(f"stopped (Ctrl-C) after {len(results) + len(stream.buffer)} frames", file=sys.stderr)
        emit(stream.flush())
    finally:  # an error or SIGTERM: the frames emitted so far
        write_results(cfg, results, stream.pipeline.rig.names, fps)
    fps = len(results) / max(time.perf_counter() - t0, 1e-9)
    print(f"{len(results)} frames, {fps:.1f} frame/s" + (f"; wrote {cfg.out}" if cfg.out is not None else ""))
    return results


def write_results(cfg: DictConfig, results: list[FrameResult], names: list[str], fps: float | None = None) -> None:
    """Every result so far into cfg.out (poses3d.json, atomically); nothing when out is null."""
    if cfg.out is not None:
        write_poses3d(cfg.out, poses3d_rows(results), names, fill=cfg.output.fill, fps=fps)


def compose_config(argv: list[str]) -> DictConfig:
    """eval.yaml composed with the overrides of argv, the stream's own keys (STREAM_KEYS) added."""
    register_resolvers()
    ours = lambda arg: arg.lstrip("+").split("=", 1)[0] in STREAM_KEYS
    overrides = [a for a in argv if not ours(a)] + ["+" + a.lstrip("+") for a in argv if ours(a)]
    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base="1.3"):
        try:
            cfg = compose("eval", overrides=overrides)
        except HydraException as err:  # e.g. a key eval.yaml does not have, or a bad override
            raise SystemExit(f"error: {err}".splitlines()[0]) from None
    with open_dict(cfg):
        for key, value in STREAM_KEYS.items():
            cfg.setdefault(key, value)
    return cfg


def main(argv: list[str] | None = None) -> list[FrameResult]:
    """python -m stream [cameras=<calibration> sources=<[0,1,..] | [a.mp4,..] | folder>] [out=..] [eval.yaml keys]."""
    argv = sys.argv[1:] if argv is None else argv
    if {"-h", "--help"} & set(argv):
        usage = "usage: python -m stream [cameras=FILE sources=[0,1,..]|FOLDER|[a.mp4,..]] [out=FILE] [quiet=true] [key=value]"
        print(f"{usage}\n\n{__doc__}\nkeys: {STREAM_KEYS} and eval.yaml's (without cameras=/sources=: its dataset=)")
        return []
    cfg = compose_config(argv)
    warnings.showwarning = one_line_warning  # RigWarning, InputWarning: one line, as in eval.py
    with one_line_errors(ConfigError, CalibrationError, Poses2DError, ImageSourceError, config=cfg):
        try:
            sequence, frames = open_frames(cfg)
            stream = Pipeline.from_config(cfg, sequence)
        except KeyboardInterrupt:  # while loading models or opening cameras
            print("stopped (Ctrl-C) before the first frame; nothing written", file=sys.stderr)
            raise SystemExit(130) from None
        return run_stream(stream, frames, cfg, sequence.meta.get("fps"))


if __name__ == "__main__":
    exit_on_sigterm()
    main()
