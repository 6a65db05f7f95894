"""The gel as a linear-elastic solid: its effective compliant layer, and the displacement of embedded particles.

The gel is three silicone layers (bottom to top in `sensor.gel_layers`). The bottom one (`transparent_base`) is
about seven times stiffer than the two above it (plane-strain modulus 1505 kPa against their series 207 kPa), so it
is treated as the rigid base the compliant layers are bonded to (`rigid_base`), and the compliant layers are merged
into one layer with an effective modulus (see `compliant_layer`). Both the contact models (contact.py,
contact_solver.py) and the particle displacement below use that one layer, so the forces and the particle motion
come from the same material. docs/simulator-physics.md justifies every choice.

Particle displacement (`GelDisplacement`): each loaded bin is a force at its centre, spread over about the bin's
area; the displacement of a point at depth zeta is the exact Green's function of the bonded layer (Fourier-Hankel
solution of the Navier equations with a free top and a bonded base, `layer_kernel`), which is the Boussinesq
(normal) and Cerruti (tangential) half-space solution (Johnson, Contact Mechanics, 1985, eqs. 3.22 and 3.86) for a
thick layer, vanishes on the base and decays exponentially along the layer instead of like 1/r. It is cut off
smoothly at a finite influence radius, which is what makes it fast: a press loads ~10-30 bins and each bin only
moves the particles within 3 layer thicknesses of it, so a frame multiplies only those columns of a sparse
influence matrix built once.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.sparse import csc_matrix
from scipy.spatial import cKDTree
from scipy.special import j0, j1

from tactile_description import GelLayer, SensorDescription
from tactile_description.value_checks import is_number

#: The bottom gel layer is treated as a rigid base when its plane-strain modulus is at least this many times the
#: effective modulus of the layers above it (the reference sensor: 1505 kPa over 207 kPa, a ratio of 7.3).
RIGID_BASE_STIFFNESS_RATIO = 5.0

#: Default influence radius of a bin force on the particles, in compliant-layer thicknesses (see docs).
INFLUENCE_RADIUS_LAYERS = 3.0
#: The kernel is tapered to zero (a half cosine) from this fraction of the influence radius to the radius.
INFLUENCE_TAPER_START = 0.75


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
    return _merge_layers(layers[1:] if rigid_base(sensor) is not None else layers)


def rigid_base(sensor: SensorDescription) -> GelLayer | None:
    """The bottom gel layer when it is much stiffer than the layers above it (RIGID_BASE_STIFFNESS_RATIO): the rigid
    base that does not deform; None when every layer deforms (a single layer sits on the rigid camera board)."""
    layers = sensor.gel_layers
    if len(layers) > 1 and (_merge_layers(layers[:1]).plane_strain_modulus_pa
                            >= RIGID_BASE_STIFFNESS_RATIO * _merge_layers(layers[1:]).plane_strain_modulus_pa):
        return layers[0]
    return None


def _layer_spectra(q: np.ndarray, depth: np.ndarray, layer: CompliantLayer) -> dict[str, np.ndarray]:
    """Fourier-space displacement at `depth` per unit surface traction of wavenumber q, each (n_q, n_depth).

    The layer (depth 0 to h, z into the solid) is free at the top and bonded at h. In plane strain along q the
    displacement modes of the Navier equations are, with s = q z, t = q (z - h), kappa = 3 - 4 nu and the
    in-plane amplitude U (u = i U e^{iqx}) and the vertical W (w = W e^{iqx}):
        (U, W) = (1, -1) e^-s,  (s, -s - kappa) e^-s,  (1, 1) e^t,  (t, t - kappa) e^t
    (direct substitution; Barber, Elasticity, ch. 16 derives the same family). Four boundary conditions fix
    them: the traction at the top (normal: sigma_zz = -1; tangential along q) and U = W = 0 on the base. The
    anti-plane part of a tangential load is u = sinh(q (h - z)) / (G q cosh(q h)) per unit traction. Written
    with e^-s and e^t only, nothing overflows for any q h.
    """
    h, shear, nu = layer.thickness_m, layer.shear_modulus_pa, layer.poisson_ratio
    kappa = 3.0 - 4.0 * nu
    lam = 2.0 * shear * nu / (1.0 - 2.0 * nu)
    qc = q[:, None]

    def modes(z):
        s, t = qc * z, qc * (z - h)
        em, ep = np.exp(-s), np.exp(t)
        u = np.stack([em, s * em, ep, t * ep], axis=-1)
        w = np.stack([-em, (-s - kappa) * em, ep, (t - kappa) * ep], axis=-1)
        du = qc[..., None] * np.stack([-em, (1 - s) * em, ep, (1 + t) * ep], axis=-1)
        dw = qc[..., None] * np.stack([em, (s - 1 + kappa) * em, ep, (1 + t - kappa) * ep], axis=-1)
        return u, w, du, dw

    u0, w0, du0, dw0 = modes(np.zeros((1, 1)))
    uh, wh, _, _ = modes(np.full((1, 1), h))
    normal_stress = (lam + 2.0 * shear) * dw0 - lam * qc[..., None] * u0
    shear_stress = shear * (du0 + qc[..., None] * w0)
    system = np.stack([normal_stress[:, 0], shear_stress[:, 0], uh[:, 0], wh[:, 0]], axis=1)
    loads = np.zeros((q.size, 4, 2))
    loads[:, 0, 0] = -1.0  # unit normal load pushing into the gel
    loads[:, 1, 1] = 1.0   # unit tangential load (phase i, see GelGreenFunction)
    coefficients = np.linalg.solve(system, loads)
    u, w, _, _ = modes(np.asarray(depth)[None, :])
    z = np.asarray(depth)[None, :]
    return {
        "normal_u": np.einsum("qzk,qk->qz", u, coefficients[:, :, 0]),
        "normal_w": np.einsum("qzk,qk->qz", w, coefficients[:, :, 0]),
        "shear_u": -np.einsum("qzk,qk->qz", u, coefficients[:, :, 1]),
        "shear_w": np.einsum("qzk,qk->qz", w, coefficients[:, :, 1]),
        "antiplane_u": (np.exp(-qc * z) - np.exp(-qc * (2 * h - z))) / (shear * qc * (1.0 + np.exp(-2 * qc * h))),
    }


@functools.lru_cache(maxsize=8)
def _green_tables(layer: CompliantLayer, spread_m: float, r_max_m: float, depth_max_m: float):
    """(r, depth, tables): the five radial functions of layer_kernel on a regular (r, depth) grid, depth up to
    depth_max_m.

    Hankel transforms of the spectra, computed as one matrix product per Bessel order (midpoint rule in q up to
    9 / spread, where the Gaussian below is e^-40; >= 16 points per Bessel period at r_max), each spectrum
    multiplied by exp(-(q spread)^2 / 2): the force spread by a Gaussian of standard deviation `spread_m`.
    """
    spacing = max(min(spread_m, layer.thickness_m) / 10.0, r_max_m / 2000.0, depth_max_m / 1000.0)
    r = np.linspace(0.0, r_max_m, int(math.ceil(r_max_m / spacing)) + 1)
    depth = np.linspace(0.0, depth_max_m, int(math.ceil(depth_max_m / spacing)) + 1)
    q_max = 9.0 / spread_m
    dq = min(2.0 * math.pi / (16.0 * r_max_m), q_max / 400.0)
    q = (np.arange(int(math.ceil(q_max / dq))) + 0.5) * dq
    spectra = _layer_spectra(q, depth, layer)
    weight = (q * dq * np.exp(-0.5 * (q * spread_m) ** 2) / (2.0 * math.pi))[:, None]
    in_plane, antiplane = spectra["shear_u"], spectra["antiplane_u"]
    integrands = [(0, spectra["normal_w"], 1.0),                      # vertical under a normal load
                  (1, spectra["normal_u"], -1.0),                     # radial under a normal load
                  (0, 0.5 * (in_plane + antiplane), 1.0),             # along a tangential load, isotropic part
                  (2, 0.5 * (in_plane - antiplane), 1.0),             # along a tangential load, cos 2 theta part
                  (1, spectra["shear_w"], -1.0)]                      # vertical under a tangential load, x cos
    tables = np.empty((r.size, depth.size, len(integrands)))
    for start in range(0, r.size, 128):  # chunks keep the (r, q) Bessel tables small
        qr = np.outer(r[start:start + 128], q)
        bessel = {0: j0(qr), 1: j1(qr)}
        # J2 by the recurrence J2 = 2 J1 / x - J0 (scipy's jv is ~10x slower), its series near x = 0
        bessel[2] = np.where(qr > 1e-3, 2.0 * bessel[1] / np.maximum(qr, 1e-3) - bessel[0], qr * qr / 8.0)
        for i, (order, spectrum, sign) in enumerate(integrands):
            tables[start:start + 128, :, i] = sign * (bessel[order] @ (spectrum * weight))
    return r, depth, tables


def layer_kernel(dx: np.ndarray, dy: np.ndarray, depth: np.ndarray, layer: CompliantLayer, spread_m: float,
                 influence_radius_m: float) -> np.ndarray:
    """(..., 3, 3) displacement per unit surface force of the bonded layer: [..., i, j] = component i (sensor x,
    y, z) at offset (dx, dy) and `depth` below the surface from a force j (0, 1: tangential along +x, +y; 2:
    normal, pushing into the gel) spread over a Gaussian of standard deviation `spread_m`.

    The exact Green's function of the layer on its rigid base (see _layer_spectra); it is Boussinesq's and
    Cerruti's solutions (Johnson 1985, eqs. 3.22, 3.86) when the layer is thick, vanishes on the base and decays
    exponentially along the layer (over a few h). A half-cosine taper from INFLUENCE_TAPER_START of the
    influence radius to the radius makes its support finite. Points below the base do not move.
    """
    if not 0.0 < influence_radius_m <= 0.2:
        raise ValueError(f"influence_radius_m must be in (0, 0.2] m (a few layer thicknesses: the bonded layer's "
                         f"response decays exponentially over a few h), got {influence_radius_m!r}")
    dx, dy, depth = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (dx, dy, depth)))
    # tabulate down to the deepest point (rounded up to 0.5 mm so that similar point sets share the table)
    deepest = min(layer.thickness_m, 5e-4 * math.ceil(float(np.max(depth, initial=0.0)) / 5e-4 + 1e-9))
    r_table, depth_table, tables = _green_tables(layer, float(spread_m), float(influence_radius_m), max(deepest, 5e-4))
    r = np.hypot(dx, dy)
    inside = (depth < layer.thickness_m) & (r < influence_radius_m)
    values = RegularGridInterpolator((r_table, depth_table), tables, bounds_error=False, fill_value=0.0)(
        np.stack([np.minimum(r, r_table[-1]), np.clip(depth, 0.0, depth_table[-1])], axis=-1))
    normal_w, normal_r, along, along_2, shear_w = np.moveaxis(values, -1, 0)
    safe_r = np.where(r > 0.0, r, 1.0)
    cos, sin = np.where(r > 0.0, dx / safe_r, 0.0), np.where(r > 0.0, dy / safe_r, 0.0)
    cos2, sin2 = cos * cos - sin * sin, 2.0 * cos * sin
    start = INFLUENCE_TAPER_START * influence_radius_m
    t = np.clip((r - start) / (influence_radius_m - start), 0.0, 1.0)
    taper = np.where(inside, 0.5 * (1.0 + np.cos(math.pi * t)), 0.0)
    k = np.empty(dx.shape + (3, 3))
    k[..., 0, 2] = normal_r * cos
    k[..., 1, 2] = normal_r * sin
    k[..., 2, 2] = -normal_w               # the gel's "into the solid" is the sensor's -z
    k[..., 0, 0] = along - along_2 * cos2
    k[..., 1, 1] = along + along_2 * cos2
    k[..., 1, 0] = k[..., 0, 1] = -along_2 * sin2
    k[..., 2, 0] = -shear_w * cos
    k[..., 2, 1] = -shear_w * sin
    return k * taper[..., None, None]


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
        if not (is_number(radius) and radius > 0):
            raise ValueError(f"influence_radius_m must be a positive number of metres, got {influence_radius_m!r}")
        self.influence_radius_m = float(radius)
        #: A bin's force acts spread over the bin; it is spread here by a Gaussian of the same variance as a
        #: uniform load on the bin (w^2 / 12 per axis), which keeps a particle under a bin centre finite.
        self.spread_m = math.sqrt(grid.bin_width_m * grid.bin_length_m / 12.0)

        centres = grid.bin_centers_m().reshape(-1, 2)
        neighbours = cKDTree(points[:, :2]).query_ball_point(centres, r=self.influence_radius_m)
        counts = np.array([len(n) for n in neighbours], dtype=np.int64)
        point_index = np.concatenate([np.asarray(n, dtype=np.int64) for n in neighbours] + [np.zeros(0, np.int64)])
        bin_index = np.repeat(np.arange(len(centres)), counts)
        kernel = layer_kernel(points[point_index, 0] - centres[bin_index, 0],
                              points[point_index, 1] - centres[bin_index, 1],
                              -points[point_index, 2], self.layer, self.spread_m, self.influence_radius_m)
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


def _median_ms(call, repeats: int) -> float:
    call()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def benchmark_displacement(sensor: SensorDescription, points_m: np.ndarray, bin_forces_n: np.ndarray,
                           repeats: int = 51) -> dict:
    """Median ms per frame of GelDisplacement.displacements_m, against the direct evaluation it replaces.

    The baseline evaluates the same kernel for every point and every loaded bin at call time (no precomputed
    influence matrix, no cut-off search); both are timed in this run, and their results compared.
    """
    gel = GelDisplacement(sensor, points_m)
    points = np.asarray(points_m, dtype=np.float64)
    centres = sensor.grid.bin_centers_m().reshape(-1, 2)
    flat = np.asarray(bin_forces_n, dtype=np.float64).reshape(-1, 3)
    loaded = np.flatnonzero(np.any(flat != 0.0, axis=1))

    def direct():
        dx = points[:, None, 0] - centres[None, loaded, 0]
        dy = points[:, None, 1] - centres[None, loaded, 1]
        depth = np.broadcast_to(-points[:, None, 2], dx.shape)
        kernel = layer_kernel(dx, dy, depth, gel.layer, gel.spread_m, gel.influence_radius_m)
        return np.einsum("nbij,bj->ni", kernel, flat[loaded])

    fast_ms = _median_ms(lambda: gel.displacements_m(bin_forces_n), repeats)
    direct_ms = _median_ms(direct, max(3, repeats // 10))
    difference = np.abs(gel.displacements_m(bin_forces_n) - direct()).max()
    return {"ms_per_frame_median": fast_ms, "direct_ms_per_frame_median": direct_ms,
            "speedup_vs_direct": direct_ms / fast_ms, "max_difference_m": float(difference),
            "points": len(points), "loaded_bins": int(loaded.size), "influence_matrix_mb": gel.influence_bytes / 1e6,
            "runs": repeats}
