"""The paper's metrics, the printed table and the figures."""

import numpy as np
import pytest

from tactile_fusion.metrics import force_metrics, metrics_table
from tactile_fusion.plots import example_frames, least_squares_line, plot_fz_maps, plot_recalibration


def test_rmse_per_bin_and_on_the_total_force_per_component():
    true = np.zeros((2, 2, 2, 3))
    true[0, 0, 0, 2] = 1.0
    true[1, 1, 1, 2] = 3.0
    predicted = true.copy()
    predicted[0, :, :, 0] = 0.1          # frame 0: +0.1 N fx in all 4 bins -> total fx error 0.4 N
    predicted[1, 1, 1, 2] = 2.0          # frame 1: 1 N too little fz in one bin
    m = force_metrics(predicted, true)
    assert m["rmse_bin_n"][0] == pytest.approx(np.sqrt(4 * 0.01 / 8))
    assert m["rmse_bin_n"][1] == 0.0
    assert m["rmse_bin_n"][2] == pytest.approx(np.sqrt(1 / 8))
    assert m["rmse_total_n"] == pytest.approx([np.sqrt(0.16 / 2), 0.0, np.sqrt(1 / 2)])
    assert m["max_total_fz_n"] == 3.0 and m["frames"] == 2
    assert m["rmse_total_fz_percent_range"] == pytest.approx(100 * np.sqrt(0.5) / 3)


def test_metrics_refuse_nan_and_mismatched_shapes():
    good = np.zeros((1, 2, 2, 3))
    with pytest.raises(ValueError, match="NaN"):
        force_metrics(np.full_like(good, np.nan), good)
    with pytest.raises(ValueError, match="must both be"):
        force_metrics(good[:, :1], good)
    with pytest.raises(ValueError, match="no frames"):
        force_metrics(good[:0], good[:0])


def test_all_zero_ground_truth_has_no_percentage():
    zero = np.zeros((3, 2, 2, 3))
    m = force_metrics(zero, zero)
    assert m["rmse_total_fz_percent_range"] is None
    assert "-" in metrics_table({"rest": m}).splitlines()[-1]


def test_table_lists_each_data_set_in_millinewtons():
    m = force_metrics(np.full((1, 1, 1, 3), 0.002), np.zeros((1, 1, 1, 3)))
    table = metrics_table({"paper_grid test split": m, "edge_corner (all)": m})
    lines = table.splitlines()
    assert len(lines) == 4 and "bin Fz mN" in lines[0]
    assert lines[2].startswith("paper_grid test split") and "2.000" in lines[2]


def test_least_squares_line_recovers_a_line():
    x = np.array([0.1, 0.5, 1.0])
    assert least_squares_line(x, 2.0 * x - 1.0) == pytest.approx((2.0, -1.0))


def test_figures_are_written(tmp_path):
    rng = np.random.default_rng(0)
    true = np.abs(rng.normal(size=(6, 4, 5, 3))) * 0.01
    frames = example_frames(true)
    assert frames[0] == int(np.argmax(true[..., 2].sum(axis=(1, 2)))) and len(set(frames)) == len(frames)
    path = plot_fz_maps(true, true * 0.9, tmp_path / "fz.png", "test")
    assert path.stat().st_size > 10_000
    m = force_metrics(true * 0.9, true)
    sweep = {"added_camera": "cam3", "base_cameras": 3, "speedup_full_data": 7.0,
             "full_training": {"wall_time_s": 70.0, "metrics": m},
             "recalibration": [{"fraction": f, "wall_time_s": 10.0 * f, "metrics": m} for f in (0.1, 0.5, 1.0)]}
    assert plot_recalibration(sweep, tmp_path / "recal.png").stat().st_size > 10_000
