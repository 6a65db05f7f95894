"""The white microspheres spread in the particle layer, generated once and reproducibly from the description.

The real sensor's particles are polyethylene spheres (150-180 um) mixed at random into the soft middle layer
before it cures. Here they are placed uniformly at random in that layer with the density, diameter range and
seed of the sensor description, so every part of the stack that builds a simulator sees the same particles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_description import SensorConfigError, SensorDescription
from tactile_sim.elastic import rigid_base

#: Cell size of the storage order (see generate_particles): about the reach of one loaded bin's neighbourhood.
_CELL_M = 2e-3


@dataclass(frozen=True)
class ParticleField:
    """The particles at rest, in the sensor frame (z < 0 inside the gel)."""

    positions_m: np.ndarray   # (N, 3) float64
    diameters_m: np.ndarray   # (N,) float64
    reflectance: np.ndarray   # (N,) float64 in (0, 1]: how white each sphere looks (surface and tint spread)

    def __len__(self) -> int:
        return len(self.positions_m)


def generate_particles(sensor: SensorDescription) -> ParticleField:
    """Particles spread uniformly in the particle layer; same description -> same particles.

    The count is the description's density times the layer volume (rounded, `sensor.particle_count`), not a
    Poisson draw, so that it is a plain function of the description. The layer must deform: particles in the
    rigid base (elastic.rigid_base) would never move. Sphere centres keep one maximum radius away from the layer's
    top and bottom faces (a sphere does not stick out of the layer it was cast in). Particles are stored in
    raster order of 2 mm cells of the surface, so that the particles one press moves sit close together in
    memory (the per-frame gathers then hit the cache).
    """
    spec = sensor.particles
    base = rigid_base(sensor)
    if base is not None and spec.layer == base.name:
        raise SensorConfigError(f"{sensor.source}: particles.layer {spec.layer!r} is the gel's rigid base (much "
                                f"stiffer than the layers above it), which does not deform: the cameras would see no "
                                f"press; put the particles in one of {[layer.name for layer in sensor.gel_layers[1:]]}")
    top, bottom = sensor.layer_depth_range_m(spec.layer)
    margin = 0.5 * spec.diameter_max_m
    if bottom - top <= 2 * margin:
        raise SensorConfigError(f"{sensor.source}: the particle layer {spec.layer!r} ({(bottom - top) * 1e3:.3f} mm) "
                                f"is thinner than one particle ({spec.diameter_max_m * 1e6:.0f} um); make it thicker")
    count = sensor.particle_count
    rng = np.random.default_rng(spec.seed)
    positions = np.empty((count, 3))
    positions[:, 0] = rng.uniform(0.0, sensor.grid.width_m, count)
    positions[:, 1] = rng.uniform(0.0, sensor.grid.length_m, count)
    positions[:, 2] = -rng.uniform(top + margin, bottom - margin, count)
    diameters = rng.uniform(spec.diameter_min_m, spec.diameter_max_m, count)
    reflectance = rng.uniform(0.75, 1.0, count)
    cells = np.floor(positions[:, :2] / _CELL_M).astype(np.int64)
    order = np.lexsort((cells[:, 0], cells[:, 1]))
    return ParticleField(positions_m=positions[order], diameters_m=diameters[order], reflectance=reflectance[order])
