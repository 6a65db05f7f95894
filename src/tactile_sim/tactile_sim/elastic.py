"""The gel as a linear-elastic solid: its effective compliant layer, and the displacement of embedded particles.

The gel is three silicone layers (bottom to top in `sensor.gel_layers`). The bottom one (`transparent_base`) is
about ten times stiffer than the two above it, so it is treated as the rigid base the compliant layers are bonded
to, and the compliant layers are merged into one layer with an effective modulus (see `compliant_layer`). Both
the contact models (contact.py, contact_solver.py) and the particle displacement below use that one layer, so the
forces and the particle motion come from the same material. docs/simulator-physics.md justifies every choice.

Particle displacement (`GelDisplacement`): each loaded bin is a point force at its centre; the displacement of a
point at depth zeta is the Boussinesq (normal) and Cerruti (tangential) half-space solution (Johnson, Contact
Mechanics, 1985, eqs. 3.22 and 3.86), corrected for the bonded base by subtracting the same solution at the
mirror depth 2h - zeta (so the displacement vanishes on the base, zeta = h, and decays like 1/r^3 instead of 1/r),
and cut off smoothly at a finite influence radius. The cut-off is what makes it fast: a press loads ~10-30 bins
and each bin only moves the particles within 2.5 layer thicknesses of it, so a frame multiplies only those
columns of a sparse influence matrix built once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csc_matrix
from scipy.spatial import cKDTree

from tactile_description import SensorDescription

#: The bottom gel layer is treated as a rigid base when its plane-strain modulus is at least this many times the
#: effective modulus of the layers above it (the reference sensor: 1200 kPa over ~180 kPa, a ratio of ~7).
RIGID_BASE_STIFFNESS_RATIO = 5.0

#: Default influence radius of a bin force on the particles, in compliant-layer thicknesses (see docs).
INFLUENCE_RADIUS_LAYERS = 2.5


@dataclass(frozen=True)
class CompliantLayer:
    """The compliant part of the gel as one homogeneous layer bonded to a rigid base at depth `thickness_m`."""

    thickness_m: float
    youngs_modulus_pa: float
    poisson_ratio: float

    @property
    def plane_strain_modulus_pa(self) -> float:
        """E* = E / (1 - nu^2) (Johnson 1985, eq. 4.22 with a rigid indenter)."""
        return self.youngs_modulus_pa / (1.0 - self.poisson_ratio**2)

    @property
    def shear_modulus_pa(self) -> float:
        return self.youngs_modulus_pa / (2.0 * (1.0 + self.poisson_ratio))


def _merge_layers(layers) -> CompliantLayer:
    """Layers in series: E*_eff = h / sum(h_i / E*_i) (their normal compliances add); nu thickness-weighted."""
    thickness = sum(layer.thickness_m for layer in layers)
    compliance = sum(layer.thickness_m * (1.0 - layer.poisson_ratio**2) / layer.youngs_modulus_pa for layer in layers)
    nu = sum(layer.thickness_m * layer.poisson_ratio for layer in layers) / thickness
    return CompliantLayer(thickness_m=thickness, youngs_modulus_pa=thickness / compliance * (1.0 - nu**2),
                          poisson_ratio=nu)


def compliant_layer(sensor: SensorDescription) -> CompliantLayer:
    """The layer that deforms: all gel layers above a much stiffer bottom layer, else all layers.

    With one layer only, it is bonded to the rigid camera board. The effective modulus of stacked layers is the
    series (uniform-pressure) average; it is exact for a load much wider than the stack and an approximation for
    a contact a few millimetres wide (docs/simulator-physics.md, "The gel").
    """
    layers = sensor.gel_layers
    if len(layers) == 1:
        return _merge_layers(layers)
    upper = _merge_layers(layers[1:])
    base = _merge_layers(layers[:1])
    if base.plane_strain_modulus_pa >= RIGID_BASE_STIFFNESS_RATIO * upper.plane_strain_modulus_pa:
        return upper
    return _merge_layers(layers)


def _half_space_kernel(dx: np.ndarray, dy: np.ndarray, depth: np.ndarray, nu: float,
                       shear_modulus_pa: float) -> np.ndarray:
    """(M, 3, 3) displacement per unit surface force: [..., i, j] = component i (sensor x, y, z) per force j.

    Force j = 0, 1: tangential along +x, +y (Cerruti, Johnson eq. 3.86); j = 2: normal, compressive (pushing into
    the gel, Boussinesq, Johnson eq. 3.22). Johnson's z points into the solid, i.e. along -z of the sensor, hence
    the sign flips of the vertical rows. Singular at depth 0 under the load: callers keep depth > 0.
    """
    rho = np.sqrt(dx * dx + dy * dy + depth * depth)
    c = 1.0 / (4.0 * math.pi * shear_modulus_pa)
    rho3 = rho**3
    rz = rho + depth
    s = 1.0 - 2.0 * nu
    k = np.empty(dx.shape + (3, 3), dtype=np.float64)
    # normal force (Boussinesq)
    k[..., 0, 2] = c * (dx * depth / rho3 - s * dx / (rho * rz))
    k[..., 1, 2] = c * (dy * depth / rho3 - s * dy / (rho * rz))
    k[..., 2, 2] = -c * (depth * depth / rho3 + 2.0 * (1.0 - nu) / rho)
    # tangential force along x (Cerruti)
    k[..., 0, 0] = c * (1.0 / rho + dx * dx / rho3 + s * (1.0 / rz - dx * dx / (rho * rz * rz)))
    k[..., 1, 0] = c * (dx * dy / rho3 - s * dx * dy / (rho * rz * rz))
    k[..., 2, 0] = -c * (dx * depth / rho3 + s * dx / (rho * rz))
    # tangential force along y (Cerruti, x and y swapped)
    k[..., 1, 1] = c * (1.0 / rho + dy * dy / rho3 + s * (1.0 / rz - dy * dy / (rho * rz * rz)))
    k[..., 0, 1] = k[..., 1, 0]
    k[..., 2, 1] = -c * (dy * depth / rho3 + s * dy / (rho * rz))
    return k


def layer_kernel(dx: np.ndarray, dy: np.ndarray, depth: np.ndarray, layer: CompliantLayer, core_m: float,
                 influence_radius_m: float) -> np.ndarray:
    """Displacement per unit surface force in the bonded layer: half-space minus its image, smoothly cut off.

    `core_m` spreads the bin force: the point-force solution is evaluated core_m deeper than the point (for the
    1/rho part this is exactly the load spread by a Poisson kernel of width core_m), which keeps a particle right
    under a bin centre finite and makes the displacement fall monotonically with depth there. The image (the
    same surface force seen from depth 2h - zeta) makes every component vanish on the base (zeta = h) and turns
    the 1/r far field of the half-space into ~h^2/r^3; the cosine taper from half the influence radius to the
    radius makes the influence finite. Points below the base do not move.
    """
    dx, dy, depth = (np.asarray(v, dtype=np.float64) for v in (dx, dy, depth))
    h = layer.thickness_m
    inside = depth < h
    direct = _half_space_kernel(dx, dy, depth + core_m, layer.poisson_ratio, layer.shear_modulus_pa)
    image = _half_space_kernel(dx, dy, 2.0 * h - depth + core_m, layer.poisson_ratio, layer.shear_modulus_pa)
    r = np.hypot(dx, dy)
    start = 0.5 * influence_radius_m
    t = np.clip((r - start) / (influence_radius_m - start), 0.0, 1.0)
    taper = np.where(inside, 0.5 * (1.0 + np.cos(math.pi * t)), 0.0)
    return (direct - image) * taper[..., None, None]


class GelDisplacement:
    """Displacement of fixed points in the gel (the particles) caused by bin forces on the surface.

    Everything that depends only on the points and the bin grid is done once here: a sparse influence matrix
    (3 N rows: point x component; 3 B columns: bin x force component) holding, for every bin, the kernels of the
    points within the influence radius (float32 by default, ~1e-7 relative; pass dtype=np.float64 for reference
    results). `displacements_m` then multiplies only the columns of the non-zero force components.
    """

    def __init__(self, sensor: SensorDescription, points_m: np.ndarray, *, influence_radius_m: float | None = None,
                 dtype=np.float32):
        points = np.asarray(points_m, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points_m must be an (N, 3) array of positions in metres, got shape {points.shape}")
        if not np.all(np.isfinite(points)):
            raise ValueError("points_m contains NaN or Inf; pass finite particle positions in metres")
        if np.any(points[:, 2] >= 0.0):
            raise ValueError(f"points_m must lie in the gel (z < 0, the surface is z = 0); the highest point is at "
                             f"z = {points[:, 2].max() * 1e3:.4f} mm")
        self.layer = compliant_layer(sensor)
        grid = sensor.grid
        self.shape = (grid.rows, grid.cols, 3)
        self.n_points = len(points)
        self.dtype = np.dtype(dtype)
        radius = INFLUENCE_RADIUS_LAYERS * self.layer.thickness_m if influence_radius_m is None else influence_radius_m
        if not (isinstance(radius, (int, float)) and math.isfinite(radius) and radius > 0):
            raise ValueError(f"influence_radius_m must be a positive number of metres, got {influence_radius_m!r}")
        self.influence_radius_m = float(radius)
        #: Radius of the disc with the area of one bin: the point-force regularisation (see layer_kernel).
        self.core_m = math.sqrt(grid.bin_width_m * grid.bin_length_m / math.pi)

        centres = grid.bin_centers_m().reshape(-1, 2)
        neighbours = cKDTree(points[:, :2]).query_ball_point(centres, r=self.influence_radius_m)
        counts = np.array([len(n) for n in neighbours], dtype=np.int64)
        point_index = np.concatenate([np.asarray(n, dtype=np.int64) for n in neighbours] + [np.zeros(0, np.int64)])
        bin_index = np.repeat(np.arange(len(centres)), counts)
        kernel = layer_kernel(points[point_index, 0] - centres[bin_index, 0],
                              points[point_index, 1] - centres[bin_index, 1],
                              -points[point_index, 2], self.layer, self.core_m, self.influence_radius_m)
        component = np.arange(3)
        rows = 3 * point_index[:, None, None] + component[None, :, None] + 0 * component[None, None, :]
        cols = 3 * bin_index[:, None, None] + 0 * component[None, :, None] + component[None, None, :]
        self._influence = csc_matrix((kernel.ravel().astype(self.dtype), (rows.ravel(), cols.ravel())),
                                     shape=(3 * self.n_points, 3 * len(centres)))

    @property
    def influence_bytes(self) -> int:
        """Memory held by the precomputed influence matrix (for the benchmark report)."""
        m = self._influence
        return m.data.nbytes + m.indices.nbytes + m.indptr.nbytes

    def displacements_m(self, bin_forces_n: np.ndarray) -> np.ndarray:
        """(N, 3) displacement of each point (sensor frame, metres) under `bin_forces_n` (rows, cols, 3), newtons.

        Pressing (fz > 0) moves points down (-z, towards the cameras); a tangential force moves them along it.
        """
        forces = np.asarray(bin_forces_n)
        if forces.shape != self.shape:
            raise ValueError(f"bin_forces_n must have shape (rows, cols, 3) = {self.shape}, got {forces.shape}")
        flat = forces.reshape(-1)
        loaded = np.flatnonzero(flat)
        if loaded.size == 0:
            return np.zeros((self.n_points, 3), dtype=self.dtype)
        values = flat[loaded]
        if not np.all(np.isfinite(values)):
            raise ValueError("bin_forces_n contains NaN or Inf; pass finite forces in newtons")
        moved = self._influence[:, loaded] @ values.astype(self.dtype)
        return moved.reshape(self.n_points, 3)
