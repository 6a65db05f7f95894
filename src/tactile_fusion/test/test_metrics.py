"""The paper's metrics, the printed table and the figures."""

import numpy as np
import pytest

from tactile_fusion.metrics import (
    CONTACT_LEVEL_N,
    LOAD_BAND_EDGES_N,
    _centre_of_pressure,
    contact_metrics,
    contact_table,
    detection_limit,
    force_metrics,
    metrics_table,
)
from tactile_fusion.plots import example_frames, plot_fz_maps, plot_recalibration, trend_line_mn
from tactile_fusion.study import least_squares_line


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


#: A 3 x 4 grid of 2 mm bins: centres at x = 1, 3, 5, 7 mm and y = 1, 3, 5 mm.
BIN_CENTERS_M = np.stack(np.meshgrid(np.arange(1, 8, 2) * 1e-3, np.arange(1, 6, 2) * 1e-3), axis=-1)


def _fz_frames(*loads):
    """(N, 3, 4, 3) forces: per frame a dict {(row, col): Fz newtons}."""
    frames = np.zeros((len(loads), 3, 4, 3))
    for i, load in enumerate(loads):
        for (row, col), fz in load.items():
            frames[i, row, col, 2] = fz
    return frames


def test_contact_is_reported_from_the_contact_level_and_located_by_its_centre_of_pressure():
    true = _fz_frames({}, {}, {(1, 1): 0.03}, {(1, 1): 0.3}, {(0, 0): 0.4, (2, 3): 0.4}, {(1, 2): 0.6})
    predicted = _fz_frames({}, {(0, 0): 0.02},   # a surface without load: silent, then a false contact
                           {(1, 1): 0.005},       # a light press below the level: not reported
                           {(1, 2): 0.3, (0, 0): -0.1},  # one bin off in x; the negative bin is no pull: ignored
                           {(0, 0): 0.4, (2, 3): 0.4},   # two contacts: their centre is the middle of the surface
                           {(1, 2): 0.6, (1, 1): 0.2})   # weighted: a quarter of the way to the next bin
    m = contact_metrics(predicted, true, BIN_CENTERS_M)
    assert m["contact_level_n"] == CONTACT_LEVEL_N
    assert (m["frames_without_load"], m["false_contacts"]) == (2, 1)
    bands = {tuple(b["load_n"]): b for b in m["bands"]}
    assert bands[(0.0, 0.05)]["frames"] == 1 and bands[(0.0, 0.05)]["reported_share"] == 0.0
    assert bands[(0.0, 0.05)]["centre_error_mm_median"] is None
    assert bands[(0.05, 0.1)] == {"load_n": [0.05, 0.1], "frames": 0, "reported_share": None,
                                  "centre_error_mm_median": None, "centre_error_mm_p95": None}
    assert bands[(0.2, 0.5)]["frames"] == 1 and bands[(0.2, 0.5)]["reported_share"] == 1.0
    assert bands[(0.2, 0.5)]["centre_error_mm_median"] == pytest.approx(2.0)
    assert bands[(0.5, None)]["frames"] == 2 and bands[(0.5, None)]["reported_share"] == 1.0
    assert bands[(0.5, None)]["centre_error_mm_median"] == pytest.approx(0.25)    # median of 0 and 0.5 mm
    assert bands[(0.5, None)]["centre_error_mm_p95"] == pytest.approx(0.475)
    assert m["detected_from_n"] is None   # bands of one or two frames are too few to judge
    assert contact_metrics(predicted, true, BIN_CENTERS_M, contact_level_n=0.001)["false_contacts"] == 1
    assert contact_metrics(predicted, true, BIN_CENTERS_M, contact_level_n=1.0)["bands"][-1]["reported_share"] == 0.0


def _bands(*judged):
    """Bands from the lightest: (reported share, frames) each."""
    return [{"load_n": [low, high], "frames": frames, "reported_share": share}
            for (share, frames), low, high in zip(judged, LOAD_BAND_EDGES_N[:-1], LOAD_BAND_EDGES_N[1:], strict=True)]


def test_detection_limit_is_given_only_where_the_data_show_it():
    # The shipped model's test split: reported from 0.2 N.
    assert detection_limit(_bands((0.06, 387), (0.41, 503), (0.89, 804), (1.0, 1601), (1.0, 5924))) == 0.2
    assert detection_limit(_bands((0.9, 10), (0.95, 20), (1.0, 30), (1.0, 40), (1.0, 50))) == 0.0  # any load
    # No light presses in the data, or the miss in a band too small to judge: not shown.
    assert detection_limit(_bands((None, 0), (None, 0), (None, 0), (1.0, 100), (1.0, 100))) is None
    assert detection_limit(_bands((0.0, 9), (1.0, 100), (1.0, 100), (1.0, 100), (1.0, 100))) is None
    assert detection_limit(_bands((0.0, 50), (0.5, 9), (1.0, 100), (0.95, 100), (0.5, 100))) is None  # heaviest short
    assert detection_limit(_bands((0.0, 50), (0.5, 9), (0.95, 100), (1.0, 100), (1.0, 100))) == 0.1  # 9 passed over


def test_centre_of_pressure_of_a_frame_without_load_is_nan_and_a_pull_does_not_count():
    centre = _centre_of_pressure(_fz_frames({}, {(0, 3): -0.5, (2, 0): 0.1})[..., 2], BIN_CENTERS_M)
    assert np.isnan(centre[0]).all()
    np.testing.assert_allclose(centre[1], [1e-3, 5e-3])


def test_contact_metrics_refuse_a_bad_level_mismatched_shapes_and_non_finite_forces():
    frames = _fz_frames({(1, 1): 0.3})
    for bad in (np.inf, np.nan):
        with pytest.raises(ValueError, match="NaN or Inf"):
            contact_metrics(_fz_frames({(1, 1): bad}), frames, BIN_CENTERS_M)
    for level in (0.0, -0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="contact_level_n"):
            contact_metrics(frames, frames, BIN_CENTERS_M, contact_level_n=level)
    with pytest.raises(ValueError, match="do not match"):
        contact_metrics(frames, frames, BIN_CENTERS_M[:2])
    with pytest.raises(ValueError, match="do not match"):
        contact_metrics(frames[:, :2], frames, BIN_CENTERS_M)


def test_contact_table_lists_false_contacts_and_each_band():
    true = _fz_frames({}, {(1, 1): 0.3})
    m = contact_metrics(_fz_frames({}, {(1, 2): 0.3}), true, BIN_CENTERS_M)
    lines = contact_table({"paper_grid test split": m}).splitlines()
    assert "10 mN" in lines[0] and "0.2-0.5 N" in lines[1] and "> 0.5 N" in lines[1]
    assert lines[3].startswith("paper_grid test split") and "0 of 1" in lines[3]
    assert "100 % 2.00 mm" in lines[3] and lines[3].rstrip().endswith("-")  # one press: no detection limit shown
    m["detected_from_n"] = 0.2
    assert contact_table({"paper_grid test split": m}).splitlines()[3].rstrip().endswith("0.2 N")


def test_least_squares_line_recovers_a_line():
    x = np.array([0.1, 0.5, 1.0])
    assert least_squares_line(x, 2.0 * x - 1.0) == pytest.approx((2.0, -1.0))
    for one_x in ([1.0], [0.5, 0.5]):  # no line is determined: lstsq gave a made-up slope of half the error
        with pytest.raises(ValueError, match="a least-squares line needs two distinct x"):
            least_squares_line(np.array(one_x), np.full(len(one_x), 0.004))


def test_a_trend_line_is_drawn_in_millinewtons_over_the_fractions_measured():
    trend = {"slope_n_per_fraction": -0.001, "intercept_n": 0.003}  # 3 mN at no data, 2 mN with all of it
    percent, error_mn = trend_line_mn(trend, np.array([0.1, 0.5, 1.0]), scale=0.1)
    assert (percent[0], percent[-1]) == pytest.approx((10.0, 100.0))
    assert (error_mn[0], error_mn[-1]) == pytest.approx((0.29, 0.2))


def test_figures_are_written(tmp_path):
    rng = np.random.default_rng(0)
    true = np.abs(rng.normal(size=(6, 4, 5, 3))) * 0.01
    frames = example_frames(true)
    assert frames[0] == int(np.argmax(true[..., 2].sum(axis=(1, 2)))) and len(set(frames)) == len(frames)
    path = plot_fz_maps(true, true * 0.9, tmp_path / "fz.png", "test")
    assert path.stat().st_size > 10_000
    m = force_metrics(true * 0.9, true)
    sweep = {"added_camera": "cam3", "base_cameras": 3,
             "full_training": {"wall_time_s": 70.0, "metrics": m},
             "recalibration": [{"fraction": f, "wall_time_s": 10.0 * f, "metrics": m} for f in (0.1, 0.5, 1.0)],
             "trend_lines": {f"{key}_fz": {"slope_n_per_fraction": -0.001, "intercept_n": m[key][2]}
                             for key in ("rmse_bin_n", "rmse_total_n")},
             "speedup": {"fraction": 1.0, "factor": 7.0}}
    assert plot_recalibration(sweep, tmp_path / "recal.png").stat().st_size > 10_000


def test_a_figure_that_cannot_be_written_is_an_error_naming_the_file_and_leaves_nothing_half_written(tmp_path):
    """A directory where the PNG goes (or a full disk) ended eval with a traceback."""
    from tactile_fusion.artifacts import ModelFileError

    true = np.abs(np.random.default_rng(0).normal(size=(3, 4, 5, 3))) * 0.01
    (tmp_path / "fz.png").mkdir()
    with pytest.raises(ModelFileError, match=f"{tmp_path / 'fz.png'}.* cannot be written .*run the command again"):
        plot_fz_maps(true, true, tmp_path / "fz.png", "test")
    assert [p.name for p in tmp_path.iterdir()] == ["fz.png"] and not any((tmp_path / "fz.png").iterdir())
