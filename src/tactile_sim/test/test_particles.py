import dataclasses

import numpy as np
import pytest

from tactile_description import SensorConfigError
from tactile_sim.particles import generate_particles


def test_particles_fill_the_particle_layer_at_the_described_density(sensor):
    field = generate_particles(sensor)
    expected = sensor.particles.per_m3 * sensor.particle_layer_volume_m3
    assert abs(len(field) - expected) <= 1
    top, bottom = sensor.layer_depth_range_m(sensor.particles.layer)
    radius = field.diameters_m / 2
    depth = -field.positions_m[:, 2]
    assert np.all(depth - radius >= top) and np.all(depth + radius <= bottom)
    assert np.all((field.positions_m[:, 0] >= 0) & (field.positions_m[:, 0] <= sensor.grid.width_m))
    assert np.all((field.positions_m[:, 1] >= 0) & (field.positions_m[:, 1] <= sensor.grid.length_m))
    # spread over the whole layer, not clumped: each quarter of the surface holds about a quarter
    quarter = (field.positions_m[:, 0] < sensor.grid.width_m / 2) & (field.positions_m[:, 1] < sensor.grid.length_m / 2)
    assert abs(quarter.mean() - 0.25) < 0.02


def test_diameters_are_within_150_to_180_um(sensor):
    d = generate_particles(sensor).diameters_m
    assert d.min() >= 150e-6 and d.max() <= 180e-6 and d.std() > 5e-6


def test_same_description_gives_the_same_particles_and_the_seed_changes_them(sensor):
    a, b = generate_particles(sensor), generate_particles(sensor)
    np.testing.assert_array_equal(a.positions_m, b.positions_m)
    other = dataclasses.replace(sensor, particles=dataclasses.replace(sensor.particles, seed=sensor.particles.seed + 1))
    assert not np.array_equal(generate_particles(other).positions_m[:10], a.positions_m[:10])


def test_a_layer_thinner_than_a_particle_is_refused(sensor):
    thin = tuple(dataclasses.replace(layer, thickness_m=100e-6) if layer.name == sensor.particles.layer else layer
                 for layer in sensor.gel_layers)
    with pytest.raises(ValueError, match="thinner than one particle"):
        generate_particles(dataclasses.replace(sensor, gel_layers=thin))


def test_particles_in_the_rigid_base_are_refused(sensor):
    """The base does not deform, so particles there never move and the sensor would be blind."""
    in_base = dataclasses.replace(sensor, particles=dataclasses.replace(sensor.particles, layer="transparent_base"))
    with pytest.raises(SensorConfigError, match="particles.layer 'transparent_base' is the gel's rigid base"):
        generate_particles(in_base)
    soft_base = tuple(dataclasses.replace(layer, youngs_modulus_pa=300e3) if i == 0 else layer
                      for i, layer in enumerate(in_base.gel_layers))   # no rigid base: every layer deforms
    assert len(generate_particles(dataclasses.replace(in_base, gel_layers=soft_base))) > 1000
