"""The numerical ground-truth model: influence coefficients, the constrained solver, and its agreement with
the textbook solutions and with the analytic model."""

import math
from pathlib import Path

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_sim.contact import (
    MAX_SPHERE_CHI,
    Contact,
    FlatPunch,
    HeightMap,
    Sphere,
    contact_radius_m,
    ground_truth_model,
    max_depth_m,
    press_report,
    reference_press,
)
from tactile_sim.contact_solver import NumericalContactModel, layer_compliance_factor, surface_influence
from tactile_sim.elastic import CompliantLayer, compliant_layer

CONFIG = Path(__file__).resolve().parents[3] / "config"


@pytest.fixture(scope="module")
def model(sensor):
    return ground_truth_model(sensor, "numerical")


@pytest.fixture(scope="module")
def analytic(sensor):
    return ground_truth_model(sensor, "analytic")


def test_layer_compliance_limits():
    x = np.array([0.0, 1e-4, 50.0, 1e4])
    for nu in (0.0, 0.3, 0.49):
        c = layer_compliance_factor(x, nu)
        assert np.all(np.isfinite(c))
        assert c[0] == 0.0 and c[2] == pytest.approx(1.0) and c[3] == pytest.approx(1.0)
        # thin layer: the oedometric compliance h (1 + nu)(1 - 2 nu) / (E (1 - nu)) = 2 (1 - nu^2) C / (E q)
        assert c[1] / x[1] == pytest.approx((1 - 2 * nu) / (2 * (1 - nu) ** 2), rel=1e-3)


def test_influence_coefficients_half_space_and_layer():
    pixel = 0.25e-3
    half_space = CompliantLayer(thickness_m=100.0, youngs_modulus_pa=300e3, poisson_ratio=0.45)
    e_star = half_space.plane_strain_modulus_pa
    kernel = surface_influence(half_space, pixel, pixel, 64, 64)
    # far from the pixel, Boussinesq's point load P / (pi E* r) with P = pressure x pixel area
    r = 40 * pixel
    assert kernel[0, 40] == pytest.approx(pixel * pixel / (math.pi * e_star * r), rel=1e-3)
    assert kernel[0, 40] == pytest.approx(kernel[40, 0]) == pytest.approx(kernel[0, -40])
    # under the pixel centre: int 1/r over a square of half side a is 8 a ln(1 + sqrt 2) (polar coordinates)
    assert kernel[0, 0] == pytest.approx(8 * math.log(1 + math.sqrt(2)) * 0.5 * pixel / (math.pi * e_star), rel=1e-5)
    thin = CompliantLayer(thickness_m=4e-3, youngs_modulus_pa=300e3, poisson_ratio=0.45)
    layer_kernel = surface_influence(thin, pixel, pixel, 256, 256)
    assert np.all(np.isfinite(layer_kernel))
    assert layer_kernel[0, 0] < kernel[0, 0]                       # the bonded base stiffens
    assert abs(layer_kernel[0, 200]) < 1e-3 * layer_kernel[0, 0]   # and kills the far field (50 mm = 12.5 h)


def test_half_space_limit_is_hertz(sensor, single_layer):
    """Small depth (the sphere is then a paraboloid): F and a of Hertz within 2 %."""
    thick = single_layer(sensor, 100.0, youngs_modulus_pa=400e3, poisson_ratio=0.45)
    e_star = 400e3 / (1 - 0.45**2)
    radius, depth = 0.005, 0.4e-3
    model = NumericalContactModel(thick, pixels_per_bin=12)
    forces, (rows, cols) = model.pixel_forces([Contact(*thick.grid.centre_m, depth, Sphere(radius))])
    fz = forces[..., 2]
    assert fz.sum() == pytest.approx(4.0 / 3.0 * e_star * math.sqrt(radius) * depth**1.5, rel=0.02)
    y = (np.arange(rows.start, rows.stop) + 0.5) * model.pixel_y_m - thick.grid.centre_m[1]
    x = (np.arange(cols.start, cols.stop) + 0.5) * model.pixel_x_m - thick.grid.centre_m[0]
    r2 = x[None, :] ** 2 + y[:, None] ** 2
    contact_radius = math.sqrt(2.5 * (fz * r2).sum() / fz.sum())  # Hertz: <r^2> = 2 a^2 / 5
    assert contact_radius == pytest.approx(math.sqrt(radius * depth), rel=0.02)


def test_reference_press_agrees_with_the_analytic_model(sensor, model, analytic):
    """The exact layer compliance confirms Dimitriadis's thin-layer factor (and the 3 N calibration)."""
    contact = reference_press(sensor)
    numerical = model.bin_forces([contact])
    assert numerical[..., 2].sum() == pytest.approx(analytic.bin_forces([contact])[..., 2].sum(), rel=0.03)
    assert numerical[..., 2].sum() == pytest.approx(3.0, abs=0.15)
    assert np.all(numerical[..., 2] >= 0) and not numerical[..., :2].any()


@pytest.mark.parametrize("radius_m", [1e-3, 2e-3, 4e-3])
def test_flat_punch_agrees_with_the_analytic_model(sensor, model, analytic, radius_m):
    contact = Contact(*sensor.grid.centre_m, 0.2e-3, FlatPunch(radius_m))
    assert model.bin_forces([contact])[..., 2].sum() == pytest.approx(
        analytic.bin_forces([contact])[..., 2].sum(), rel=0.1)


@pytest.mark.parametrize("radius_m", [5e-3, 10e-3])
def test_spheres_at_the_largest_allowed_chi_agree_with_the_analytic_model(sensor, model, analytic, radius_m):
    """At the deepest allowed press (chi = 0.79 for the 10 mm sphere 2 mm deep, MAX_SPHERE_CHI = 0.8 for a 20 mm
    sphere 1.02 mm deep) the Dimitriadis series is within 7 % of the exact layer compliance."""
    contact = Contact(*sensor.grid.centre_m, max_depth_m(sensor, Sphere(radius_m)), Sphere(radius_m))
    assert math.sqrt(radius_m * contact.depth_m) / compliant_layer(sensor).thickness_m <= MAX_SPHERE_CHI
    assert model.bin_forces([contact])[..., 2].sum() == pytest.approx(
        analytic.bin_forces([contact])[..., 2].sum(), rel=0.08)


def test_height_map_of_a_sphere_matches_the_sphere(sensor, model):
    pixel, n, radius = 0.05e-3, 121, 5e-3
    offsets = (np.arange(n) - (n - 1) / 2) * pixel
    x, y = np.meshgrid(offsets, offsets)
    heights = radius - np.sqrt(radius**2 - x**2 - y**2)
    as_map = model.bin_forces([Contact(*sensor.grid.centre_m, 1e-3, HeightMap(heights - heights.min(), pixel))])
    as_sphere = model.bin_forces([Contact(*sensor.grid.centre_m, 1e-3, Sphere(radius))])
    assert as_map[..., 2].sum() == pytest.approx(as_sphere[..., 2].sum(), rel=0.005)
    np.testing.assert_allclose(as_map, as_sphere, atol=0.01 * as_sphere.max())


def test_a_height_map_press_is_reported_and_refused_beside_the_surface_as_a_sphere_is(sensor, model):
    """press_report read a radius that a height map has not: AttributeError for any height-map press (review). A height
    map reaches as far as its pixels within the depth of its lowest point: the footprint of a rigid indentation, an
    upper bound of the contact (a sphere's map: sqrt(2 R d - d^2) = 3 mm at 1 mm deep, Hertz's contact 2.24 mm)."""
    pixel, n, radius = 0.1e-3, 101, 5e-3
    offsets = (np.arange(n) - (n - 1) / 2) * pixel
    x, y = np.meshgrid(offsets, offsets)
    sphere_map = HeightMap(radius - np.sqrt(np.clip(radius**2 - x**2 - y**2, 0.0, None)), pixel)
    assert contact_radius_m(sphere_map, 1e-3) == pytest.approx(3e-3, abs=pixel)
    on_surface = Contact(*sensor.grid.centre_m, 1e-3, sphere_map)
    report = press_report(sensor, on_surface, model)
    np.testing.assert_allclose(np.array(report["bin_forces_n"]).reshape(sensor.grid.rows, sensor.grid.cols, 3),
                               model.bin_forces([on_surface]))
    assert report["total_force_n"][2] > 0
    width_mm = sensor.grid.width_m * 1e3
    grazing = press_report(sensor, Contact((width_mm + 2.0) * 1e-3, 0.025, 1e-3, sphere_map), model)
    assert grazing["total_force_n"][2] > 0  # 2 mm beside the edge, within the 2.24 mm Hertz's contact reaches
    with pytest.raises(ValueError, match=r"is 4 mm off the 49 x 51 mm surface, beyond the 3\.\d+ mm its contact"):
        press_report(sensor, Contact((width_mm + 4.0) * 1e-3, 0.025, 1e-3, sphere_map), model)


def test_an_asymmetric_height_map_loads_its_low_side(sensor, model):
    """A wedge tilted along +x touches first on its low (-x) side."""
    pixel = 0.1e-3
    x = (np.arange(81) - 40) * pixel
    heights = np.tile(0.1 * (x - x.min()), (81, 1))
    forces = model.bin_forces([Contact(*sensor.grid.centre_m, 0.3e-3, HeightMap(heights, pixel))])
    cols = np.arange(sensor.grid.cols)
    fz = forces[..., 2].sum(axis=0)
    assert fz.sum() > 0 and (cols * fz).sum() / fz.sum() < sensor.grid.centre_m[0] / sensor.grid.bin_width_m - 0.5


def test_overlapping_indenters_are_a_union_not_a_sum(sensor, model):
    x, y = sensor.grid.centre_m
    one = model.bin_forces([Contact(x, y, 1e-3)])
    np.testing.assert_allclose(model.bin_forces([Contact(x, y, 1e-3), Contact(x, y, 1e-3)]), one)
    near = model.bin_forces([Contact(x, y, 1e-3), Contact(x + 3e-3, y, 1e-3)])
    apart = model.bin_forces([Contact(x + 3e-3, y, 1e-3)])
    assert one[..., 2].sum() < near[..., 2].sum() < (one + apart)[..., 2].sum()  # they share the gel between
    assert np.all(near[..., 2] >= 0) and np.all(np.isfinite(near))


def test_shear_gives_partial_slip_along_the_shear(sensor, model, analytic):
    x, y = sensor.grid.centre_m
    direction = np.array([0.6, -0.8])
    previous = 0.0
    for shear in (1e-5, 1e-4, 3e-4, 1e-3, 5e-3):
        contact = Contact(x, y, 1.5e-3, shear_m=tuple(shear * direction), friction=0.7)
        forces = model.bin_forces([contact])
        q = forces[..., :2].sum(axis=(0, 1))
        p = forces[..., 2].sum()
        np.testing.assert_allclose(q / np.linalg.norm(q), direction, atol=1e-12)
        assert previous < np.linalg.norm(q) <= 0.7 * p * (1 + 1e-9)
        previous = np.linalg.norm(q)
        expected = analytic.bin_forces([contact])[..., :2].sum(axis=(0, 1))
        assert np.linalg.norm(q) == pytest.approx(np.linalg.norm(expected), rel=0.08)
        assert np.all(np.linalg.norm(forces[..., :2], axis=-1) <= 0.7 * forces[..., 2] * (1 + 1e-9) + 1e-15)
    assert previous == pytest.approx(0.7 * p, rel=1e-9)  # 5 mm: gross slip


def test_hard_cases_stay_finite(sensor, model):
    x, y = sensor.grid.centre_m
    assert not model.bin_forces([Contact(x, y, 0.0), Contact(0.01, 0.01, 0.0, FlatPunch(1e-3))]).any()
    assert not model.bin_forces([]).any()
    tiny = model.bin_forces([Contact(x, y, 1e-15)])
    full = model.bin_forces([Contact(x, y, 1e-3)])[..., 2].sum()
    edge = model.bin_forces([Contact(0.0, y, 1e-3)])
    corner = model.bin_forces([Contact(sensor.grid.width_m, sensor.grid.length_m, 1e-3)])
    outside = model.bin_forces([Contact(-0.01, y, 1e-3)])
    deepest = model.bin_forces([Contact(x, y, 0.5 * compliant_layer(sensor).thickness_m)])
    for forces in (tiny, edge, corner, outside, deepest):
        assert np.all(np.isfinite(forces)) and np.all(forces[..., 2] >= 0)
    assert 0 < corner[..., 2].sum() < edge[..., 2].sum() < full < deepest[..., 2].sum()
    assert not outside.any()
    with pytest.raises(ValueError, match="deeper than the deepest allowed press"):
        model.bin_forces([Contact(x, y, 2.1e-3)])


def test_skin_sensor_works_too():
    skin = load_sensor(CONFIG / "skin_3x3.yaml")
    forces = ground_truth_model(skin, "numerical").bin_forces([reference_press(skin)])
    assert forces.shape == (38, 38, 3)
    assert forces[..., 2].sum() == pytest.approx(3.0, abs=0.15)
