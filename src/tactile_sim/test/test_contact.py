"""The analytic ground-truth model: calibration, textbook limits, shapes, shear and the hard cases."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_sim.contact import (
    MAX_SPHERE_CHI,
    AnalyticContactModel,
    Contact,
    FlatPunch,
    HeightMap,
    Sphere,
    dimitriadis_factor,
    ground_truth_model,
    max_depth_m,
    normal_load,
    press_contact,
    press_report,
    reference_press,
    stick_depth_m,
)
from tactile_sim.contact_solver import NumericalContactModel
from tactile_sim.elastic import compliant_layer

CONFIG = Path(__file__).resolve().parents[3] / "config"


def whole_contact_force_n(sensor, contact):
    """(3,) force of the whole contact, off-surface part included: Hertz / Sneddon with the thin-layer factor, and
    the Cattaneo-Mindlin tangential force Q = mu [P(d) - P(d')] along the shear (d' the stick zone's depth)."""
    layer = compliant_layer(sensor)
    normal = normal_load(layer, contact.shape, contact.depth_m).force_n
    tangential = contact.friction * (normal - normal_load(layer, contact.shape, stick_depth_m(layer, contact)).force_n)
    shear = math.hypot(*contact.shear_m)
    direction = np.array(contact.shear_m) / shear if shear > 0 else np.zeros(2)
    return np.array([*(tangential * direction), normal])


@pytest.mark.parametrize("name", ["sensor.yaml", "skin_3x3.yaml"])
def test_reference_press_gives_about_3_newtons(name):
    sensor = load_sensor(CONFIG / name)
    forces = ground_truth_model(sensor).bin_forces([reference_press(sensor)])
    assert forces[..., 2].sum() == pytest.approx(3.0, abs=0.15)
    assert forces.shape == (sensor.grid.rows, sensor.grid.cols, 3)


def test_half_space_limit_is_hertz(sensor, single_layer):
    """Thickness -> infinity: F = (4/3) E* sqrt(R) d^1.5 and a = sqrt(R d) (Johnson eq. 4.23) within 2 %."""
    thick = single_layer(sensor, 100.0, youngs_modulus_pa=400e3, poisson_ratio=0.45)
    e_star = 400e3 / (1 - 0.45**2)
    radius, depth = 0.005, 1.0e-3
    forces = ground_truth_model(thick).bin_forces([Contact(*thick.grid.centre_m, depth, Sphere(radius))])
    hertz = 4.0 / 3.0 * e_star * math.sqrt(radius) * depth**1.5
    assert forces[..., 2].sum() == pytest.approx(hertz, rel=0.02)
    # contact radius: the force-weighted r^2 of Hertz pressure is 2 a^2 / 5; the bins' own r^2 adds the bin
    # area's second moment (w^2 / 6) - the binned distribution keeps the contact size
    centres = thick.grid.bin_centers_m() - np.array(thick.grid.centre_m)
    r2 = (forces[..., 2] * (centres**2).sum(axis=-1)).sum() / forces[..., 2].sum()
    contact_radius = math.sqrt(max(r2 - thick.grid.bin_width_m**2 / 6.0, 0.0) * 5.0 / 2.0)
    assert contact_radius == pytest.approx(math.sqrt(radius * depth), rel=0.05)


def test_thin_layer_is_stiffer_by_the_dimitriadis_factor(sensor, single_layer):
    radius, depth = 0.005, 1.0e-3
    forces = {}
    for h in (100.0, 8e-3, 4e-3, 3e-3):
        layered = single_layer(sensor, h)
        forces[h] = ground_truth_model(layered).bin_forces([Contact(*sensor.grid.centre_m, depth)])[..., 2].sum()
    for h in (8e-3, 4e-3, 3e-3):
        chi = math.sqrt(radius * depth) / h
        assert forces[h] / forces[100.0] == pytest.approx(1 + 1.133 * chi + 1.283 * chi**2 + 0.769 * chi**3
                                                          + 0.0975 * chi**4, rel=1e-3)
    assert forces[3e-3] > forces[4e-3] > forces[8e-3] > forces[100.0]
    assert dimitriadis_factor(0.0) == 1.0


def test_bin_forces_sum_to_the_contact_force(sensor, model):
    for contact in [Contact(0.0213, 0.0187, 1.2e-3, shear_m=(2e-4, -1e-4), friction=0.8),
                    Contact(0.03, 0.02, 0.7e-3, FlatPunch(0.003), shear_m=(-1e-5, 0.0))]:
        forces = model.bin_forces([contact])
        np.testing.assert_allclose(forces.sum(axis=(0, 1)), whole_contact_force_n(sensor, contact), rtol=1e-12,
                                   atol=1e-15)


def test_zero_depth_gives_exactly_zero(model):
    forces = model.bin_forces([Contact(0.02, 0.02, 0.0), Contact(0.01, 0.01, 0.0, FlatPunch(0.002), (1e-4, 0))])
    assert not forces.any()
    assert not model.bin_forces([]).any()


@pytest.mark.parametrize("shape", [Sphere(), FlatPunch(0.002)])
def test_vanishing_depth_is_finite_and_tiny(sensor, model, shape):
    contact = Contact(*sensor.grid.centre_m, 1e-15, shape, shear_m=(1e-3, 0.0))  # 1e-12 mm
    forces = model.bin_forces([contact])
    assert np.all(np.isfinite(forces))
    assert 0.0 < forces[..., 2].sum() < 1e-9
    assert np.all(forces[..., 2] >= 0.0)
    np.testing.assert_allclose(forces.sum(axis=(0, 1)), whole_contact_force_n(sensor, contact), rtol=1e-12)


def test_centre_on_a_bin_corner_splits_evenly(sensor, model):
    w, lb = sensor.grid.bin_width_m, sensor.grid.bin_length_m
    for depth in (1e-15, 1e-3):
        forces = model.bin_forces([Contact(12 * w, 13 * lb, depth)])
        block = forces[12:14, 11:13, 2]
        np.testing.assert_allclose(block, block[0, 0], rtol=1e-9)
        assert block.sum() == pytest.approx(forces[..., 2].sum(), rel=0.5 if depth > 1e-6 else 1e-12)


def test_edges_corners_and_off_surface_keep_only_the_surface_part(sensor, model):
    full = normal_load(compliant_layer(sensor), Sphere(), 1e-3).force_n
    width, length = sensor.grid.width_m, sensor.grid.length_m
    edge = model.bin_forces([Contact(0.0, 0.5 * length, 1e-3)])
    corner = model.bin_forces([Contact(width, length, 1e-3)])
    assert edge[..., 2].sum() == pytest.approx(0.5 * full, rel=0.02)     # half the contact is on the surface
    assert corner[..., 2].sum() == pytest.approx(0.25 * full, rel=0.02)  # a quarter
    assert corner[-1, -1, 2] > 0 and corner[0, 0, 2] == 0
    outside = model.bin_forces([Contact(-0.01, 0.02, 1e-3), Contact(width + 0.01, length + 0.01, 1e-3)])
    assert not outside.any()
    for forces in (edge, corner):
        assert np.all(np.isfinite(forces)) and np.all(forces[..., 2] >= 0)


def test_overlapping_contacts_superpose(model):
    a = Contact(0.020, 0.025, 1.0e-3)
    b = Contact(0.022, 0.025, 0.8e-3, FlatPunch(0.002))
    both = model.bin_forces([a, b])
    np.testing.assert_allclose(both, model.bin_forces([a]) + model.bin_forces([b]), rtol=1e-12)


def test_deepest_press_is_allowed_and_deeper_raises(sensor, model):
    limit = max_depth_m(sensor, Sphere())
    assert limit == pytest.approx(0.5 * compliant_layer(sensor).thickness_m)
    forces = model.bin_forces([Contact(*sensor.grid.centre_m, limit)])
    assert np.all(np.isfinite(forces)) and forces[..., 2].sum() > 3.0
    with pytest.raises(ValueError, match="deeper than the deepest allowed press"):
        model.bin_forces([Contact(*sensor.grid.centre_m, limit * 1.001)])
    assert max_depth_m(sensor, Sphere(0.001)) == 0.001
    assert max_depth_m(sensor, HeightMap(np.array([[0.0, 3e-4]]), 1e-4)) == 3e-4


@pytest.mark.parametrize("model_name", ["analytic", "numerical"])
def test_indenters_outside_the_thin_layer_fits_are_refused(sensor, model_name):
    """Far outside the fits (a 400 mm sphere 2 mm deep: chi = 5, twice the exact force; a 20 mm punch: a / h = 2.5,
    104 N instead of 48 N) the models refuse the press instead of answering wrongly; at the limits they answer."""
    model = ground_truth_model(sensor, model_name)
    h = compliant_layer(sensor).thickness_m
    centre = sensor.grid.centre_m
    assert max_depth_m(sensor, Sphere(0.2)) == pytest.approx((MAX_SPHERE_CHI * h) ** 2 / 0.2)
    for contact, message in [(Contact(*centre, 2e-3, Sphere(0.2)), r"chi = sqrt\(R d\) / h at most 0.8"),
                             (Contact(*centre, 1e-3, Sphere(1e9)), r"chi = sqrt\(R d\) / h at most 0.8"),
                             (Contact(*centre, 1e-3, FlatPunch(0.010)), r"a / h = 2.5, above 1")]:
        with pytest.raises(ValueError, match=message):
            model.bin_forces([contact])
    widest_punch = Contact(10e-3, 10e-3, 1e-3, FlatPunch(h))
    for contact in [Contact(*centre, max_depth_m(sensor, Sphere(0.02)), Sphere(0.02)), widest_punch]:
        forces = model.bin_forces([contact])
        assert np.all(np.isfinite(forces)) and forces[..., 2].sum() > 0.5


def test_shear_gives_mindlin_partial_slip_along_the_shear(sensor, single_layer):
    """Half-space Hertz + Mindlin (Johnson eq. 7.42): Q = mu P [1 - (1 - delta / delta_slip)^(3/2)]."""
    thick = single_layer(sensor, 100.0, poisson_ratio=0.45)
    model = ground_truth_model(thick)
    layer = compliant_layer(thick)
    radius, depth, mu = 0.005, 1e-3, 0.6
    p = normal_load(layer, Sphere(radius), depth).force_n
    a = math.sqrt(radius * depth)
    delta_slip = 3 * mu * p * (2 - layer.poisson_ratio) / (16 * layer.shear_modulus_pa * a)
    direction = np.array([0.6, -0.8])
    for fraction in (0.1, 0.5, 0.9, 1.5):
        shear = tuple(fraction * delta_slip * direction)
        forces = model.bin_forces([Contact(0.02, 0.02, depth, shear_m=shear, friction=mu)])
        q = forces[..., :2].sum(axis=(0, 1))
        expected = mu * p * (1 - (1 - min(fraction, 1.0)) ** 1.5)
        assert np.linalg.norm(q) == pytest.approx(expected, rel=1e-4)  # 1e-4: a 100 m layer is not quite infinite
        np.testing.assert_allclose(q / np.linalg.norm(q), direction, atol=1e-12)
        # Coulomb: no bin carries more tangential force than mu times its normal force (tolerance: rounding)
        assert np.all(np.linalg.norm(forces[..., :2], axis=-1) <= mu * forces[..., 2] * (1 + 1e-9) + 1e-15)


def test_partial_slip_traction_peaks_at_the_slip_annulus(sensor, model):
    """Mindlin's traction is mu p outside the stick zone and lower inside: small shear loads the rim first."""
    x, y = sensor.grid.centre_m
    forces = model.bin_forces([Contact(x, y, 1.5e-3, shear_m=(2e-5, 0.0))])
    ratio = forces[..., 0] / np.where(forces[..., 2] > 0, forces[..., 2], np.inf)
    row, col = int(y / sensor.grid.bin_length_m), int(x / sensor.grid.bin_width_m)
    assert 0 < ratio[row, col] < ratio[row, col + 1] <= 1.0  # friction 1
    assert ratio[row, col + 2] == 0  # outside the contact (radius 2.7 mm)


def test_flat_punch_matches_sneddon_in_the_half_space(sensor, single_layer):
    thick = single_layer(sensor, 100.0, youngs_modulus_pa=300e3, poisson_ratio=0.4)
    forces = ground_truth_model(thick).bin_forces([Contact(0.02, 0.02, 2e-4, FlatPunch(0.003))])
    assert forces[..., 2].sum() == pytest.approx(2 * 300e3 / (1 - 0.4**2) * 0.003 * 2e-4, rel=1e-3)
    # the edge-singular pressure loads bins at the rim more than at the centre (bin areas are equal)
    loaded = forces[..., 2][forces[..., 2] > 0]
    assert loaded.size >= 9


def test_vertical_press_has_no_net_tangential_force(model):
    forces = model.bin_forces([Contact(0.0213, 0.0301, 1.4e-3), Contact(0.01, 0.01, 1e-3, FlatPunch(0.002))])
    assert not forces[..., :2].any()


def test_height_map_needs_the_numerical_model(model):
    with pytest.raises(ValueError, match="numerical"):
        model.bin_forces([Contact(0.02, 0.02, 1e-4, HeightMap(np.array([[1e-3, 0.0, 1e-3]]), 1e-4))])


@pytest.mark.parametrize("kwargs, message", [
    (dict(x_m=0.0, y_m=0.0, depth_m=-1e-3), "depth_m must be >= 0"),
    (dict(x_m=math.nan, y_m=0.0, depth_m=1e-3), "x_m must be a finite number"),
    (dict(x_m=0.0, y_m=0.0, depth_m=1e-3, friction=-0.1), "friction must be >= 0"),
    (dict(x_m=0.0, y_m=0.0, depth_m=1e-3, shear_m=(1.0,)), "shear_m must be two finite numbers"),
    (dict(x_m=0.0, y_m=0.0, depth_m=1e-3, shape="sphere"), "shape must be a Sphere"),
])
def test_bad_contacts_are_rejected_clearly(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Contact(**kwargs)


def test_bad_shapes_are_rejected_clearly():
    with pytest.raises(ValueError, match="radius_m must be a positive"):
        Sphere(0.0)
    with pytest.raises(ValueError, match="radius_m must be a positive"):
        FlatPunch(math.inf)
    with pytest.raises(ValueError, match="subtract heights_m.min"):
        HeightMap(np.ones((2, 2)), 1e-4)
    with pytest.raises(ValueError, match="2-D"):
        HeightMap(np.zeros(4), 1e-4)


def test_bad_model_resolutions_are_rejected_clearly(sensor):
    for rings, sectors in ((0, 32), (2.5, 32), (24, 30), (24, 0)):
        with pytest.raises(ValueError, match="rings must be a whole number >= 1 and sectors a positive multiple of 4"):
            AnalyticContactModel(sensor, rings, sectors)
    for pixels in (0, 1.5):
        with pytest.raises(ValueError, match=f"pixels_per_bin must be a whole number >= 1, got {pixels}"):
            NumericalContactModel(sensor, pixels)


def test_press_report_matches_bin_forces(sensor, model):
    contact = press_contact(20.0, 30.0, 1.2, shear_x_mm=0.1)
    report = json.loads(json.dumps(press_report(sensor, contact, model)))
    forces = model.bin_forces([contact])
    np.testing.assert_allclose(np.array(report["bin_forces_n"]).reshape(forces.shape), forces)
    np.testing.assert_allclose(report["total_force_n"], forces.sum(axis=(0, 1)))
    assert report["total_force_n"][0] > 0 and report["total_force_n"][1] == 0
    assert report["loaded_bins"] == np.count_nonzero(forces[..., 2])
    assert report["contact"]["depth_mm"] == pytest.approx(1.2)
    punch = press_contact(20.0, 30.0, 0.5, shape="punch", radius_mm=2.0)
    assert punch.shape == FlatPunch(0.002)
    with pytest.raises(ValueError, match="--radius-mm"):
        press_contact(20.0, 30.0, 0.5, shape="punch")
    with pytest.raises(ValueError, match="--shape"):
        press_contact(20.0, 30.0, 0.5, shape="cube")


def test_press_report_refuses_a_press_beside_the_surface(sensor, model):
    # a sphere of 5 mm radius 1 mm deep reaches sqrt(5 * 1) = 2.24 mm: 2 mm beside the 49 mm edge it still presses
    width_mm = sensor.grid.width_m * 1e3
    grazing = press_report(sensor, press_contact(width_mm + 2.0, 25.0, 1.0), model)
    assert grazing["total_force_n"][2] > 0 and grazing["loaded_bins"] > 0
    # it reported 0 N over 0 bins, status 0, for a press 11 mm beside it (found in review)
    with pytest.raises(ValueError, match=r"a press at \(60, 25\) mm is 11 mm off the 49 x 51 mm surface, beyond the "
                                         r"2.24 mm its contact reaches at its deepest: it would press nothing"):
        press_report(sensor, press_contact(60.0, 25.0, 1.0), model)
    with pytest.raises(ValueError, match="is 3 mm off the 49 x 51 mm surface"):
        press_report(sensor, press_contact(-3.0, 25.0, 1.0, shape="punch", radius_mm=2.0), model)


def test_unknown_model_name_is_rejected(sensor):
    with pytest.raises(ValueError, match="'analytic' or 'numerical'"):
        ground_truth_model(sensor, "fem")


@pytest.mark.parametrize("model_name", ["analytic", "numerical"])
def test_press_command_prints_the_bin_forces(sensor, capsys, model_name):
    from tactile_sim.cli import main

    argv = ["press", "--x-mm", "10.3", "--y-mm", "40.1", "--depth-mm", "1.1", "--shear-y-mm", "0.05",
            "--model", model_name, "--sensor", str(CONFIG / "sensor.yaml"), "--json"]
    assert main(argv) in (0, None)
    report = json.loads(capsys.readouterr().out)
    forces = ground_truth_model(sensor, model_name).bin_forces([press_contact(10.3, 40.1, 1.1, shear_y_mm=0.05)])
    np.testing.assert_allclose(np.array(report["bin_forces_n"]).reshape(forces.shape), forces, rtol=1e-12)
    np.testing.assert_allclose(report["total_force_n"], forces.sum(axis=(0, 1)), rtol=1e-12)
    assert report["total_force_n"][1] > 0 and report["total_force_n"][2] > 1.0


def test_benchmark_reports_every_model(sensor):
    from tactile_sim.contact import benchmark_models

    result = benchmark_models(sensor, repeats=1, numerical_repeats=1)
    assert set(result) == {"analytic", "numerical"}
    for entry in result.values():
        assert entry["press_ms_median"] > 0 and entry["sheared_press_ms_median"] > 0
        assert entry["press_total_force_n"][2] == pytest.approx(3.0, abs=0.15)
        assert entry["sheared_press_total_force_n"][0] > 0
    assert result["analytic"]["cost_vs_analytic"] == 1.0
