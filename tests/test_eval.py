"""End-to-end runs of eval.py through Hydra's compose API, and a multirun smoke test."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.formats.poses_io import read_poses3d

CONFIGS = str(Path(__file__).resolve().parents[1] / "configs")


def run_eval(tmp_path: Path, overrides: list[str]):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(config_name="eval", overrides=["progress=false", *overrides])
    return eval_script.run(cfg, tmp_path)


def test_noise_free_synthetic_scene_is_reconstructed_below_a_millimetre(tmp_path, capsys):
    report = run_eval(
        tmp_path,
        [
            "dataset.noise_px=0",
            "dataset.occlusion=false",
            "dataset.num_frames=5",
            "matching=oracle",
            "reconstruction=vanilla",
        ],
    )
    m = report.metrics
    assert m["mpjpe_mm"] < 1.0 and m["pcp_average"] == 100.0 and m["recall"] == 100.0
    assert m["matching_precision"] == 1.0
    assert m["reprojection_max_px"] < 1e-6 and m["reprojection_var_px2"] < 1e-12  # exact 2D, exact 3D
    poses = read_poses3d(tmp_path / "poses3d.json")
    assert sorted(poses) == list(range(5)) and all(p.shape[1:] == (23, 4) for p in poses.values())
    saved = json.loads((tmp_path / "metrics.json").read_text())["metrics"]
    assert np.isclose(saved["mpjpe_mm"], m["mpjpe_mm"])
    out = capsys.readouterr().out
    assert "MPJPE all 23 joints (mm)" in out and "Protocol: absolute MPJPE" in out and "ms / frame" in out


def test_reprojection_statistics_grow_with_the_2d_noise(tmp_path):
    """The paper's Table 3 statistics against the detections: about the 2D noise, ordered by it."""
    means = [
        run_eval(tmp_path, [f"dataset.noise_px={n}", "dataset.num_frames=2", "matching=oracle"]).metrics[
            "reprojection_mean_px"
        ]
        for n in (1, 4)
    ]
    assert 0.3 < means[0] < means[1] < 40.0


def test_default_pipeline_on_noise_free_input_is_unbiased_where_the_paper_prior_is_not(tmp_path):
    # the population-mean bone table differs from the synthetic bodies by a few mm: the paper's MAP keeps that
    # bias on exact 2D, the default (each person's own bones, the noise scale estimated) does not
    exact = ["dataset.noise_px=0", "dataset.occlusion=false", "dataset.num_frames=3"]
    m = run_eval(tmp_path / "default", exact).metrics
    paper = run_eval(tmp_path / "paper", [*exact, "reconstruction=paper"]).metrics
    assert m["matching_precision"] == 1.0 and m["recall"] == 100.0
    assert m["mpjpe_mm"] < 0.5 < paper["mpjpe_mm"]


def test_default_noise_gives_a_plausible_error(tmp_path):
    m = run_eval(tmp_path, ["dataset.num_frames=5"]).metrics
    assert 5.0 < m["mpjpe_mm"] < 80.0 and m["pcp_average"] > 90.0


def test_multirun_sweep_over_matchers(tmp_path):
    cmd = [
        sys.executable,
        "eval.py",
        "-m",
        "matching=oracle,feet",
        "dataset.num_frames=2",
        "progress=false",
        f"hydra.sweep.dir={tmp_path}",
    ]
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=Path(CONFIGS).parent, timeout=120)
    runs = sorted(tmp_path.glob("*/metrics.json"))
    assert len(runs) == 2
    assert all(json.loads(r.read_text())["metrics"]["num_gt"] > 0 for r in runs)


def test_bad_calibration_stops_with_one_message_naming_file_camera_and_key(tmp_path):
    bad = tmp_path / "cams.json"
    eye = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    bad.write_text(
        json.dumps({"left": {"K": eye, "dist": [0] * 5, "R": eye, "t": [0, 1, 0], "size": [640, 480]}}).replace(
            '"t": [0, 1, 0]', '"t": [0, NaN, 0]'
        )
    )
    cmd = [sys.executable, "eval.py", f"dataset.rig={bad}", "progress=false", f"hydra.run.dir={tmp_path / 'run'}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(CONFIGS).parent, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.strip() == f"error: {bad}: camera 'left': key 't' has a non-finite value"


def test_a_bad_config_value_stops_with_one_message(tmp_path):
    cmd = [sys.executable, "eval.py", "matching.feet.foot_rule=bogus", "progress=false", f"hydra.run.dir={tmp_path}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(CONFIGS).parent, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ") and "'bogus'" in proc.stderr


def test_every_dataset_gets_the_default_matcher_and_reconstruction_unless_the_command_line_names_one():
    datasets = [p.stem for p in (Path(CONFIGS) / "dataset").glob("*.yaml")]
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        chosen = {
            o[-1]: (
                compose(config_name="eval", overrides=o).matching._target_.rsplit(".", 1)[1],
                compose(config_name="eval", overrides=o).reconstruction._target_.rsplit(".", 1)[1],
            )
            for o in [[f"dataset={d}"] for d in datasets] + [["dataset=shelf", "matching=feet_paper"]]
        }
    assert len(datasets) >= 5
    assert all(chosen[f"dataset={d}"] == ("EvidenceMatcher", "MLEMAPReconstruction") for d in datasets)
    assert chosen["matching=feet_paper"][0] == "FeetMatcher"


def test_the_real_datasets_lie_under_paths_data_dir():
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        roots = {
            d: compose(config_name="eval", overrides=[f"dataset={d}", "paths.data_dir=/elsewhere"]).dataset.root
            for d in ("shelf", "panoptic", "wildtrack")
        }
    assert roots == {d: f"/elsewhere/{d}" for d in roots}


@pytest.mark.parametrize(
    "override, key",
    [
        ("evaluation.max_dist_m=abc", "evaluation.max_dist_m"),
        ("dataset.num_cameras=1", "num_cameras"),
        ("dataset.num_persons=0", "num_persons"),
        ("vis_frame=-1", "vis_frame"),
    ],
)
def test_a_bad_value_stops_with_one_line_naming_the_key(tmp_path, override, key):
    cmd = [sys.executable, "eval.py", override, "progress=false", "dataset.num_frames=1", f"hydra.run.dir={tmp_path}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(CONFIGS).parent, timeout=120)
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: ") and key in proc.stderr and not (tmp_path / "poses3d.json").exists()


def test_a_frame_to_draw_that_is_not_reconstructed_is_reported_after_the_report(tmp_path):
    cmd = [
        sys.executable,
        "eval.py",
        "vis=true",
        "vis_frame=999",
        "progress=false",
        "dataset.num_frames=1",
        "reconstruction=vanilla",
        f"hydra.run.dir={tmp_path}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(CONFIGS).parent, timeout=120)
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: vis_frame=999")
    assert "MPJPE all 23 joints (mm)" in proc.stdout
    report = (tmp_path / "report.txt").read_text()
    assert "MPJPE all 23 joints (mm)" in report and report.strip() in proc.stdout


def test_a_2d_metric_of_minus_one_says_why():
    assert "no annotated foot keypoints" in eval_script._why_missing("AP_foot", -1.0)
    assert eval_script._why_missing("AP_foot", 0.42) == ""


def test_frames_out_of_order_stop_a_tracked_run_with_one_line(tmp_path):
    from data.formats.poses2d_io import write_poses2d
    from data.geometry.calibration import save_cameras_json
    from data.synthetic import SyntheticConfig, generate_sequence

    seq = generate_sequence(SyntheticConfig(num_persons=2, num_frames=3, num_cameras=3, seed=1))
    save_cameras_json(seq.rig, tmp_path / "cameras.json")
    write_poses2d(tmp_path / "poses2d.json", {f.index: f.views for f in seq.frames}, seq.rig.names)
    files = [
        "dataset=files",
        f"dataset.cameras={tmp_path / 'cameras.json'}",
        f"dataset.poses2d={tmp_path / 'poses2d.json'}",
        "dataset.frames=2:-1:-1",
    ]
    with pytest.raises(eval_script.ConfigError, match="frame 1 comes after frame 2"):
        run_eval(tmp_path, files)
    run_eval(tmp_path, [*files, "tracking=off"])  # every frame on its own: any order


def test_the_fitted_noise_model_is_reported_and_written_and_fixed_writes_null(tmp_path, capsys):
    run_eval(tmp_path / "calibrated", ["dataset.num_frames=3"])
    line = json.loads((tmp_path / "calibrated" / "metrics.json").read_text())["noise_model"]
    assert line.startswith("2D noise model: self-calibrated") and line in capsys.readouterr().out
    run_eval(tmp_path / "fixed", ["dataset.num_frames=3", "noise_model=fixed"])
    assert json.loads((tmp_path / "fixed" / "metrics.json").read_text())["noise_model"] is None
