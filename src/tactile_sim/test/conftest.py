"""Fixtures shared by the simulator's tests: the reference sensor and its analytic ground-truth model."""

import dataclasses

import pytest

from tactile_description import GelLayer, load_sensor
from tactile_sim.contact import ground_truth_model


@pytest.fixture(scope="session")
def sensor():
    """The installed reference sensor (config/sensor.yaml): 4 cameras, 26 x 25 bins."""
    return load_sensor()


@pytest.fixture(scope="session")
def model(sensor):
    """The default (analytic) ground-truth model of the reference sensor."""
    return ground_truth_model(sensor)


@pytest.fixture(scope="session")
def single_layer():
    """Factory: a sensor whose gel is one layer (thick: the half-space limit; thin: the bonded-layer regime)."""

    def make(sensor, thickness_m, youngs_modulus_pa=150e3, poisson_ratio=0.49):
        layer = GelLayer("gel", thickness_m, youngs_modulus_pa, poisson_ratio)
        return dataclasses.replace(sensor, gel_layers=(layer,),
                                   particles=dataclasses.replace(sensor.particles, layer="gel"))

    return make
