"""The dev-set benchmark and the sigma-model fit run, and say what the issue asks of the default."""

from benchmarks.fit_sigma_model import main as fit_main
from benchmarks.real_inputs import main as real_main


def test_the_default_beats_the_paper_and_matches_epipolar_vanilla_on_panoptic_at_2px():
    rows = real_main(["--sets", "panoptic", "--match", "band2 2 px", "--rows", "default,paper,epipolar_vanilla"])
    by_row = {r[1]: r for r in rows}
    found, fp, mpjpe = 2, 4, 7
    assert by_row["default"][found] == 100.0 and by_row["default"][fp] == 0
    assert by_row["default"][mpjpe] <= 1.02 * by_row["epipolar + vanilla"][mpjpe]
    assert by_row["default"][mpjpe] < by_row["paper"][mpjpe]


def test_sigma_model_fit_on_shelf_grows_at_low_scores(capsys):
    sigma_px, c, k = fit_main([])
    assert 1.0 < sigma_px < 20.0 and 0.0 <= c < 0.1 and 0.5 < k < 3.0
    assert "fit: sigma = max(1" in capsys.readouterr().out
