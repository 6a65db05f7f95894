"""The gel model: effective compliant layer and the displacement of embedded particles."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from tactile_description import GelLayer, load_sensor
from tactile_sim.contact import Contact, reference_press
from tactile_sim.elastic import CompliantLayer, GelDisplacement, compliant_layer, layer_kernel

CONFIG = Path(__file__).resolve().parents[3] / "config"


def grid_points(sensor, depth_m, spacing_m=1e-3):
    """A regular (N, 3) lattice of points at one depth over the whole surface."""
    x = np.arange(0.5 * spacing_m, sensor.grid.width_m, spacing_m)
    y = np.arange(0.5 * spacing_m, sensor.grid.length_m, spacing_m)
    xx, yy = np.meshgrid(x, y)
    return np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, -depth_m)])


def test_reference_gel_is_a_4mm_layer_on_a_rigid_base(sensor):
    layer = compliant_layer(sensor)
    assert layer.thickness_m == pytest.approx(4e-3)
    # series average of 3 mm at E1 and 1 mm at E2 (same nu): h / E = 3 mm / E1 + 1 mm / E2
    e1, e2 = sensor.layer("particle_layer").youngs_modulus_pa, sensor.layer("protective_top").youngs_modulus_pa
    assert layer.youngs_modulus_pa == pytest.approx(4e-3 / (3e-3 / e1 + 1e-3 / e2))
    assert e1 < layer.youngs_modulus_pa < e2


def test_a_soft_base_is_part_of_the_compliant_layer(sensor):
    soft_base = dataclasses.replace(sensor.gel_layers[0], youngs_modulus_pa=200e3)
    layers = (soft_base,) + sensor.gel_layers[1:]
    assert compliant_layer(dataclasses.replace(sensor, gel_layers=layers)).thickness_m == pytest.approx(8e-3)
    single = dataclasses.replace(sensor, gel_layers=(GelLayer("gel", 5e-3, 100e3, 0.45),))
    assert compliant_layer(single).youngs_modulus_pa == pytest.approx(100e3)


def test_pressing_moves_particles_down_most_under_the_contact(sensor, model):
    points = grid_points(sensor, 2e-3)
    moved = GelDisplacement(sensor, points).displacements_m(model.bin_forces([reference_press(sensor)]))
    x0, y0 = sensor.grid.centre_m
    r = np.hypot(points[:, 0] - x0, points[:, 1] - y0)
    assert moved.shape == points.shape and np.all(np.isfinite(moved))
    below = r < 1.5e-3
    assert np.all(moved[below, 2] < -0.3e-3)                    # ~ a fraction of the 1.5 mm press
    assert moved[np.argmin(r), 2] == pytest.approx(moved[:, 2].min(), rel=0.05)
    # incompressible layer on a base: the material under the indenter flows outwards, away from the contact
    ring = (r > 2e-3) & (r < 4e-3)
    outward = ((points[ring, 0] - x0) * moved[ring, 0] + (points[ring, 1] - y0) * moved[ring, 1]) / r[ring]
    assert np.all(outward > 0)


def test_shear_moves_particles_along_the_shear(sensor, model):
    points = grid_points(sensor, 1.5e-3)
    x0, y0 = sensor.grid.centre_m
    gel = GelDisplacement(sensor, points)
    pressed = gel.displacements_m(model.bin_forces([Contact(x0, y0, 1.2e-3)]))
    sheared = gel.displacements_m(model.bin_forces([Contact(x0, y0, 1.2e-3, shear_m=(0.0, 3e-4))]))
    near = np.hypot(points[:, 0] - x0, points[:, 1] - y0) < 2e-3
    extra = sheared - pressed
    assert np.all(extra[near, 1] > 0)
    assert np.abs(extra[near, 0]).max() < 0.2 * extra[near, 1].min()


def test_displacement_vanishes_on_the_base_and_beyond_the_influence_radius(sensor):
    layer = compliant_layer(sensor)
    dx = np.array([0.0, 1e-3, 3e-3])
    on_base = layer_kernel(dx, 0 * dx, np.full(3, layer.thickness_m), layer, 1e-3, 10e-3)
    assert np.abs(on_base).max() < 1e-12 * np.abs(layer_kernel(dx, 0 * dx, np.full(3, 1e-3), layer, 1e-3,
                                                                 10e-3)).max()
    below_base = layer_kernel(dx, 0 * dx, np.full(3, layer.thickness_m + 1e-3), layer, 1e-3, 10e-3)
    assert not below_base.any()
    far = layer_kernel(np.array([10e-3, 20e-3]), np.zeros(2), np.full(2, 2e-3), layer, 1e-3, 10e-3)
    assert not far.any()


def test_bonded_layer_decays_much_faster_than_a_half_space(sensor):
    """A half-space moves a point 10 mm away by ~1/5 of a point 2 mm away; the bonded 4 mm layer by < 5 %."""
    layer = compliant_layer(sensor)
    r = np.array([0.0, 10e-3])
    bonded = layer_kernel(r, 0 * r, np.full(2, 2e-3), layer, 1e-3, 0.05)[:, 2, 2]  # cut-off far beyond 10 mm
    assert abs(bonded[1]) < 0.05 * abs(bonded[0])


def test_particle_right_under_a_loaded_bin_centre_stays_finite(sensor):
    centre = sensor.grid.bin_centers_m()[10, 10]
    points = np.array([[centre[0], centre[1], -1e-3], [centre[0], centre[1], -1e-9], [centre[0], centre[1], -4e-3]])
    forces = np.zeros((sensor.grid.rows, sensor.grid.cols, 3))
    forces[10, 10] = (0.1, -0.1, 1.0)
    gel = GelDisplacement(sensor, points, dtype=np.float64)
    moved = gel.displacements_m(forces)
    assert np.all(np.isfinite(moved))
    assert moved[1, 2] < moved[0, 2] < 0          # shallower moves more
    assert moved[2] == pytest.approx(np.zeros(3), abs=1e-12)  # on the base
    # the bin's load acts spread by a Gaussian (sigma): at the surface it moves less than that Gaussian load on a
    # half-space, int p(r) / (pi E* r) dA = P / (E* sigma sqrt(2 pi)) (the bonded base stiffens), but of that order
    gaussian = 1.0 / (gel.layer.plane_strain_modulus_pa * gel.spread_m * math.sqrt(2 * math.pi))
    assert 0.5 * gaussian < -moved[1, 2] < gaussian


def test_float32_matches_float64(sensor, model):
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(0, sensor.grid.width_m, 3000), rng.uniform(0, sensor.grid.length_m, 3000),
                              -rng.uniform(1e-3, 4e-3, 3000)])
    forces = model.bin_forces([Contact(0.015, 0.03, 1.3e-3, shear_m=(1e-4, 2e-4)), Contact(0.03, 0.01, 0.5e-3)])
    fast = GelDisplacement(sensor, points).displacements_m(forces)
    exact = GelDisplacement(sensor, points, dtype=np.float64).displacements_m(forces)
    assert fast.dtype == np.float32 and exact.dtype == np.float64
    np.testing.assert_allclose(fast, exact, atol=1e-6 * np.abs(exact).max())


def test_displacement_is_linear_in_the_forces(sensor, model):
    points = grid_points(sensor, 2.5e-3, spacing_m=2e-3)
    gel = GelDisplacement(sensor, points, dtype=np.float64)
    a = model.bin_forces([Contact(0.012, 0.02, 1e-3)])
    b = model.bin_forces([Contact(0.03, 0.035, 0.8e-3, shear_m=(2e-4, 0))])
    np.testing.assert_allclose(gel.displacements_m(a + 2 * b), gel.displacements_m(a) + 2 * gel.displacements_m(b),
                               atol=1e-15)
    assert not gel.displacements_m(np.zeros_like(a)).any()


def test_bad_inputs_are_rejected_clearly(sensor):
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        GelDisplacement(sensor, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="z < 0"):
        GelDisplacement(sensor, np.array([[0.01, 0.01, 0.0]]))
    with pytest.raises(ValueError, match="NaN"):
        GelDisplacement(sensor, np.array([[0.01, math.nan, -1e-3]]))
    with pytest.raises(ValueError, match="influence_radius_m"):
        GelDisplacement(sensor, np.array([[0.01, 0.01, -1e-3]]), influence_radius_m=-1.0)
    gel = GelDisplacement(sensor, np.array([[0.01, 0.01, -1e-3]]))
    with pytest.raises(ValueError, match="shape"):
        gel.displacements_m(np.zeros((3, 3, 3)))
    forces = np.zeros((sensor.grid.rows, sensor.grid.cols, 3))
    forces[0, 0, 2] = math.inf
    with pytest.raises(ValueError, match="NaN or Inf"):
        gel.displacements_m(forces)


def test_green_function_conserves_what_the_layer_must():
    """Integrated over a plane (no cut-off): a tangential force shears the layer by (h - z) / G per newton, and a
    nearly incompressible layer's bulge almost cancels the normal force's dent (net ~ (1 - 2 nu) / (1 - nu))."""
    layer = compliant_layer(load_sensor(CONFIG / "sensor.yaml"))
    spacing = 0.4e-3
    x = np.arange(-50e-3, 50e-3, spacing)
    xx, yy = np.meshgrid(x, x)
    for depth in (1e-3, 2.5e-3):
        kernel = layer_kernel(xx, yy, np.full(xx.shape, depth), layer, 0.6e-3, 0.05)
        sheared = kernel[..., 0, 0].sum() * spacing**2
        assert sheared == pytest.approx((layer.thickness_m - depth) / layer.shear_modulus_pa, rel=0.01)
        assert abs(kernel[..., 1, 0].sum()) < 1e-9 * abs(kernel[..., 0, 0].sum())
        dent = kernel[..., 2, 2]
        assert abs(dent.sum()) < 0.1 * np.abs(dent).sum()


def test_thick_layer_is_boussinesq_and_cerruti():
    """Johnson (1985) eqs. 3.22 and 3.86 for a half-space, z into the solid, rho = |(x, y, z)|."""
    layer = CompliantLayer(thickness_m=10.0, youngs_modulus_pa=150e3, poisson_ratio=0.45)
    nu, c = layer.poisson_ratio, 1.0 / (4 * math.pi * layer.shear_modulus_pa)
    x, y, z = np.array([1e-3, 2e-3, -3e-3]), np.array([0.5e-3, -1e-3, 2e-3]), np.array([1.5e-3, 2e-3, 3e-3])
    rho = np.sqrt(x**2 + y**2 + z**2)
    kernel = layer_kernel(x, y, z, layer, 0.1e-3, 5e-3)  # a 0.1 mm spread is a point force seen from >= 1.8 mm
    boussinesq = c * np.stack([x * z / rho**3 - (1 - 2 * nu) * x / (rho * (rho + z)),
                               y * z / rho**3 - (1 - 2 * nu) * y / (rho * (rho + z)),
                               -(z**2 / rho**3 + 2 * (1 - nu) / rho)], axis=-1)
    cerruti_x = c * np.stack([1 / rho + x**2 / rho**3 + (1 - 2 * nu) * (1 / (rho + z) - x**2 / (rho * (rho + z) ** 2)),
                              x * y / rho**3 - (1 - 2 * nu) * x * y / (rho * (rho + z) ** 2),
                              -(x * z / rho**3 + (1 - 2 * nu) * x / (rho * (rho + z)))], axis=-1)
    np.testing.assert_allclose(kernel[..., :, 2], boussinesq, rtol=5e-3, atol=5e-3 * np.abs(boussinesq).max())
    np.testing.assert_allclose(kernel[..., :, 0], cerruti_x, rtol=5e-3, atol=5e-3 * np.abs(cerruti_x).max())


def test_displacement_benchmark_agrees_with_the_direct_sum(sensor, model):
    from tactile_sim.elastic import benchmark_displacement

    points = grid_points(sensor, 2e-3, spacing_m=2e-3)
    result = benchmark_displacement(sensor, points, model.bin_forces([reference_press(sensor)]), repeats=3)
    assert result["points"] == len(points) and result["loaded_bins"] > 5
    assert result["ms_per_frame_median"] > 0 and result["speedup_vs_direct"] > 0
    assert result["max_difference_m"] < 1e-6 * 1e-3  # float32 matrix against the float64 direct sum, 1e-6 of 1 mm
